// FitCalibrationCheck on synthetic epipolar errors with known fields and known noise: the fit
// recovers the field's size and shape, the noise estimate recovers the noise, blunders do not move
// either, and the threshold follows the noise, the floor or the user.
#include "reconstruct/calibration_check.h"

#include <cmath>
#include <functional>
#include <limits>
#include <random>
#include <string>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "core/camera_model.h"

namespace slshadow {
namespace {

struct Samples {
  std::vector<float> x, y, e;
};

// n points uniform over a 1 x 0.625 image (normalised half-widths), error = field + N(0, sigma).
Samples Make(int n, double sigma, const std::function<double(double, double)>& field,
             uint32_t seed = 7) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(-1, 1), uy(-0.625, 0.625);
  std::normal_distribution<double> noise(0, sigma);
  Samples s;
  for (int i = 0; i < n; ++i) {
    const double x = ux(rng), y = uy(rng);
    s.x.push_back(static_cast<float>(x));
    s.y.push_back(static_cast<float>(y));
    s.e.push_back(static_cast<float>(field(x, y) + noise(rng)));
  }
  return s;
}

CalibrationCheckSetup DefaultSetup() {
  CalibrationCheckSetup setup;
  setup.pair = "left-projector";
  setup.working_distance_mm = 500;
  setup.mm_per_px = 1.5;
  return setup;
}

CalibrationCheck Fit(const Samples& s, const CalibrationCheckSetup& setup = DefaultSetup()) {
  return FitCalibrationCheck(s.x, s.y, s.e, setup);
}

// RMS over the sampled points of a field.
double FieldRms(const Samples& s, const std::function<double(double, double)>& field) {
  double sum = 0;
  for (size_t i = 0; i < s.x.size(); ++i) sum += std::pow(field(s.x[i], s.y[i]), 2);
  return std::sqrt(sum / static_cast<double>(s.x.size()));
}

bool Names(const CalibrationCheck& c, const std::string& word) {
  for (const auto& cause : c.likely_causes) {
    if (cause.find(word) != std::string::npos) return true;
  }
  return false;
}

TEST(CalibrationCheckTest, NoiseAloneDoesNotWarnAndIsMeasured) {
  for (uint32_t seed = 1; seed <= 10; ++seed) {
    const Samples s = Make(
        50000, 0.05, [](double, double) { return 0.0; }, seed);
    const CalibrationCheck c = Fit(s);
    ASSERT_TRUE(c.available);
    EXPECT_EQ(c.count, 50000);
    EXPECT_NEAR(c.noise_px, 0.05, 0.002);
    // A field of 8 terms fitted to pure noise: RMS ~ sigma sqrt(8 / n) = 0.0006 px.
    EXPECT_LT(c.systematic_px, 0.002);
    EXPECT_EQ(c.threshold_source, "noise");
    EXPECT_NEAR(c.threshold_px, c.noise_px, 1e-12);
    EXPECT_NEAR(c.threshold_mm, 1.5 * c.threshold_px, 1e-12);
    EXPECT_FALSE(c.warn);
    EXPECT_TRUE(c.likely_causes.empty());
    EXPECT_EQ(c.Message().rfind("calibration check: passed: ", 0), 0u) << c.Message();
  }
}

TEST(CalibrationCheckTest, FieldsAreMeasuredAndNamedByShape) {
  const double sigma = 0.05;
  struct Case {
    const char* name;
    std::function<double(double, double)> field;
    int group;          // the group that must carry it
    const char* cause;  // a word of the named cause
  };
  const std::vector<Case> cases = {
      {"offset", [](double, double) { return 0.06; }, 0, "principal point"},
      {"linear", [](double x, double y) { return 0.16 * x - 0.1 * y; }, 1, "focal length"},
      {"quadratic", [](double x, double y) { return 0.5 * x * y; }, 2, "pose"},
      {"radial", [](double x, double y) { return 0.4 * x * (x * x + y * y) - 0.2 * x; }, 3,
       "distortion"},
  };
  for (const auto& k : cases) {
    SCOPED_TRACE(k.name);
    const Samples s = Make(50000, sigma, k.field);
    const CalibrationCheck c = Fit(s);
    EXPECT_NEAR(c.systematic_px, FieldRms(s, k.field), 0.003);
    EXPECT_NEAR(c.noise_px, sigma, 0.002);
    EXPECT_TRUE(c.warn) << c.Message();
    EXPECT_TRUE(Names(c, k.cause)) << c.Message();
    // The group carries most of the field.
    EXPECT_GT(c.group_rms_px[static_cast<size_t>(k.group)], 0.5 * c.systematic_px) << c.Message();
    EXPECT_NE(c.Message().find("above the threshold"), std::string::npos);
    EXPECT_NE(c.Message().find(" mm in depth at the 500 mm working distance of this scan"),
              std::string::npos)
        << c.Message();
    const nlohmann::json j = c.ToJson();
    EXPECT_TRUE(j["warning"].get<bool>());
    EXPECT_EQ(j["residual"], "epipolar_error_px");
    EXPECT_NEAR(j["field_rms_px"][CalibrationCheck::GroupName(k.group)].get<double>(),
                c.group_rms_px[static_cast<size_t>(k.group)], 1e-12);
  }
}

TEST(CalibrationCheckTest, BlundersMoveNeitherNoiseNorField) {
  const double sigma = 0.05;
  Samples s = Make(50000, sigma, [](double x, double) { return 0.03 * x; });
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> blunder(-50, 50);
  for (size_t i = 0; i < s.e.size(); i += 20) s.e[i] = static_cast<float>(blunder(rng));  // 5 %
  const CalibrationCheck c = Fit(s);
  EXPECT_NEAR(c.noise_px, sigma, 0.006);
  EXPECT_NEAR(c.group_rms_px[1], 0.03 / std::sqrt(3.0), 0.004);
  EXPECT_LT(c.group_rms_px[0] + c.group_rms_px[2] + c.group_rms_px[3], 0.01);
}

TEST(CalibrationCheckTest, GrossErrorsNameAWrongRigFile) {
  const CalibrationCheck c = Fit(Make(20000, 0.05, [](double x, double) { return 300 + 100 * x; }));
  EXPECT_TRUE(c.warn);
  EXPECT_NEAR(c.median_px, 300, 3);
  EXPECT_TRUE(Names(c, "swapped camera names")) << c.Message();
}

TEST(CalibrationCheckTest, ThresholdFloorUserOverrideAndTooFewPoints) {
  // Exact data: no noise to judge by; the floor holds a field of 1e-4 px below the threshold.
  const Samples exact = Make(5000, 0.0, [](double x, double) { return 1e-4 * x; });
  const CalibrationCheck floor = Fit(exact);
  EXPECT_EQ(floor.threshold_source, "floor");
  EXPECT_EQ(floor.threshold_px, 0.01);
  EXPECT_FALSE(floor.warn);
  EXPECT_NE(floor.Message().find("floor"), std::string::npos);
  // A user threshold replaces the automatic one, both ways.
  const Samples s = Make(20000, 0.05, [](double, double) { return 0.1; });
  CalibrationCheckSetup setup = DefaultSetup();
  setup.warning_px = 0.2;
  const CalibrationCheck user = Fit(s, setup);
  EXPECT_EQ(user.threshold_source, "user");
  EXPECT_EQ(user.threshold_px, 0.2);
  EXPECT_FALSE(user.warn);
  EXPECT_NE(user.Message().find("--calibration-warning-px"), std::string::npos);
  setup.warning_px = std::numeric_limits<double>::infinity();
  const CalibrationCheck off = Fit(s, setup);
  EXPECT_TRUE(off.available);
  EXPECT_FALSE(off.warn);
  EXPECT_NEAR(off.systematic_px, 0.1, 0.002);  // still measured and reported
  EXPECT_EQ(off.ToJson()["threshold_px"], "inf");
  EXPECT_EQ(
      off.Message().rfind("calibration check: reported only (--calibration-warning-px inf): ", 0),
      0u)
      << off.Message();
  // No projector model: no mm equivalent, and the message says so.
  CalibrationCheckSetup no_mm = DefaultSetup();
  no_mm.mm_per_px = 0;
  const CalibrationCheck unitless = Fit(s, no_mm);
  EXPECT_EQ(unitless.threshold_mm, 0);
  EXPECT_NE(unitless.Message().find("no mm equivalent without a projector model"),
            std::string::npos)
      << unitless.Message();
  // Few points: a small-sample threshold (5 standard errors of a fitted field) guards the fit.
  const Samples few = Make(150, 0.05, [](double, double) { return 0.0; });
  EXPECT_GT(Fit(few).threshold_px, 0.05 * 5 * std::sqrt(8.0 / 150) * 0.8);
  // Too few: not available, and says why.
  const Samples tiny = Make(99, 0.05, [](double, double) { return 0.0; });
  const CalibrationCheck none = Fit(tiny);
  EXPECT_FALSE(none.available);
  EXPECT_FALSE(none.warn);
  EXPECT_EQ(none.Message().rfind(
                "calibration check: not available for left-projector, because only 99", 0),
            0u)
      << none.Message();
  EXPECT_FALSE(none.ToJson()["available"].get<bool>());
  // NaN entries are skipped.
  Samples holes = Make(1000, 0.05, [](double, double) { return 0.0; });
  for (size_t i = 0; i < holes.e.size(); i += 2)
    holes.e[i] = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(Fit(holes).count, 500);
}

// The cause list follows the field's size: a 0.3 px field names its shape only, 6 px a bumped
// device first, 71 px a wrong rig file first and nothing of the shape; and the shape's causes come
// in order of their share.
TEST(CalibrationCheckTest, CausesAreRankedBySizeAndShape) {
  const auto linear = [](double a) { return [a](double x, double) { return a * x; }; };
  const CalibrationCheck small = Fit(Make(20000, 0.05, linear(0.5)));
  ASSERT_TRUE(small.warn);
  ASSERT_FALSE(small.likely_causes.empty());
  EXPECT_NE(small.likely_causes[0].find("focal length"), std::string::npos) << small.Message();
  EXPECT_FALSE(Names(small, "wrong rig file")) << small.Message();
  EXPECT_FALSE(Names(small, "bumped")) << small.Message();
  const CalibrationCheck bump = Fit(Make(20000, 0.05, linear(10)));  // 5.8 px RMS
  ASSERT_TRUE(bump.warn);
  ASSERT_GE(bump.likely_causes.size(), 3u);
  EXPECT_NE(bump.likely_causes[0].find("bumped"), std::string::npos) << bump.Message();
  EXPECT_NE(bump.likely_causes[1].find("focal length"), std::string::npos) << bump.Message();
  EXPECT_NE(bump.likely_causes.back().find("wrong rig file"), std::string::npos);
  const CalibrationCheck gross = Fit(Make(20000, 0.05, linear(123)));  // 71 px RMS
  ASSERT_TRUE(gross.warn);
  ASSERT_EQ(gross.likely_causes.size(), 2u) << gross.Message();
  EXPECT_NE(gross.likely_causes[0].find("wrong rig file"), std::string::npos) << gross.Message();
  EXPECT_NE(gross.likely_causes[1].find("bumped"), std::string::npos) << gross.Message();
  EXPECT_NE(small.Message(), bump.Message());
  // Shape: the groups in order of their share (an offset names the principal point, a linear
  // field the focal length).
  const CalibrationCheck offset_first =
      Fit(Make(20000, 0.05, [](double x, double) { return 0.5 + 0.4 * x; }));
  const CalibrationCheck linear_first =
      Fit(Make(20000, 0.05, [](double x, double) { return 0.2 + 0.9 * x; }));
  ASSERT_GE(offset_first.likely_causes.size(), 2u) << offset_first.Message();
  ASSERT_GE(linear_first.likely_causes.size(), 2u) << linear_first.Message();
  EXPECT_NE(offset_first.likely_causes[0].find("principal point"), std::string::npos);
  EXPECT_NE(offset_first.likely_causes[1].find("focal length"), std::string::npos);
  EXPECT_NE(linear_first.likely_causes[0].find("focal length"), std::string::npos);
  EXPECT_NE(linear_first.likely_causes[1].find("principal point"), std::string::npos);
}

// FitOneAxisProjector against columns projected by core's camera model (the demo projector's
// intrinsics and pose) at points spread over a 300 x 200 x 150 mm volume 500 mm away, with
// N(0, 0.05 px) noise: the fitted projector predicts held-out columns to a fraction of the noise;
// the radial terms are used when the projector has them, not when it has none; columns no
// projector can produce leave a residual far above the noise.
struct ProjectorData {
  std::vector<Eigen::Vector3d> points;
  std::vector<double> columns;
};

CameraModel DemoProjector(double k1) {
  CameraModel m;
  m.width = 1280;
  m.height = 800;
  m.params = {1850, 1850, 640, 400, k1, 0, 0, 0, 0};
  return m;
}

Rigid3d DemoProjectorPose() {
  return Rigid3d(Eigen::Quaterniond(0.994783156801, 0.024966819226, 0.098878563892, 0.002481629502),
                 Eigen::Vector3d(-98.424688323, 24.591191283, 8.766643586));
}

ProjectorData MakeProjectorData(int n, double k1, double sigma, uint32_t seed) {
  const CameraModel model = DemoProjector(k1);
  const Rigid3d proj_from_rig = DemoProjectorPose();
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> ux(-150, 150), uy(-100, 100), uz(425, 575);
  std::normal_distribution<double> noise(0, sigma);
  ProjectorData d;
  while (static_cast<int>(d.points.size()) < n) {
    const Eigen::Vector3d p(ux(rng), uy(rng), uz(rng));
    const Eigen::Vector3d q = proj_from_rig * p;
    double px[2];
    CameraModel::ImgFromCam(model.params.data(), q.data(), px);
    if (px[0] < 0 || px[0] > model.width - 1 || px[1] < 0 || px[1] > model.height - 1) continue;
    d.points.push_back(p);
    d.columns.push_back(px[0] + noise(rng));
  }
  return d;
}

// RMS of fitted minus true (noise-free) columns at held-out points.
double PredictionRmsPx(const OneAxisProjectorFit& fit, double k1) {
  const ProjectorData truth = MakeProjectorData(2000, k1, 0.0, 99);
  double sum = 0;
  for (size_t i = 0; i < truth.points.size(); ++i)
    sum += std::pow(fit.Column(truth.points[i]) - truth.columns[i], 2);
  return std::sqrt(sum / static_cast<double>(truth.points.size()));
}

TEST(FitOneAxisProjectorTest, RecoversPinholeAndRadialProjectors) {
  for (const double k1 : {0.0, -0.031}) {
    SCOPED_TRACE(k1);
    const ProjectorData d = MakeProjectorData(20000, k1, 0.05, 5);
    const OneAxisProjectorFit fit = FitOneAxisProjector(d.points, d.columns);
    ASSERT_TRUE(fit.ok) << fit.reason;
    EXPECT_EQ(fit.radial, k1 != 0) << fit.Describe();
    EXPECT_NEAR(fit.rms_px, 0.05, 0.005) << fit.Describe();
    EXPECT_LT(PredictionRmsPx(fit, k1), 0.01) << fit.Describe();
    if (k1 != 0) {
      EXPECT_GT(fit.pinhole_rms_px, 4 * fit.rms_px) << fit.Describe();  // the data asked for it
      EXPECT_NEAR(fit.k1, k1, 0.005) << fit.Describe();
    }
    // The baseline against the columns: the distance of the rig origin (the left camera) from
    // the projector's axis line, against the true pose's.
    const Eigen::Vector3d c = DemoProjectorPose().TargetOriginInSource();
    const Eigen::Vector3d axis =
        DemoProjectorPose().rotation.conjugate() * Eigen::Vector3d::UnitY();
    const double truth_mm = (-c - (-c).dot(axis) * axis).norm();
    EXPECT_NEAR(fit.BaselineMm(Eigen::Vector3d::Zero()), truth_mm, 0.01 * truth_mm);
  }
}

TEST(FitOneAxisProjectorTest, InconsistentColumnsAndBadInput) {
  // Columns bent by 1 px along the projector's rows (no 1-D projector does that).
  ProjectorData d = MakeProjectorData(20000, -0.031, 0.05, 6);
  for (size_t i = 0; i < d.points.size(); ++i) d.columns[i] += std::sin(d.points[i].y() / 30.0);
  const OneAxisProjectorFit bent = FitOneAxisProjector(d.points, d.columns);
  ASSERT_TRUE(bent.ok) << bent.reason;
  EXPECT_GT(bent.rms_px, 0.3) << bent.Describe();
  // Blunders (5 %, +-50 px) do not move the fit.
  ProjectorData b = MakeProjectorData(20000, -0.031, 0.05, 7);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> blunder(-50, 50);
  for (size_t i = 0; i < b.columns.size(); i += 20) b.columns[i] += blunder(rng);
  const OneAxisProjectorFit robust = FitOneAxisProjector(b.points, b.columns);
  ASSERT_TRUE(robust.ok) << robust.reason;
  EXPECT_LT(PredictionRmsPx(robust, -0.031), 0.02) << robust.Describe();
  // Too few finite pairs; NaN pairs skipped.
  ProjectorData few = MakeProjectorData(150, 0, 0.05, 8);
  for (size_t i = 0; i < few.columns.size(); i += 2)
    few.columns[i] = std::numeric_limits<double>::quiet_NaN();
  const OneAxisProjectorFit none = FitOneAxisProjector(few.points, few.columns);
  EXPECT_FALSE(none.ok);
  EXPECT_NE(none.reason.find("only 75 points"), std::string::npos) << none.reason;
  // All points on one spot: degenerate.
  const std::vector<Eigen::Vector3d> same(200, Eigen::Vector3d(0, 0, 500));
  const OneAxisProjectorFit degenerate = FitOneAxisProjector(same, std::vector<double>(200, 640));
  EXPECT_FALSE(degenerate.ok);
}

}  // namespace
}  // namespace slshadow
