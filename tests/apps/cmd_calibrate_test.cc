// The `slshadow calibrate` subcommand end to end (apps/cmd_calibrate.cc), on real data.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "calib/calibration_io.h"
#include "calib/refine.h"
#include "core/config.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "tests/testing/opencv_stereo.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

using slshadow::testing::RunCli;

std::string Data(const std::string& name) {
  return (testing::SharedDataDir() / "opencv-stereo-chessboard" / name).string();
}

TEST(CmdCalibrate, StereoWritesRigReportAndOpenCvFile) {
  testing::TempDir tmp;
  const std::string target =
      (testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml").string();
  std::vector<std::string> args = {"calibrate",
                                   "stereo",
                                   "--target",
                                   target,
                                   "--fix-aspect",
                                   "--out",
                                   (tmp / "rig.yaml").string(),
                                   "--opencv-out",
                                   (tmp / "stereo.yml").string(),
                                   "--left"};
  const std::vector<int> ids = {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14};
  for (int i : ids)
    args.push_back(Data("left" + std::string(i < 10 ? "0" : "") + std::to_string(i) + ".jpg"));
  args.push_back("--right");
  for (int i : ids)
    args.push_back(Data("right" + std::string(i < 10 ? "0" : "") + std::to_string(i) + ".jpg"));
  ASSERT_EQ(RunCli(args), 0);
  const Rig rig = LoadRig(tmp / "rig.yaml");
  ASSERT_EQ(rig.cameras.size(), 2u);
  EXPECT_EQ(rig.cameras[0].name, "left");
  EXPECT_NEAR(rig.cameras[0].model.fx(), 535.9, 2.0);
  // The evidence recomputes the same calibration.
  const CalibrationEvidence ev = CalibrationEvidenceFromJson(rig.calibration, "rig.yaml");
  // The baseline against OpenCV's stereoCalibrate on the detections the rig file keeps (an
  // independent solver on the same corners; tests/calib/calibration_test.cc compares the pose too).
  const testing::OpenCvStereo cv_stereo =
      testing::OpenCvStereoCalibrate(ev.input, cv::CALIB_FIX_ASPECT_RATIO);
  EXPECT_EQ(cv_stereo.pairs, 13);
  EXPECT_NEAR(rig.BaselineMm(rig.cameras[0], rig.cameras[1]), cv_stereo.T_mm.norm(), 0.1);
  EXPECT_TRUE(ev.options.fix_aspect_ratio);
  EXPECT_NEAR(Calibrate(ev.input, ev.options).devices[1].model.fx(), rig.cameras[1].model.fx(),
              1e-6);
  for (const char* f : {"summary.json", "report.txt", "per_view_rms.png", "residuals_left.png",
                        "uncertainty_right.png", "cross_validation_left.png"}) {
    EXPECT_TRUE(std::filesystem::exists(tmp / "rig_report" / f)) << f;
  }
  const Rig cv_rig = ReadOpenCvCalibration(tmp / "stereo.yml");
  EXPECT_NEAR(cv_rig.cameras[1].cam_from_rig.translation.x(),
              rig.cameras[1].cam_from_rig.translation.x(), 1e-9);
  // Export / import round trip through the CLI.
  ASSERT_EQ(RunCli({"calibrate", "export", (tmp / "rig.yaml").string(), "--out",
                    (tmp / "exported.xml").string()}),
            0);
  ASSERT_EQ(RunCli({"calibrate", "import", (tmp / "exported.xml").string(), "--out",
                    (tmp / "imported.yaml").string()}),
            0);
  EXPECT_NEAR(LoadRig(tmp / "imported.yaml").cameras[1].model.cy(), rig.cameras[1].model.cy(),
              1e-9);
}

TEST(CmdCalibrate, BadInputsFailWithoutWriting) {
  testing::TempDir tmp;
  const std::string target =
      (testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml").string();
  const std::string out = (tmp / "rig.yaml").string();
  // Mismatched pair counts, a missing file, a single view, an unknown loss.
  EXPECT_NE(RunCli({"calibrate", "stereo", "--target", target, "--out", out, "--left",
                    Data("left01.jpg"), Data("left02.jpg"), "--right", Data("right01.jpg")}),
            0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images",
                    Data("left99.jpg")}),
            0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images",
                    Data("left01.jpg")}),
            0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--loss", "l1",
                    "--images", Data("left01.jpg"), Data("left02.jpg")}),
            0);
  EXPECT_NE(RunCli({"calibrate", "import", (tmp / "none.yml").string(), "--out", out}), 0);
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(tmp / "rig_report"));
  // Mixed image sizes in one camera's list (640x480 and 1280x1024).
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images",
                    Data("left01.jpg"), Data("left02.jpg"),
                    (testing::SharedDataDir() / "kamino-procam-graycode/capture_0/graycode_40.png")
                        .string()}),
            0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("mismatched image sizes"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(out));
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// The calibration check on real data: kamino's capture_0 (a board, but any scan works) decoded,
// and upstream's two published calibrations checked against it.
TEST(CmdCalibrate, RefineChecksUpstreamKaminoCalibrations) {
  testing::TempDir tmp;
  const auto kamino = testing::SharedDataDir() / "kamino-procam-graycode";
  const Rig first =
      ReadOpenCvCalibration(kamino / "calibration_result_ccf1cd8.xml", 0, 0, 1024, 768);
  const Rig head = ReadOpenCvCalibration(kamino / "calibration_result.xml", 0, 0, 1024, 768);
  const PatternSpec spec =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
  {
    ImageSetWriter writer(tmp / "scan", first, PatternSpecToJson(spec));
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
      writer.Add("camera", i, ReadGrayImage(kamino / "capture_0" / name), 0, ImageSource::kReplay);
    }
    writer.Commit();
  }
  DecodeOptions decode;
  const ProjectorMap map =
      DecodePatterns(spec, ImageSet::Open(tmp / "scan").LoadCamera("camera"), decode);
  const auto corr = SampleCorrespondences(map);
  const EpipolarStats a = EpipolarResiduals(first, 0, corr);
  const EpipolarStats b = EpipolarResiduals(head, 0, corr);
  std::printf(
      "upstream ccf1cd8: epipolar median %.3f px p95 %.3f px; HEAD: median %.3f px p95 %.3f px (%d "
      "correspondences)\n",
      a.median_px, a.p95_px, b.median_px, b.p95_px, a.count);
  SaveRig(first, tmp / "first.yaml");
  ASSERT_EQ(RunCli({"calibrate", "refine", "--rig", (tmp / "first.yaml").string(), "--imageset",
                    (tmp / "scan").string(), "--out", (tmp / "refined.yaml").string()}),
            0);
  const Rig refined = LoadRig(tmp / "refined.yaml");
  EXPECT_LE(refined.calibration["refine"]["after_median_px"].get<double>(),
            refined.calibration["refine"]["before_median_px"].get<double>() + 1e-9);
  EXPECT_NEAR(refined.calibration["refine"]["before_median_px"].get<double>(), a.median_px, 1e-9);
  // The baseline length is kept.
  EXPECT_NEAR(refined.BaselineMm(refined.cameras[0], *refined.projector),
              first.BaselineMm(first.cameras[0], *first.projector), 1e-6);
  EXPECT_NE(RunCli({"calibrate", "refine", "--rig", (tmp / "first.yaml").string(), "--imageset",
                    (tmp / "missing").string(), "--out", (tmp / "x.yaml").string()}),
            0);
}

