// The calibration check on simulated scans (the simulator as fixture factory): the demo scene seen
// by the demo rig at a quarter of its resolution (cameras 480x300, projector 320x200), phase shift
// with both axes coded, sensor noise on (EMVA: 10000 e- full well, 6 e- read noise, 8 bit). The
// images are rendered with the true rig; the reconstruction is given a rig file with one error.
// Errors in pixels are given at the demo rig's full resolution and scaled to the small rig (0.5 px
// of a 1920-px camera is 0.125 px of its 480-px copy: the same angle), which makes them 4x smaller
// against the decode noise (projector px) than on the full-size rig: a harder test.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/simulate.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

// The rig's resolution divisor: 4, or SLSHADOW_CALIB_CHECK_DIVISOR (1 = the full-size demo rig,
// for docs/benchmarks.md; slower).
int Divisor() {
  static const int divisor = [] {
    const char* env = std::getenv("SLSHADOW_CALIB_CHECK_DIVISOR");
    const int d = env ? std::atoi(env) : 4;
    return d >= 1 && d <= 8 ? d : 4;
  }();
  return divisor;
}
constexpr double kDeg = M_PI / 180.0;

PatternSpec Spec(const Rig& rig) {
  PatternSpec spec;
  spec.kind = PatternKind::kPhaseShift;
  spec.projector_width = rig.projector->model.width;
  spec.projector_height = rig.projector->model.height;
  spec.code_x = spec.code_y = true;
  spec.phase_steps = 4;
  spec.period_px = 16;
  return spec;
}

Scene NoisyScene(uint64_t seed) {
  Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  scene.layers.noise_enabled = true;
  scene.layers.full_well_e = 10000;
  scene.layers.read_noise_e = 6;
  scene.layers.seed = seed;
  return scene;
}

// Decoded maps of both cameras for noise seeds, rendered once per seed from one geometry pass
// (with the ground truth of each camera).
class Scans {
 public:
  Scans()
      : rig_(testing::SmallDemoRig(Divisor())),
        spec_(Spec(rig_)),
        scene_(NoisyScene(1)),
        sim_(scene_, rig_) {
    patterns_ = GeneratePatterns(spec_);
  }
  const Rig& rig() const { return rig_; }
  const GeometryBuffer& truth(int camera) const { return sim_.geometry(camera); }
  std::vector<ProjectorMap> Decode(uint64_t seed) const {
    const Scene scene = NoisyScene(seed);
    const auto images = sim_.Render(patterns_, &scene);
    std::vector<ProjectorMap> maps;
    for (const auto& cam : images) maps.push_back(DecodePatterns(spec_, cam));
    return maps;
  }

 private:
  Rig rig_;
  PatternSpec spec_;
  Scene scene_;
  Simulator sim_;
  std::vector<cv::Mat> patterns_;
};

Scans& SharedScans() {
  static Scans* scans = new Scans();
  return *scans;
}

// RMS depth error of a reconstruction's cloud, mm: each point's depth in its reference camera
// (the cloud's "camera" is the rig index; u, v the source pixel) against the true depth there
// (bilinear between the four pixel-centre depths; points next to a missing one are skipped).
double DepthRmsMm(const Reconstruction& rec, const Rig& rig, const Scans& scans, int camera) {
  const auto* us = rec.cloud.Scalar("u");
  const auto* vs = rec.cloud.Scalar("v");
  const cv::Mat& depth = scans.truth(camera).depth_mm;
  const Rigid3d& cam_from_rig = rig.cameras[static_cast<size_t>(camera)].cam_from_rig;
  double sum = 0;
  int64_t n = 0;
  for (size_t i = 0; i < rec.cloud.size(); ++i) {
    const double u = (*us)[i], v = (*vs)[i];
    const int x0 = static_cast<int>(std::floor(u)), y0 = static_cast<int>(std::floor(v));
    if (x0 < 0 || y0 < 0 || x0 + 1 >= depth.cols || y0 + 1 >= depth.rows) continue;
    const double ax = u - x0, ay = v - y0;
    const double d =
        (1 - ay) * ((1 - ax) * depth.at<float>(y0, x0) + ax * depth.at<float>(y0, x0 + 1)) +
        ay * ((1 - ax) * depth.at<float>(y0 + 1, x0) + ax * depth.at<float>(y0 + 1, x0 + 1));
    if (!std::isfinite(d)) continue;
    sum += std::pow((cam_from_rig * rec.cloud.points[i]).z() - d, 2);
    ++n;
  }
  return n > 0 ? std::sqrt(sum / static_cast<double>(n)) : std::numeric_limits<double>::quiet_NaN();
}

