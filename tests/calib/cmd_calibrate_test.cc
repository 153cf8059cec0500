// The `slshadow calibrate` subcommand end to end (apps/cmd_calibrate.cc), on real data.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "calib/calibration_io.h"
#include "calib/refine.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "core/file_util.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

int RunCli(std::vector<std::string> args) {
  args.insert(args.begin(), "slshadow");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  return app::Main(static_cast<int>(argv.size()), argv.data());
}

std::string Data(const std::string& name) { return (testing::SharedDataDir() / "opencv-stereo-chessboard" / name).string(); }

TEST(CmdCalibrate, StereoWritesRigReportAndOpenCvFile) {
  testing::TempDir tmp;
  const std::string target = (testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml").string();
  std::vector<std::string> args = {"calibrate", "stereo", "--target", target, "--fix-aspect", "--out", (tmp / "rig.yaml").string(),
                                   "--opencv-out", (tmp / "stereo.yml").string(), "--left"};
  const std::vector<int> ids = {1, 2, 3, 4, 5, 6, 7, 8, 9, 11, 12, 13, 14};
  for (int i : ids) args.push_back(Data("left" + std::string(i < 10 ? "0" : "") + std::to_string(i) + ".jpg"));
  args.push_back("--right");
  for (int i : ids) args.push_back(Data("right" + std::string(i < 10 ? "0" : "") + std::to_string(i) + ".jpg"));
  ASSERT_EQ(RunCli(args), 0);
  const Rig rig = LoadRig(tmp / "rig.yaml");
  ASSERT_EQ(rig.cameras.size(), 2u);
  EXPECT_EQ(rig.cameras[0].name, "left");
  EXPECT_NEAR(rig.cameras[0].model.fx(), 535.9, 2.0);
  EXPECT_NEAR(rig.BaselineMm(rig.cameras[0], rig.cameras[1]), 83.4, 1.0);
  // The evidence recomputes the same calibration.
  const CalibrationEvidence ev = CalibrationEvidenceFromJson(rig.calibration, "rig.yaml");
  EXPECT_TRUE(ev.options.fix_aspect_ratio);
  EXPECT_NEAR(Calibrate(ev.input, ev.options).devices[1].model.fx(), rig.cameras[1].model.fx(), 1e-6);
  for (const char* f : {"summary.json", "report.txt", "per_view_rms.png", "residuals_left.png", "uncertainty_right.png",
                        "cross_validation_left.png"}) {
    EXPECT_TRUE(std::filesystem::exists(tmp / "rig_report" / f)) << f;
  }
  const Rig cv_rig = ReadOpenCvCalibration(tmp / "stereo.yml");
  EXPECT_NEAR(cv_rig.cameras[1].cam_from_rig.translation.x(), rig.cameras[1].cam_from_rig.translation.x(), 1e-9);
  // Export / import round trip through the CLI.
  ASSERT_EQ(RunCli({"calibrate", "export", (tmp / "rig.yaml").string(), "--out", (tmp / "exported.xml").string()}), 0);
  ASSERT_EQ(RunCli({"calibrate", "import", (tmp / "exported.xml").string(), "--out", (tmp / "imported.yaml").string()}), 0);
  EXPECT_NEAR(LoadRig(tmp / "imported.yaml").cameras[1].model.cy(), rig.cameras[1].model.cy(), 1e-9);
}

TEST(CmdCalibrate, BadInputsFailWithoutWriting) {
  testing::TempDir tmp;
  const std::string target = (testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml").string();
  const std::string out = (tmp / "rig.yaml").string();
  // Mismatched pair counts, a missing file, a single view, an unknown loss.
  EXPECT_NE(RunCli({"calibrate", "stereo", "--target", target, "--out", out, "--left", Data("left01.jpg"), Data("left02.jpg"),
                 "--right", Data("right01.jpg")}), 0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images", Data("left99.jpg")}), 0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images", Data("left01.jpg")}), 0);
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--loss", "l1", "--images", Data("left01.jpg"),
                 Data("left02.jpg")}), 0);
  EXPECT_NE(RunCli({"calibrate", "import", (tmp / "none.yml").string(), "--out", out}), 0);
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(tmp / "rig_report"));
  // Mixed image sizes in one camera's list (640x480 and 1280x1024).
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"calibrate", "camera", "--target", target, "--out", out, "--images", Data("left01.jpg"), Data("left02.jpg"),
                    (testing::SharedDataDir() / "kamino-procam-graycode/capture_0/graycode_40.png").string()}), 0);
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
  const Rig first = ReadOpenCvCalibration(kamino / "calibration_result_ccf1cd8.xml", 0, 0, 1024, 768);
  const Rig head = ReadOpenCvCalibration(kamino / "calibration_result.xml", 0, 0, 1024, 768);
  const PatternSpec spec = LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
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
  const ProjectorMap map = DecodePatterns(spec, ImageSet::Open(tmp / "scan").LoadCamera("camera"), decode);
  const auto corr = SampleCorrespondences(map);
  const EpipolarStats a = EpipolarResiduals(first, 0, corr);
  const EpipolarStats b = EpipolarResiduals(head, 0, corr);
  std::printf("upstream ccf1cd8: epipolar median %.3f px p95 %.3f px; HEAD: median %.3f px p95 %.3f px (%d correspondences)\n",
              a.median_px, a.p95_px, b.median_px, b.p95_px, a.count);
  SaveRig(first, tmp / "first.yaml");
  ASSERT_EQ(RunCli({"calibrate", "refine", "--rig", (tmp / "first.yaml").string(), "--imageset", (tmp / "scan").string(),
                    "--out", (tmp / "refined.yaml").string()}), 0);
  const Rig refined = LoadRig(tmp / "refined.yaml");
  EXPECT_LE(refined.calibration["refine"]["after_median_px"].get<double>(),
            refined.calibration["refine"]["before_median_px"].get<double>() + 1e-9);
  EXPECT_NEAR(refined.calibration["refine"]["before_median_px"].get<double>(), a.median_px, 1e-9);
  // The baseline length is kept.
  EXPECT_NEAR(refined.BaselineMm(refined.cameras[0], *refined.projector), first.BaselineMm(first.cameras[0], *first.projector), 1e-6);
  EXPECT_NE(RunCli({"calibrate", "refine", "--rig", (tmp / "first.yaml").string(), "--imageset", (tmp / "missing").string(),
                    "--out", (tmp / "x.yaml").string()}), 0);
}

}  // namespace
}  // namespace slshadow