// `calibrate refine --stereo NAME --refine-focal` end to end on a simulated scan: the demo scene
// rendered for the demo rig (cameras at half resolution, 960x600, to keep the scan small), then
// the right camera bumped (0.2 degree, 1 mm) and its focal length made 0.5 % too long in the rig
// file; the refined rig file must bring focal length and pose back and keep the baseline length.
TEST(CmdCalibrate, RefineStereoWithFocalLengthOnSimulatedScan) {
  testing::TempDir tmp;
  Rig truth = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  for (auto& c : truth.cameras) {
    c.model.width /= 2;
    c.model.height /= 2;
    c.model.params[CameraModel::kFx] /= 2;
    c.model.params[CameraModel::kFy] /= 2;
    c.model.params[CameraModel::kCx] = (c.model.params[CameraModel::kCx] + 0.5) / 2 - 0.5;
    c.model.params[CameraModel::kCy] = (c.model.params[CameraModel::kCy] + 0.5) / 2 - 0.5;
  }
  SaveRig(truth, tmp / "truth.yaml");
  ASSERT_EQ(RunCli({"simulate", "--rig", (tmp / "truth.yaml").string(), "--scene",
                    (testing::SourceDir() / "config/demo/scene.yaml").string(), "--patterns",
                    (testing::SourceDir() / "config/demo/patterns.yaml").string(), "--out",
                    (tmp / "scan").string(), "--encoding", "pgm", "--no-ground-truth", "--quiet"}),
            0);
  Rig bumped = truth;
  const Eigen::Quaterniond turn(
      Eigen::AngleAxisd(0.2 * M_PI / 180, Eigen::Vector3d(0.3, 1.0, 0.2).normalized()));
  bumped.cameras[1].cam_from_rig =
      Rigid3d(turn, Eigen::Vector3d(0.6, -0.8, 0.0)) * truth.cameras[1].cam_from_rig;
  bumped.cameras[1].model.params[CameraModel::kFx] *= 1.005;
  bumped.cameras[1].model.params[CameraModel::kFy] *= 1.005;
  SaveRig(bumped, tmp / "bumped.yaml");
  ASSERT_EQ(RunCli({"calibrate", "refine", "--rig", (tmp / "bumped.yaml").string(), "--imageset",
                    (tmp / "scan").string(), "--camera", "left", "--stereo", "right",
                    "--refine-focal", "--out", (tmp / "refined.yaml").string()}),
            0);
  const Rig refined = LoadRig(tmp / "refined.yaml");
  const auto& info = refined.calibration["refine"];
  const double f_err = refined.cameras[1].model.fx() / truth.cameras[1].model.fx() - 1;
  const Rigid3d t10 = truth.cameras[1].cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  const Rigid3d r10 = refined.cameras[1].cam_from_rig * refined.cameras[0].cam_from_rig.Inverse();
  const double direction_err =
      std::acos(
          std::clamp(r10.translation.normalized().dot(t10.translation.normalized()), -1.0, 1.0)) *
      180 / M_PI;
  std::printf(
      "refine --stereo --refine-focal: median %.3f -> %.3f px, focal scale %.5f, focal error %+.4f "
      "%%, rotation error "
      "%.4f deg, baseline direction error %.4f deg\n",
      info["before_median_px"].get<double>(), info["after_median_px"].get<double>(),
      info["focal_scale"].get<double>(), 100 * f_err,
      r10.rotation.angularDistance(t10.rotation) * 180 / M_PI, direction_err);
  EXPECT_GT(info["before_median_px"].get<double>(), 5 * info["after_median_px"].get<double>());
  EXPECT_LT(std::abs(f_err), 0.0005);  // 0.5 % error brought to within 0.05 %
  EXPECT_LT(r10.rotation.angularDistance(t10.rotation) * 180 / M_PI, 0.01);
  EXPECT_LT(direction_err, 0.05);
  // The scale comes from the rig file's baseline, which is kept.
  EXPECT_NEAR(refined.BaselineMm(refined.cameras[0], refined.cameras[1]),
              bumped.BaselineMm(bumped.cameras[0], bumped.cameras[1]), 1e-6);
  EXPECT_EQ(refined.cameras[0].model.params, truth.cameras[0].model.params);
  // The scale was not verified (the rig file's baseline is kept) ...
  EXPECT_FALSE(info["scale_verified"].get<bool>());
  // ... unless a known baseline sets it.
  const double true_baseline = truth.BaselineMm(truth.cameras[0], truth.cameras[1]);
  ASSERT_EQ(
      RunCli({"calibrate", "refine", "--rig", (tmp / "bumped.yaml").string(), "--imageset",
              (tmp / "scan").string(), "--camera", "left", "--stereo", "right", "--baseline-mm",
              std::to_string(true_baseline), "--out", (tmp / "scaled.yaml").string()}),
      0);
  const Rig scaled = LoadRig(tmp / "scaled.yaml");
  EXPECT_TRUE(scaled.calibration["refine"]["scale_verified"].get<bool>());
  EXPECT_NEAR(scaled.BaselineMm(scaled.cameras[0], scaled.cameras[1]), true_baseline, 1e-3);
  EXPECT_NE(RunCli({"calibrate", "refine", "--rig", (tmp / "bumped.yaml").string(), "--imageset",
                    (tmp / "scan").string(), "--camera", "left", "--stereo", "right",
                    "--known-distance", "1,2,3", "--out", (tmp / "bad.yaml").string()}),
            0);
  // ... or a distance measured between two scene points: two left pixels 300 px apart on the part,
  // their distance triangulated with the true rig (midpoint of the rays), and a rig file whose
  // baseline is 3 % too long.
  {
    const ImageSet scan = ImageSet::Open(tmp / "scan");
    const PatternSpec spec =
        PatternSpecFromConfig(ConfigNode::FromJson(scan.patterns(), "manifest.json", "patterns"));
    const ProjectorMap left = DecodePatterns(spec, scan.LoadCamera("left"));
    const ProjectorMap right = DecodePatterns(spec, scan.LoadCamera("right"));
    const auto point = [&](const Correspondence& c) {
      const CameraModel &ma = truth.cameras[0].model, &mb = truth.cameras[1].model;
      const Eigen::Vector2d a = *ma.UndistortToNormalized(c.camera_px),
                            b = *mb.UndistortToNormalized(c.projector_px);
      const Rigid3d rig_from_a = truth.cameras[0].cam_from_rig.Inverse(),
                    rig_from_b = truth.cameras[1].cam_from_rig.Inverse();
      const Eigen::Vector3d oa = rig_from_a.translation, ob = rig_from_b.translation;
      const Eigen::Vector3d da = rig_from_a.rotation * Eigen::Vector3d(a.x(), a.y(), 1);
      const Eigen::Vector3d db = rig_from_b.rotation * Eigen::Vector3d(b.x(), b.y(), 1);
      Eigen::Matrix<double, 3, 2> m;
      m << da, -db;
      const Eigen::Vector2d t = (m.transpose() * m).ldlt().solve(m.transpose() * (ob - oa));
      return Eigen::Vector3d(0.5 * (oa + t.x() * da + ob + t.y() * db));
    };
    std::vector<Correspondence> ends;
    for (int x0 : {left.width() / 2 - 150, left.width() / 2 + 150}) {
      for (int dy = 0; dy < 200 && static_cast<int>(ends.size()) < (x0 < left.width() / 2 ? 1 : 2);
           ++dy) {
        const auto c = CorrespondenceAt(left, &right, Eigen::Vector2d(x0, left.height() / 2 + dy));
        if (c) ends.push_back(*c);
      }
    }
    ASSERT_EQ(ends.size(), 2u);
    const double distance = (point(ends[0]) - point(ends[1])).norm();
    Rig long_baseline = truth;
    long_baseline.cameras[1].cam_from_rig.translation *= 1.03;  // the left camera is the rig frame
    SaveRig(long_baseline, tmp / "long_baseline.yaml");
    char known[160];
    std::snprintf(known, sizeof(known), "%.0f,%.0f,%.0f,%.0f,%.6f", ends[0].camera_px.x(),
                  ends[0].camera_px.y(), ends[1].camera_px.x(), ends[1].camera_px.y(), distance);
    ASSERT_EQ(
        RunCli({"calibrate", "refine", "--rig", (tmp / "long_baseline.yaml").string(), "--imageset",
                (tmp / "scan").string(), "--camera", "left", "--stereo", "right",
                "--known-distance", known, "--out", (tmp / "by_distance.yaml").string()}),
        0);
    const Rig by_distance = LoadRig(tmp / "by_distance.yaml");
    const double baseline = by_distance.BaselineMm(by_distance.cameras[0], by_distance.cameras[1]);
    std::printf("known distance %.3f mm: baseline %.3f mm (truth %.3f mm, rig file %.3f mm)\n",
                distance, baseline, true_baseline,
                long_baseline.BaselineMm(long_baseline.cameras[0], long_baseline.cameras[1]));
    EXPECT_TRUE(by_distance.calibration["refine"]["scale_verified"].get<bool>());
    EXPECT_NEAR(baseline / true_baseline, 1.0, 0.002);
  }
  // A rig without a projector and no --stereo: the error points at --stereo, nothing is written.
  Rig cameras_only = truth;
  cameras_only.projector.reset();
  SaveRig(cameras_only, tmp / "cameras_only.yaml");
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"calibrate", "refine", "--rig", (tmp / "cameras_only.yaml").string(),
                    "--imageset", (tmp / "scan").string(), "--out", (tmp / "bad.yaml").string()}),
            0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(
      err.find("has no projector: refine the pose of one camera against another with --stereo"),
      std::string::npos)
      << err;
  // A twisted pair (the right camera turned 180 degrees about the baseline) fits the same epipolar
  // geometry: refused for cheirality, nothing written.
  Rig twisted = truth;
  const Rigid3d r10_true = truth.cameras[1].cam_from_rig * truth.cameras[0].cam_from_rig.Inverse();
  twisted.cameras[1].cam_from_rig =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI, r10_true.translation.normalized())),
              Eigen::Vector3d::Zero()) *
      truth.cameras[1].cam_from_rig;
  SaveRig(twisted, tmp / "twisted.yaml");
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"calibrate", "refine", "--rig", (tmp / "twisted.yaml").string(), "--imageset",
                    (tmp / "scan").string(), "--camera", "left", "--stereo", "right", "--out",
                    (tmp / "bad.yaml").string()}),
            0);
  const std::string twisted_err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(twisted_err.find("cheirality"), std::string::npos) << twisted_err;
  EXPECT_FALSE(std::filesystem::exists(tmp / "bad.yaml"));
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// Kamino's five captures written once per suite as ImageSets (one per board pose, PGM), for the
// `calibrate rig` tests below.
class CmdCalibrateKamino : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    sets_ = new testing::TempDir;
    const auto kamino = testing::SharedDataDir() / "kamino-procam-graycode";
    const PatternSpec spec =
        LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
    const Rig nominal =
        ReadOpenCvCalibration(kamino / "calibration_result_ccf1cd8.xml", 0, 0, 1024, 768);
    for (int p = 0; p < 5; ++p) {
      ImageSetWriterOptions wo;
      wo.encoding = ImageEncoding::kPgm;
      ImageSetWriter writer(ImageSetDir(p), nominal, PatternSpecToJson(spec), wo);
      for (int i = 0; i < spec.NumImages(); ++i) {
        char name[32];
        std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
        writer.Add("camera", i, ReadGrayImage(kamino / ("capture_" + std::to_string(p)) / name), 0,
                   ImageSource::kReplay);
      }
      writer.Commit();
    }
  }
  static void TearDownTestSuite() {
    delete sets_;
    sets_ = nullptr;
  }
  static std::filesystem::path ImageSetDir(int pose) {
    return *sets_ / ("pose" + std::to_string(pose));
  }
  static std::string Target() {
    return (testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml").string();
  }

 private:
  static testing::TempDir* sets_;
};
testing::TempDir* CmdCalibrateKamino::sets_ = nullptr;