struct RigError {
  std::string name;
  std::function<void(Rig*)> apply;
};

void ShiftPrincipalPoint(RigDevice* d, double dx_full_px, double dy_full_px) {
  d->model.params[CameraModel::kCx] += dx_full_px / Divisor();
  d->model.params[CameraModel::kCy] += dy_full_px / Divisor();
}

std::vector<RigError> Errors() {
  return {
      {"camera principal point +0.5 px (x and y)",
       [](Rig* r) { ShiftPrincipalPoint(&r->cameras[0], 0.5, 0.5); }},
      {"camera principal point +0.5 px (y)",
       [](Rig* r) { ShiftPrincipalPoint(&r->cameras[0], 0, 0.5); }},
      // Along the baseline: moves points along the epipolar lines, invisible to any epipolar check
      // (reported, not asserted).
      {"camera principal point +0.5 px (x)",
       [](Rig* r) { ShiftPrincipalPoint(&r->cameras[0], 0.5, 0); }},
      {"camera distortion inverted",
       [](Rig* r) {
         for (int k = CameraModel::kK1; k <= CameraModel::kK3; ++k)
           r->cameras[0].model.params[static_cast<size_t>(k)] *= -1;
       }},
      {"projector principal point +0.5 px (x and y)",
       [](Rig* r) { ShiftPrincipalPoint(&*r->projector, 0.5, 0.5); }},
      {"camera focal length +0.2 %",
       [](Rig* r) {
         r->cameras[0].model.params[CameraModel::kFx] *= 1.002;
         r->cameras[0].model.params[CameraModel::kFy] *= 1.002;
       }},
      {"projector focal length +0.2 %",
       [](Rig* r) {
         r->projector->model.params[CameraModel::kFx] *= 1.002;
         r->projector->model.params[CameraModel::kFy] *= 1.002;
       }},
      {"projector bumped 0.05 deg (about its x axis)",
       [](Rig* r) {
         r->projector->cam_from_rig =
             Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.05 * kDeg, Eigen::Vector3d::UnitX())),
                     Eigen::Vector3d::Zero()) *
             r->projector->cam_from_rig;
       }},
      {"projector bumped 0.05 deg (about its y axis)",
       [](Rig* r) {
         r->projector->cam_from_rig =
             Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.05 * kDeg, Eigen::Vector3d::UnitY())),
                     Eigen::Vector3d::Zero()) *
             r->projector->cam_from_rig;
       }},
      {"right camera bumped 0.05 deg (about its x axis)",
       [](Rig* r) {
         r->cameras[1].cam_from_rig =
             Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(0.05 * kDeg, Eigen::Vector3d::UnitX())),
                     Eigen::Vector3d::Zero()) *
             r->cameras[1].cam_from_rig;
       }},
  };
}

// One rig file's reconstructions of one scan: each camera against the projector, and stereo.
struct Outcome {
  std::vector<ReconstructSummary> summaries;  // left-projector, right-projector, left-right
  std::vector<double> depth_rms_mm;           // same order; stereo: depth in the left camera
};