namespace slshadow {
namespace {

// `calibrate rig` reads one ImageSet per board pose; kamino's five captures written as ImageSets
// must give what `calibrate projector` gives from the plain folders.
TEST(CmdCalibrate, RigFromImageSetsMatchesProjectorFromFolders) {
  testing::TempDir tmp;
  const auto kamino = testing::SharedDataDir() / "kamino-procam-graycode";
  const std::string spec_path = (testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml").string();
  const std::string target = (testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml").string();
  const PatternSpec spec = LoadPatternSpec(spec_path);
  const Rig nominal = ReadOpenCvCalibration(kamino / "calibration_result_ccf1cd8.xml", 0, 0, 1024, 768);
  std::vector<std::string> rig_args = {"calibrate", "rig", "--target", target, "--shadow-threshold", "40",
                                       "--contrast-threshold", "5", "--min-views", "5", "--no-cross-validation",
                                       "--out", (tmp / "rig.yaml").string(), "--imagesets"};
  std::vector<std::string> proj_args = {"calibrate", "projector", "--target", target, "--patterns", spec_path,
                                        "--shadow-threshold", "40", "--contrast-threshold", "5", "--min-views", "5",
                                        "--no-cross-validation", "--out", (tmp / "procam.yaml").string(), "--captures"};
  for (int p = 0; p < 5; ++p) {
    const auto dir = tmp / ("pose" + std::to_string(p));
    ImageSetWriterOptions wo;
    wo.encoding = ImageEncoding::kPgm;
    ImageSetWriter writer(dir, nominal, PatternSpecToJson(spec), wo);
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
      writer.Add("camera", i, ReadGrayImage(kamino / ("capture_" + std::to_string(p)) / name), 0, ImageSource::kReplay);
    }
    writer.Commit();
    rig_args.push_back(dir.string());
    proj_args.push_back((kamino / ("capture_" + std::to_string(p))).string());
  }
  ASSERT_EQ(RunCli(rig_args), 0);
  ASSERT_EQ(RunCli(proj_args), 0);
  const Rig a = LoadRig(tmp / "rig.yaml"), b = LoadRig(tmp / "procam.yaml");
  ASSERT_TRUE(a.projector && b.projector);
  for (int i = 0; i < CameraModel::kNumParams; ++i) {
    EXPECT_NEAR(a.projector->model.params[static_cast<size_t>(i)], b.projector->model.params[static_cast<size_t>(i)],
                1e-6 * (1 + std::abs(b.projector->model.params[static_cast<size_t>(i)])));
  }
  EXPECT_LT((a.projector->cam_from_rig.translation - b.projector->cam_from_rig.translation).norm(), 1e-4);
  EXPECT_LE(a.calibration["summary"]["devices"][1]["rms_px"].get<double>(), 0.43);
}

}  // namespace
}  // namespace slshadow
