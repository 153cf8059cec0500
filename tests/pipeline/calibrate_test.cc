// workflows/pipeline/calibrate.cc, the workflows behind `slshadow calibrate`, called as the command
// calls them: the board-detection summary, a stereo calibration of synthetic boards (known truth)
// through to the written rig, OpenCV file and report, and bad input refused before anything is
// written.
// (`calibrate refine` runs RefineRigFromScan to success in tests/apps/cmd_calibrate_test.)
#include "workflows/pipeline/calibrate.h"

#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "calib/calibration_io.h"
#include "calib/synthetic.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::pipeline {
namespace {

namespace fs = std::filesystem;

TEST(DescribeBoardDetections, NamesEachMissAndCountsTheFinds) {
  std::vector<ImageCheck> checks(3);
  checks[0].label = "a.png";
  checks[1].label = "b.png";
  checks[1].found = false;
  checks[1].reason = "no chessboard corners";
  checks[2].label = "c.png";
  EXPECT_EQ(DescribeBoardDetections(checks),
            "not found: b.png: no chessboard corners\nboard found in 2 of 3 images\n");
  EXPECT_EQ(DescribeBoardDetections({}), "board found in 0 of 0 images\n");
}

// 12 poses of the synthetic stereo rig (truth: cam1 150 mm right of cam0, toed in 10 degrees),
// 0.1 px noise: the written rig holds the truth to within the noise's reach, the OpenCV file the
// same pose, the report its files, and what was printed says what was written.
TEST(CalibrateAndWrite, SyntheticStereoWritesTheRigItsOpenCvFileAndTheReport) {
  testing::TempDir tmp;
  const SyntheticRig truth = SyntheticRig::Stereo();
  const SyntheticData data = MakeSyntheticData(truth, 12, 0.1, 7);
  CalibrateWriteOptions options;
  options.rig_name = "synthetic";
  options.rig_out = tmp / "rig.yaml";
  options.report_dir = tmp / "report";
  options.opencv_out = tmp / "stereo.yml";
  options.min_views = 10;
  std::vector<ImageCheck> checks;
  for (const auto& v : data.input.views) {
    ImageCheck c;
    c.label = v.label;
    c.device = v.device;
    checks.push_back(c);
  }
  std::string printed;
  CalibrateAndWrite(data.input, checks, options, {{"target", "synthetic 11x8"}},
                    [&](const std::string& s) { printed += s; });
  const Rig rig = LoadRig(options.rig_out);
  EXPECT_EQ(rig.name, "synthetic");
  ASSERT_EQ(rig.cameras.size(), 2u);
  EXPECT_NEAR(rig.cameras[0].model.fx(), 1400, 2.0);
  EXPECT_NEAR(rig.cameras[1].model.fx(), 1390, 2.0);
  EXPECT_NEAR(rig.BaselineMm(rig.cameras[0], rig.cameras[1]), 150, 0.5);
  const Rigid3d truth_10 = truth.devices[1].cam_from_rig;
  const Rigid3d got_10 = rig.cameras[1].cam_from_rig * rig.cameras[0].cam_from_rig.Inverse();
  EXPECT_LT(Eigen::AngleAxisd(truth_10.rotation.inverse() * got_10.rotation).angle() * 180 / M_PI,
            0.05);
  // The evidence is in the rig file; the OpenCV file carries the same pose.
  EXPECT_EQ(rig.calibration["format"], "slshadow-calibration-evidence");
  EXPECT_EQ(rig.calibration["views"].size(), data.input.views.size());
  EXPECT_TRUE(rig.calibration.contains("cross_validation"));
  const Rig cv_rig = ReadOpenCvCalibration(options.opencv_out);
  EXPECT_NEAR((cv_rig.cameras[1].cam_from_rig.translation - got_10.translation).norm(), 0, 1e-6);
  for (const char* f :
       {"summary.json", "report.txt", "per_view_rms.png", "cross_validation_cam0.png"}) {
    EXPECT_TRUE(fs::exists(options.report_dir / f)) << f;
  }
  for (const std::string& line : {std::string("  cam0: 1280x1024 fx "), std::string("  cam1: RMS "),
                                  "wrote " + options.rig_out.string() + " and report " +
                                      options.report_dir.string() + "\n"}) {
    EXPECT_NE(printed.find(line), std::string::npos) << line << "\n" << printed;
  }
  EXPECT_EQ(printed.find("cross-validation skipped"), std::string::npos) << printed;

  // Too few poses to split into even and odd halves: said, and the rest still written.
  const SyntheticData few = MakeSyntheticData(truth, 3, 0.1, 8);
  options.rig_out = tmp / "few.yaml";
  options.report_dir = tmp / "few_report";
  options.opencv_out.clear();
  printed.clear();
  CalibrateAndWrite(few.input, {}, options, nlohmann::json::object(),
                    [&](const std::string& s) { printed += s; });
  EXPECT_NE(printed.find("cross-validation skipped"), std::string::npos) << printed;
  EXPECT_TRUE(fs::exists(tmp / "few.yaml"));
}

// A count of angles that does not match the folders is refused, naming both counts, and no rig is
// written.
TEST(CalibrateTurntableAndWrite, AnglesNotMatchingTheFoldersAreRefusedBeforeWriting) {
  testing::TempDir tmp;
  CalibrateTurntableRequest request;
  request.rig = testing::SourceDir() / "config/demo/rig.yaml";
  request.target = testing::SourceDir() / "config/targets/opencv-stereo-chessboard.yaml";
  request.out = tmp / "out.yaml";
  request.folders = {tmp / "a", tmp / "b"};
  request.commanded_deg = {0};
  std::string printed;
  try {
    CalibrateTurntableAndWrite(request, [&](const std::string& s) { printed += s; });
    ADD_FAILURE() << "accepted 1 angle for 2 folders";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("--angles: 1 angle(s) for 2 --images folder(s)"),
              std::string::npos)
        << e.what();
  }
  EXPECT_FALSE(fs::exists(request.out));
  EXPECT_EQ(printed, "");
}