Outcome Reconstruct(const Rig& rig, const std::vector<ProjectorMap>& maps, const Scans& scans) {
  // The ground truth is the true rig's: depths are compared in the true camera frames.
  Outcome out;
  for (int cam = 0; cam < 2; ++cam) {
    const Reconstruction rec = ReconstructWithProjector(
        rig, rig.cameras[static_cast<size_t>(cam)].name, maps[static_cast<size_t>(cam)]);
    out.depth_rms_mm.push_back(DepthRmsMm(rec, scans.rig(), scans, cam));
    out.summaries.push_back(rec.summary);
  }
  const Reconstruction stereo = ReconstructStereo(rig, "left", "right", maps[0], maps[1]);
  out.depth_rms_mm.push_back(DepthRmsMm(stereo, scans.rig(), scans, 0));
  out.summaries.push_back(stereo.summary);
  return out;
}

// A table row; the depth error the rig error adds to the clean scan's (noise): sqrt(rms^2 -
// clean^2).
void PrintRow(const std::string& what, const ReconstructSummary& s, double depth_rms_mm,
              double clean_rms_mm) {
  const CalibrationCheck& c = s.calibration_check;
  char depth[64] = "no points pass the gates | -";
  if (std::isfinite(depth_rms_mm)) {
    std::snprintf(
        depth, sizeof(depth), "%.3f | %.3f", depth_rms_mm,
        std::sqrt(std::max(0.0, depth_rms_mm * depth_rms_mm - clean_rms_mm * clean_rms_mm)));
  }
  std::printf("| %s | %s | %s | %.4f | %.4f | %.4f | %.3f | %s | %s |\n", what.c_str(),
              c.pair.c_str(), depth, c.systematic_px, c.noise_px, c.threshold_px, c.threshold_mm,
              c.warn ? "**yes**" : "no", c.likely_causes.empty() ? "" : c.likely_causes[0].c_str());
}

bool Names(const CalibrationCheck& c, const std::string& word) {
  for (const auto& cause : c.likely_causes) {
    if (cause.find(word) != std::string::npos) return true;
  }
  return false;
}