// `calibrate rig` reads one ImageSet per board pose; kamino's five captures written as ImageSets
// must give what `calibrate projector` gives from the plain folders. Both with
// --principal-point-inside (the default solve is run by the --select-model test below): the flag
// reaches the solver and the rig file through either subcommand.
TEST_F(CmdCalibrateKamino, RigFromImageSetsMatchesProjectorFromFolders) {
  testing::TempDir tmp;
  const auto kamino = testing::SharedDataDir() / "kamino-procam-graycode";
  const std::string spec_path =
      (testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml").string();
  const std::string target = Target();
  // The same decoding and model options for both commands; each then names its output and inputs.
  const auto args_for = [&](std::vector<std::string> head, const std::string& out,
                            const std::string& inputs_flag) {
    head.insert(head.end(),
                {"--target", target, "--shadow-threshold", "40", "--contrast-threshold", "5",
                 "--min-views", "5", "--no-cross-validation", "--principal-point-inside"});
    head.insert(head.end(), {"--out", (tmp / out).string(), inputs_flag});
    return head;
  };
  std::vector<std::string> rig_args = args_for({"calibrate", "rig"}, "rig.yaml", "--imagesets");
  std::vector<std::string> proj_args =
      args_for({"calibrate", "projector", "--patterns", spec_path}, "procam.yaml", "--captures");
  for (int p = 0; p < 5; ++p) {
    rig_args.push_back(ImageSetDir(p).string());
    proj_args.push_back((kamino / ("capture_" + std::to_string(p))).string());
  }
  ASSERT_EQ(RunCli(rig_args), 0);
  ASSERT_EQ(RunCli(proj_args), 0);
  const Rig a = LoadRig(tmp / "rig.yaml"), b = LoadRig(tmp / "procam.yaml");
  ASSERT_TRUE(a.projector && b.projector);
  for (int i = 0; i < CameraModel::kNumParams; ++i) {
    EXPECT_NEAR(a.projector->model.params[static_cast<size_t>(i)],
                b.projector->model.params[static_cast<size_t>(i)],
                1e-6 * (1 + std::abs(b.projector->model.params[static_cast<size_t>(i)])));
  }
  EXPECT_LT((a.projector->cam_from_rig.translation - b.projector->cam_from_rig.translation).norm(),
            1e-4);
  EXPECT_LE(a.calibration["summary"]["devices"][1]["rms_px"].get<double>(), 0.43);
  for (const Rig* r : {&a, &b}) {
    EXPECT_TRUE(r->calibration["options"]["principal_point_inside"].get<bool>());
    EXPECT_LE(r->projector->model.cy(), 767.5);
    ASSERT_EQ(r->calibration["summary"]["bounds_active"].size(), 1u);
    EXPECT_EQ(r->calibration["summary"]["bounds_active"][0], "projector cy = 767.5 (upper bound)");
  }
}

// --select-model (eight leave-one-pose-out calibrations, the costly part, so run once; through
// `calibrate rig` on the suite's ImageSets, which shares the selection with `calibrate projector`
// and reads PGM instead of decoding PNG): the chosen model has the lowest prediction RMS of the 8
// candidates, and the rig file's evidence keeps the held parameters.
TEST_F(CmdCalibrateKamino, SelectModelChoosesLowestPredictionError) {
  testing::TempDir tmp;
  std::vector<std::string> args = {"calibrate",
                                   "rig",
                                   "--target",
                                   Target(),
                                   "--shadow-threshold",
                                   "40",
                                   "--contrast-threshold",
                                   "5",
                                   "--min-views",
                                   "5",
                                   "--no-cross-validation",
                                   "--select-model",
                                   "--out",
                                   (tmp / "procam.yaml").string(),
                                   "--imagesets"};
  for (int p = 0; p < 5; ++p) args.push_back(ImageSetDir(p).string());
  ASSERT_EQ(RunCli(args), 0);
  const Rig b = LoadRig(tmp / "procam.yaml");
  ASSERT_TRUE(b.projector);
  EXPECT_LE(b.calibration["summary"]["devices"][1]["rms_px"].get<double>(), 0.43);
  const CalibrationEvidence evidence = CalibrationEvidenceFromJson(b.calibration, "procam.yaml");
  std::ifstream summary_file(tmp / "procam_report" / "summary.json");
  ASSERT_TRUE(summary_file.good());
  const nlohmann::json summary = nlohmann::json::parse(summary_file);
  const auto& selection = summary["extra"]["model_selection"];
  ASSERT_EQ(selection["candidates"].size(), 8u);
  double best = 1e9;
  std::string best_name;
  for (const auto& c : selection["candidates"]) {
    if (c["prediction_rms_px"].get<double>() < best) {
      best = c["prediction_rms_px"].get<double>();
      best_name = c["model"].get<std::string>();
    }
    EXPECT_EQ(c["num_predicted"].get<int>(), 5 * 63);
  }
  EXPECT_EQ(selection["chosen"].get<std::string>(), best_name);
  // Kamino's corner errors correlate across each view: the report quotes the view-correlated
  // covariance for both devices, and its uncertainty maps are wider than the standard ones by the
  // factor the two covariances' maps in the rig file's evidence give.
  for (int d = 0; d < 2; ++d) {
    const auto& dev = summary["devices_result"][d];
    EXPECT_EQ(dev["covariance_used"], "view-correlated") << dev["covariance_reason"];
    const double used = dev["projection_uncertainty"]["median_px"].get<double>();
    const double standard = summary["projection_uncertainty"][d]["median_px"].get<double>();
    const double view =
        summary["projection_uncertainty_view_correlated"][d]["median_px"].get<double>();
    std::printf(
        "%s: uncertainty median %.3f px quoted, standard %.3f px (x%.2f); fx sigma %.2f (standard "
        "%.2f); %s\n",
        dev["name"].get<std::string>().c_str(), used, standard, used / standard,
        dev["params_sigma"][0].get<double>(), dev["params_sigma_standard"][0].get<double>(),
        dev["covariance_reason"].get<std::string>().c_str());
    EXPECT_NEAR(used, view, 1e-9);
    EXPECT_GT(used, 1.5 * standard);
    EXPECT_GT(dev["params_sigma"][0].get<double>(),
              1.5 * dev["params_sigma_standard"][0].get<double>());
  }
  const std::string text = ReadTextFile(tmp / "procam_report" / "report.txt");
  EXPECT_NE(text.find("view-correlated covariance: corner errors correlate"), std::string::npos)
      << text;
  std::printf("chosen: %s, predicted %.4f px; projector held %s\n", best_name.c_str(), best,
              b.calibration["devices"][1]["held_params"].dump().c_str());
  ASSERT_EQ(evidence.input.devices.size(), 2u);
  const std::vector<std::string> names = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"};
  std::vector<std::string> held;
  for (int i : evidence.input.devices[1].held_params)
    held.push_back(names.at(static_cast<size_t>(i)));
  EXPECT_EQ(nlohmann::json(held), b.calibration["devices"][1]["held_params"]);
  EXPECT_LT(best, 0.43);
}

}  // namespace
}  // namespace slshadow