// A scan RefineRigFromScan cannot use is refused naming the file and what is wrong, and no rig is
// written: a camera the rig does not have, patterns coding one projector axis, a rig without a
// projector and no --stereo camera. (A small blank Gray-code scan: the checks come before any
// decoding.)
TEST(RefineRigFromScan, UnusableRequestsAreRefusedNamingTheFileAndWriteNothing) {
  testing::TempDir tmp;
  Rig rig;
  rig.name = "small";
  rig.working_distance_mm = 500;
  rig.cameras.push_back({"cam", CameraModel(64, 48, 80, 80, 32, 24), Rigid3d()});
  rig.projector = RigDevice{"projector", CameraModel(32, 24, 40, 40, 16, 12),
                            Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(-100, 0, 0))};
  SaveRig(rig, tmp / "rig.yaml");
  const auto write_scan = [&](const fs::path& dir, bool code_y) {
    PatternSpec spec;
    spec.kind = PatternKind::kGrayCode;
    spec.projector_width = 32;
    spec.projector_height = 24;
    spec.code_y = code_y;
    ImageSetWriter writer(dir, rig, PatternSpecToJson(spec));
    for (int i = 0; i < spec.NumImages(); ++i) {
      writer.Add("cam", i, cv::Mat(48, 64, CV_8UC1, cv::Scalar(100)), 0, ImageSource::kReplay);
    }
    writer.Commit();
  };
  write_scan(tmp / "scan", true);
  write_scan(tmp / "scan_x", false);
  const auto refused = [&](RefineFromScanRequest request, const std::string& expected) {
    request.out = tmp / "out.yaml";
    try {
      RefineRigFromScan(request);
      ADD_FAILURE() << "accepted; expected: " << expected;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
    EXPECT_FALSE(fs::exists(tmp / "out.yaml")) << expected;
  };
  RefineFromScanRequest request;
  request.rig = tmp / "rig.yaml";
  request.scan = tmp / "scan";
  request.camera = "nope";
  refused(request, (tmp / "rig.yaml").string() + ": no camera named 'nope'");
  request.camera.clear();
  request.scan = tmp / "scan_x";
  refused(request, (tmp / "scan_x").string() + ": patterns must code both projector axes");
  rig.projector.reset();
  SaveRig(rig, tmp / "cameras.yaml");
  request.rig = tmp / "cameras.yaml";
  request.scan = tmp / "scan";
  refused(request, "has no projector: refine the pose of one camera against another with --stereo");
}

}  // namespace
}  // namespace slshadow::pipeline