// Each error of issue 20's table (and a focal length error of 0.2 %, a 0.05 deg bump) is caught
// wherever it changes the epipolar geometry of the pair, and named: in projector mode by the
// pairs of the device it affects; in stereo by the camera pair when a camera is wrong. Projector
// errors are not observable in stereo, where the projector is only a texture: the stereo cloud
// does not change either, and the check stays quiet.
TEST(CalibrationCheckSimTest, RigErrorsAreCaughtWhereObservable) {
  const Scans& scans = SharedScans();
  const auto maps = scans.Decode(1);
  const Rig& truth = scans.rig();
  std::printf(
      "| rig file error | pair | depth RMS, mm | added by the error, mm | systematic, px | noise, "
      "px | threshold, px | "
      "threshold, mm | warning | first named cause |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
  const Outcome clean = Reconstruct(truth, maps, scans);
  for (size_t k = 0; k < 3; ++k) {
    PrintRow("none", clean.summaries[k], clean.depth_rms_mm[k], clean.depth_rms_mm[k]);
    EXPECT_FALSE(clean.summaries[k].calibration_check.warn)
        << clean.summaries[k].calibration_check.Message();
    EXPECT_TRUE(clean.summaries[k].calibration_check.available);
  }
  const auto errors = Errors();
  // Caught by left-projector, right-projector, left-right; a word of a named cause.
  const std::map<std::string, std::pair<std::array<bool, 3>, const char*>> expected = {
      {"camera principal point +0.5 px (x and y)", {{true, false, true}, "principal point"}},
      {"camera principal point +0.5 px (y)", {{true, false, true}, "principal point"}},
      {"camera distortion inverted", {{true, false, true}, "distortion"}},
      {"projector principal point +0.5 px (x and y)", {{true, true, false}, "principal point"}},
      {"camera focal length +0.2 %", {{true, false, true}, "focal length"}},
      {"projector focal length +0.2 %", {{true, true, false}, "focal length"}},
      {"projector bumped 0.05 deg (about its x axis)", {{true, true, false}, "rotation"}},
      {"projector bumped 0.05 deg (about its y axis)", {{true, true, false}, "rotation"}},
      {"right camera bumped 0.05 deg (about its x axis)", {{false, true, true}, "rotation"}},
  };
  for (const auto& e : errors) {
    Rig wrong = truth;
    e.apply(&wrong);
    const Outcome out = Reconstruct(wrong, maps, scans);
    const auto it = expected.find(e.name);
    for (size_t k = 0; k < 3; ++k) {
      PrintRow(e.name, out.summaries[k], out.depth_rms_mm[k], clean.depth_rms_mm[k]);
      if (it == expected.end()) continue;  // reported only (see Errors())
      const CalibrationCheck& c = out.summaries[k].calibration_check;
      SCOPED_TRACE(e.name + ", " + c.pair);
      EXPECT_EQ(c.warn, it->second.first[k]) << c.Message();
      if (c.warn) {
        EXPECT_TRUE(Names(c, it->second.second)) << c.Message();
        EXPECT_EQ(out.summaries[k].warnings.size(), 1u);
        // The margin: at least 1.3x the threshold (the closest case, measured: 1.49x; 4x that on
        // the full-size rig, where the same angle is 4x more pixels against the same noise).
        EXPECT_GT(c.systematic_px, 1.3 * c.threshold_px) << c.Message();
      } else {
        // Unaffected pairs keep the clean scan's values (stereo ignores the projector).
        EXPECT_NEAR(c.systematic_px, clean.summaries[k].calibration_check.systematic_px, 1e-9);
      }
    }
  }
}

// False alarms over 20 noise seeds of the clean scan: 80 checks (3 pairs with both axes coded and
// one-axis stereo, x 20 seeds), none warns.
// The largest systematic part found, against its threshold, is the margin.
TEST(CalibrationCheckSimTest, CleanScansDoNotWarnOverTwentySeeds) {
  const Scans& scans = SharedScans();
  int checks = 0, alarms = 0;
  double worst_ratio = 0;
  for (uint64_t seed = 101; seed < 121; ++seed) {
    auto maps = scans.Decode(seed);
    Outcome out = Reconstruct(scans.rig(), maps, scans);
    // And one-axis stereo (the projector error, OneCodedAxis below).
    for (auto& m : maps) {
      m.has_y = false;
      m.proj_y = cv::Mat();
    }
    out.summaries.push_back(
        ReconstructStereo(scans.rig(), "left", "right", maps[0], maps[1]).summary);
    for (const auto& s : out.summaries) {
      const CalibrationCheck& c = s.calibration_check;
      ASSERT_TRUE(c.available);
      ++checks;
      alarms += c.warn ? 1 : 0;
      worst_ratio = std::max(worst_ratio, c.systematic_px / c.threshold_px);
      EXPECT_FALSE(c.warn) << "seed " << seed << ": " << c.Message();
      EXPECT_TRUE(s.warnings.empty());
    }
  }
  std::printf(
      "false alarms: %d of %d checks (20 seeds x 4 checks); largest systematic part %.3f x its "
      "threshold\n",
      alarms, checks, worst_ratio);
  RecordProperty("false_alarms", alarms);
  RecordProperty("checks", checks);
  RecordProperty("worst_systematic_over_threshold", std::to_string(worst_ratio));
  EXPECT_EQ(checks, 80);
  EXPECT_LT(worst_ratio, 0.15);  // measured 0.056: a wide margin, not a near miss
}

// One coded axis (projector columns only, the usual stereo phase shift) leaves no epipolar error.
// Stereo then checks the calibrated projector as a third view (issue 14): the clean scan passes; a
// right camera turned 0.3 deg or 0.05 deg (about its y axis, along the baseline: invisible to any
// epipolar check, it changes the disparities) and swapped camera names are caught. Projector mode
// and a rig without a projector have nothing to check, and say so in one line.
TEST(CalibrationCheckSimTest, OneCodedAxis) {
  const Scans& scans = SharedScans();
  auto maps = scans.Decode(1);
  for (auto& m : maps) {
    m.has_y = false;
    m.proj_y = cv::Mat();
  }
  const Rig& truth = scans.rig();
  const Outcome out = Reconstruct(truth, maps, scans);
  for (size_t k = 0; k < 2; ++k) {  // projector mode
    const ReconstructSummary& s = out.summaries[k];
    const CalibrationCheck& c = s.calibration_check;
    EXPECT_FALSE(c.available);
    EXPECT_FALSE(c.warn);
    EXPECT_TRUE(s.warnings.empty());
    EXPECT_EQ(c.Message().rfind("calibration check: not available for " + c.pair +
                                    ", because only projector columns are coded",
                                0),
              0u)
        << c.Message();
    EXPECT_NE(s.FullReport().find(c.Message()), std::string::npos);
    EXPECT_FALSE(s.ToJson()["calibration_check"]["available"].get<bool>());
  }
  const CalibrationCheck& clean = out.summaries[2].calibration_check;
  ASSERT_TRUE(clean.available) << clean.Message();
  EXPECT_EQ(clean.residual, CalibrationResidual::kProjectorError);
  EXPECT_FALSE(clean.warn) << clean.Message();
  EXPECT_LT(clean.systematic_px, 0.2 * clean.threshold_px) << clean.Message();
  EXPECT_EQ(out.summaries[2].ToJson()["calibration_check"]["residual"], "projector_error_px");
  std::printf("one axis, clean: %s\n", clean.Message().c_str());
  for (double deg : {0.3, 0.05}) {
    Rig bumped = truth;
    bumped.cameras[1].cam_from_rig =
        Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(deg * kDeg, Eigen::Vector3d::UnitY())),
                Eigen::Vector3d::Zero()) *
        bumped.cameras[1].cam_from_rig;
    const Reconstruction rec = ReconstructStereo(bumped, "left", "right", maps[0], maps[1]);
    const CalibrationCheck& c = rec.summary.calibration_check;
    std::printf(
        "one axis, right camera turned %.2f deg about y: depth RMS %.3f mm (clean %.3f); %s\n", deg,
        DepthRmsMm(rec, truth, scans, 0), out.depth_rms_mm[2], c.Message().c_str());
    EXPECT_TRUE(c.warn) << deg << " deg: " << c.Message();
    EXPECT_EQ(rec.projector_error_px.size(), rec.grid.reason.size());  // the residual map's values
    EXPECT_GT(c.systematic_px, 1.3 * c.threshold_px) << c.Message();
  }
  // The two cameras' images filed under each other's names.
  const Reconstruction swapped = ReconstructStereo(truth, "left", "right", maps[1], maps[0]);
  const CalibrationCheck& sc = swapped.summary.calibration_check;
  std::printf("one axis, swapped cameras: %lld points; %s\n",
              static_cast<long long>(swapped.summary.points), sc.Message().c_str());
  EXPECT_TRUE(sc.warn) << sc.Message();
  // No projector in the rig: a 1-D projector is fitted instead (FittedProjector below).
  Rig no_projector = truth;
  no_projector.projector.reset();
  const CalibrationCheck none =
      ReconstructStereo(no_projector, "left", "right", maps[0], maps[1]).summary.calibration_check;
  EXPECT_TRUE(none.available) << none.Message();
  EXPECT_EQ(none.residual, CalibrationResidual::kFittedProjectorError);
}

// One coded axis and a rig without a projector (the usual stereo phase-shift rig file): the stereo
// points and the left camera's decoded columns must fit one 1-D projector (FitOneAxisProjector).
// The errors of the issue (right camera turned 0.3 deg about its x axis, swapped camera names) and
// smaller ones are caught; errors that map the cloud by a 3-D projective transform (a camera
// turned about its y axis: a near-constant disparity offset; a baseline length: a similarity) are
// absorbed by the fitted projector and reported, not asserted.
Rig Turned(const Rig& rig, int camera, double deg, const Eigen::Vector3d& axis) {
  Rig r = rig;
  RigDevice& d = r.cameras[static_cast<size_t>(camera)];
  d.cam_from_rig =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(deg * kDeg, axis)), Eigen::Vector3d::Zero()) *
      d.cam_from_rig;
  return r;
}

std::vector<ProjectorMap> ColumnsOnly(std::vector<ProjectorMap> maps) {
  for (auto& m : maps) {
    m.has_y = false;
    m.proj_y = cv::Mat();
  }
  return maps;
}

void PrintFittedRow(const std::string& what, const Reconstruction& rec, double depth_rms_mm,
                    double clean_rms_mm) {
  const CalibrationCheck& c = rec.summary.calibration_check;
  char depth[64] = "- | -";
  if (std::isfinite(depth_rms_mm)) {
    std::snprintf(
        depth, sizeof(depth), "%.3f | %.3f", depth_rms_mm,
        std::sqrt(std::max(0.0, depth_rms_mm * depth_rms_mm - clean_rms_mm * clean_rms_mm)));
  }
  std::printf("| %s | %lld | %s | %.4f | %.4f | %.4f (%.3f mm) | %.2f | %s | %s |\n", what.c_str(),
              static_cast<long long>(rec.summary.points), depth, c.systematic_px, c.noise_px,
              c.threshold_px, c.threshold_mm, c.systematic_px / c.threshold_px,
              c.warn ? "**yes**" : "no", c.likely_causes.empty() ? "" : c.likely_causes[0].c_str());
}

TEST(CalibrationCheckSimTest, FittedProjectorCatchesStereoRigErrorsWithOneCodedAxis) {
  const Scans& scans = SharedScans();
  const auto maps = ColumnsOnly(scans.Decode(1));
  Rig truth = scans.rig();
  truth.projector.reset();
  const Reconstruction clean = ReconstructStereo(truth, "left", "right", maps[0], maps[1]);
  const double clean_depth = DepthRmsMm(clean, scans.rig(), scans, 0);
  const CalibrationCheck& cc = clean.summary.calibration_check;
  std::printf("fitted projector, clean: %s\n  %s\n", cc.Message().c_str(),
              cc.fitted_projector.c_str());
  std::printf(
      "| rig file error | points | depth RMS, mm | added by the error, mm | systematic, px | "
      "noise, "
      "px | threshold, px (mm) | systematic / threshold | warning | first named cause |\n");
  std::printf("|---|---|---|---|---|---|---|---|---|---|\n");
  PrintFittedRow("none", clean, clean_depth, clean_depth);
  ASSERT_TRUE(cc.available) << cc.Message();
  EXPECT_EQ(cc.residual, CalibrationResidual::kFittedProjectorError);
  EXPECT_FALSE(cc.warn) << cc.Message();
  EXPECT_TRUE(clean.summary.warnings.empty());
  EXPECT_LT(cc.systematic_px, 0.6 * cc.threshold_px) << cc.Message();
  EXPECT_EQ(clean.summary.ToJson()["calibration_check"]["residual"], "fitted_projector_error_px");
  // The demo projector's k1 = -0.031 is what the data ask a radial term for.
  EXPECT_NE(cc.fitted_projector.find("radial"), std::string::npos) << cc.fitted_projector;
  EXPECT_EQ(clean.projector_error_px.size(), clean.grid.reason.size());  // the map's values

  struct Case {
    std::string name;
    Rig rig;
    bool swap = false;
    bool asserted = true;  // false: a blind spot, reported only
    double margin = 1.5;   // systematic part over threshold at least (measured: the log below)
  };
  const Eigen::Vector3d x = Eigen::Vector3d::UnitX(), y = Eigen::Vector3d::UnitY();
  Rig pp = truth;
  ShiftPrincipalPoint(&pp.cameras[1], 0, 2.0);
  Rig distortion = truth;
  for (int k = CameraModel::kK1; k <= CameraModel::kK3; ++k)
    distortion.cameras[0].model.params[static_cast<size_t>(k)] *= -1;
  Rig baseline = truth;
  baseline.cameras[1].cam_from_rig.translation *= 1.01;
  const std::vector<Case> cases = {
      {"right camera turned 0.3 deg about its x axis", Turned(truth, 1, 0.3, x)},
      {"right camera turned 0.1 deg about its x axis", Turned(truth, 1, 0.1, x), false, true, 1.1},
      {"right camera principal point +2 px (y)", pp, false, true, 1.1},
      {"left camera distortion inverted", distortion},
      {"camera names swapped", truth, true},
      {"right camera turned 0.3 deg about its y axis", Turned(truth, 1, 0.3, y), false, false},
      {"baseline 1 % long", baseline, false, false},
  };
  for (const Case& c : cases) {
    const Reconstruction rec = c.swap ? ReconstructStereo(c.rig, "left", "right", maps[1], maps[0])
                                      : ReconstructStereo(c.rig, "left", "right", maps[0], maps[1]);
    PrintFittedRow(c.name, rec, DepthRmsMm(rec, scans.rig(), scans, 0), clean_depth);
    const CalibrationCheck& check = rec.summary.calibration_check;
    std::printf("  %s\n", check.fitted_projector.c_str());
    if (!c.asserted) continue;
    SCOPED_TRACE(c.name);
    ASSERT_TRUE(check.available) << check.Message();
    EXPECT_TRUE(check.warn) << check.Message();
    // The margin (measured: docs/benchmarks/log/calibration-check-one-axis.md).
    EXPECT_GT(check.systematic_px, c.margin * check.threshold_px) << check.Message();
    EXPECT_TRUE(Names(check, "rows out of register")) << check.Message();
    EXPECT_EQ(rec.summary.warnings.size(), 1u);
  }
}

// False alarms of the fitted-projector check over 20 noise seeds of the clean one-axis scan.
TEST(CalibrationCheckSimTest, FittedProjectorDoesNotWarnOnCleanScansOverTwentySeeds) {
  const Scans& scans = SharedScans();
  Rig truth = scans.rig();
  truth.projector.reset();
  int checks = 0, alarms = 0, radial = 0;
  double worst_ratio = 0, noise_min = 1e9, noise_max = 0;
  for (uint64_t seed = 201; seed < 221; ++seed) {
    const auto maps = ColumnsOnly(scans.Decode(seed));
    const Reconstruction rec = ReconstructStereo(truth, "left", "right", maps[0], maps[1]);
    const CalibrationCheck& c = rec.summary.calibration_check;
    ASSERT_TRUE(c.available) << c.Message();
    ASSERT_EQ(c.residual, CalibrationResidual::kFittedProjectorError);
    ++checks;
    alarms += c.warn ? 1 : 0;
    radial += c.fitted_projector.find("radial") != std::string::npos ? 1 : 0;
    worst_ratio = std::max(worst_ratio, c.systematic_px / c.threshold_px);
    noise_min = std::min(noise_min, c.noise_px);
    noise_max = std::max(noise_max, c.noise_px);
    EXPECT_FALSE(c.warn) << "seed " << seed << ": " << c.Message();
  }
  std::printf(
      "fitted projector: false alarms %d of %d clean scans (seeds 201-220); largest systematic "
      "part %.3f x its threshold; decode noise %.4f-%.4f px; radial model chosen %d times\n",
      alarms, checks, worst_ratio, noise_min, noise_max, radial);
  RecordProperty("false_alarms", alarms);
  RecordProperty("worst_systematic_over_threshold", std::to_string(worst_ratio));
  EXPECT_EQ(checks, 20);
  EXPECT_LT(worst_ratio, 0.6);
}

}  // namespace
}  // namespace slshadow
