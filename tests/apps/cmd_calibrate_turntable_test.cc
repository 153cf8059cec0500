// `slshadow calibrate turntable` end to end (apps/cmd_calibrate_turntable.cc): the known table of
// tests/testing/turntable_fixture.h in the demo rig, its chessboard rendered by sim/ at nine
// commanded angles (each camera alone, lit from beside it, sensor noise on), written as one
// folder of PNGs per angle, detected by the real detector, calibrated and written into the rig.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "core/image_io.h"
#include "core/rig.h"
#include "sim/shapes.h"
#include "sim/simulate.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"
#include "tests/testing/turntable_fixture.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;
using slshadow::testing::RunCli;
constexpr double kDeg = M_PI / 180;

class CmdCalibrateTurntable : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir();
    truth_ = new testing::SimTurntable(testing::MakeSimTurntable());
    const auto& t = *truth_;
    SaveRig(t.rig, *tmp_ / "rig.yaml");
    std::ofstream(*tmp_ / "board.yaml")
        << "format: slshadow-target\nversion: 1\ntype: chessboard\ncols: " << t.board.cols
        << "\nrows: " << t.board.rows << "\nsquare_size_mm: " << t.board.square_size_mm
        << "\ndetector: classic\n";
    RigDevice light;  // a wide light beside the camera rendered: one white frame
    light.name = "projector";
    light.model = CameraModel(64, 48, 16, 16, 32, 24);
    const cv::Mat white(48, 64, CV_8UC1, cv::Scalar(255));
    for (size_t p = 0; p < t.angles_deg.size(); ++p) {
      const fs::path dir = *tmp_ / std::to_string(static_cast<int>(t.angles_deg[p]));
      fs::create_directories(dir);
      folders_.push_back(dir.string());
      const Rigid3d rig_from_board = t.RigFromBoard(t.angles_deg[p]);
      for (size_t c = 0; c < t.rig.cameras.size(); ++c) {
        Rig rig;
        rig.name = "sim";
        rig.cameras = {t.rig.cameras[c]};
        light.cam_from_rig = Rigid3d(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0, 30, 0)) *
                             rig.cameras[0].cam_from_rig;
        rig.projector = light;
        BoardScene scene = MakeCheckerboardScene(t.board.cols, t.board.rows, t.board.square_size_mm,
                                                 rig_from_board);
        scene.scene.layers.supersampling = 1;
        scene.scene.layers.ambient = 0.3;
        scene.scene.layers.noise_enabled = true;
        scene.scene.layers.seed = static_cast<uint32_t>(500 + 2 * p + c);
        const double d = (rig_from_board.translation - light.CenterInRig()).norm();
        scene.scene.radiometry.exposure_fraction = 0.6 * (d / 500) * (d / 500);
        const auto images = RenderScan(scene.scene, rig, {white});
        WriteImage(dir / (t.rig.cameras[c].name + ".png"), images[0][0]);
      }
    }
  }
  static void TearDownTestSuite() {
    delete truth_;
    delete tmp_;
  }

  static std::vector<std::string> Args(const std::string& out) {
    std::vector<std::string> args = {"calibrate", "turntable",
                                     "--rig",     (*tmp_ / "rig.yaml").string(),
                                     "--target",  (*tmp_ / "board.yaml").string(),
                                     "--out",     out,
                                     "--images"};
    args.insert(args.end(), folders_.begin(), folders_.end());
    return args;
  }

  static testing::TempDir* tmp_;
  static testing::SimTurntable* truth_;
  static std::vector<std::string> folders_;
};

testing::TempDir* CmdCalibrateTurntable::tmp_ = nullptr;
testing::SimTurntable* CmdCalibrateTurntable::truth_ = nullptr;
std::vector<std::string> CmdCalibrateTurntable::folders_;

TEST_F(CmdCalibrateTurntable, WritesTheAxisIntoTheRig) {
  const auto& t = *truth_;
  const std::string out = (*tmp_ / "with_table.yaml").string();
  ::testing::internal::CaptureStdout();
  ASSERT_EQ(RunCli(Args(out)), 0);
  const std::string printed = ::testing::internal::GetCapturedStdout();
  std::printf("%s", printed.c_str());
  EXPECT_NE(printed.find("axis (rig frame, 1-sigma):"), std::string::npos);
  EXPECT_NE(printed.find("wrote " + out), std::string::npos);
  const Rig rig = LoadRig(out);
  ASSERT_TRUE(rig.turntable.has_value());
  const TurntableAxis& a = *rig.turntable;
  // The cameras are the input's, untouched.
  ASSERT_EQ(rig.cameras.size(), t.rig.cameras.size());
  EXPECT_EQ(rig.cameras[1].model.params, t.rig.cameras[1].model.params);
  // Against the truth, through rendering and the real detector: corner errors are not exactly
  // independent Gaussians (the detector's small biases), so the bounds are 3x the corner-level
  // test's (tests/calib/turntable_test.cc) and each error must also stay within 4 stated sigma.
  const Eigen::Vector3d& n = t.axis.direction_in_rig;
  const double direction_deg =
      std::atan2(n.cross(a.direction_in_rig).norm(), n.dot(a.direction_in_rig)) / kDeg;
  const Eigen::Vector3d d = a.point_in_rig_mm - t.axis.point_in_rig_mm;
  const double point_mm = (d - n * n.dot(d)).norm();
  const double turn_deg = std::abs((a.angle_scale - t.axis.angle_scale) * 80);
  std::printf("errors: direction %.5f deg, point %.5f mm, 80 deg turn %.5f deg\n", direction_deg,
              point_mm, turn_deg);
  EXPECT_LT(direction_deg, 0.015);
  EXPECT_LT(point_mm, 0.03);
  EXPECT_LT(turn_deg, 0.015);
  EXPECT_LT(direction_deg, 4 * a.sigma_direction_deg);
  EXPECT_LT(point_mm, 4 * a.sigma_point_mm);
  EXPECT_LT(std::abs(a.angle_scale - t.axis.angle_scale), 4 * a.sigma_angle_scale);
  EXPECT_EQ(a.angle_offset_deg, 0.0);

  // The same with the angles given explicitly, from folders whose names are not angles.
  std::vector<std::string> renamed;
  std::string angles;
  for (size_t p = 0; p < folders_.size(); ++p) {
    const fs::path dir = *tmp_ / ("view" + std::to_string(p));
    fs::create_directories(dir);
    for (const auto& e : fs::directory_iterator(folders_[p]))
      fs::copy_file(e.path(), dir / e.path().filename());
    renamed.push_back(dir.string());
    angles += (p ? "," : "") + std::to_string(t.angles_deg[p]);
  }
  const std::string out2 = (*tmp_ / "with_table2.yaml").string();
  std::vector<std::string> args = {"calibrate", "turntable",
                                   "--rig",     (*tmp_ / "rig.yaml").string(),
                                   "--target",  (*tmp_ / "board.yaml").string(),
                                   "--out",     out2,
                                   "--angles",  angles,
                                   "--images"};
  args.insert(args.end(), renamed.begin(), renamed.end());
  ::testing::internal::CaptureStdout();
  ASSERT_EQ(RunCli(args), 0);
  ::testing::internal::GetCapturedStdout();
  const TurntableAxis b = *LoadRig(out2).turntable;
  EXPECT_LT((b.direction_in_rig - a.direction_in_rig).norm(), 1e-12);
  EXPECT_NEAR(b.angle_scale, a.angle_scale, 1e-12);
}

std::string FailureOf(const std::vector<std::string>& args) {
  ::testing::internal::CaptureStdout();
  ::testing::internal::CaptureStderr();
  const int code = RunCli(args);
  ::testing::internal::GetCapturedStdout();
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(code, 0) << err;
  return err;
}

TEST_F(CmdCalibrateTurntable, RefusesBadInputAndWritesNothing) {
  const std::string out = (*tmp_ / "refused.yaml").string();
  {  // two angles
    auto args = Args(out);
    args.resize(args.size() - folders_.size() + 2);
    EXPECT_NE(FailureOf(args).find("the axis needs the board at 3 or more different table angles"),
              std::string::npos);
  }
  {  // all angles equal
    auto args = Args(out);
    std::string same = "5";
    for (size_t i = 1; i < folders_.size(); ++i) same += ",5";
    args.insert(args.end() - static_cast<long>(folders_.size()) - 1, {"--angles", same});
    const std::string e = FailureOf(args);
    EXPECT_NE(e.find("1 distinct commanded angle(s)"), std::string::npos) << e;
  }
  {  // a count mismatch
    auto args = Args(out);
    args.insert(args.end() - static_cast<long>(folders_.size()) - 1, {"--angles", "0,10,20"});
    const std::string e = FailureOf(args);
    EXPECT_NE(e.find("--angles: 3 angle(s) for " + std::to_string(folders_.size()) +
                     " --images folder(s)"),
              std::string::npos)
        << e;
  }
  {  // a folder where no camera finds the board
    const fs::path blank = *tmp_ / "25";
    fs::create_directories(blank);
    WriteImage(blank / "left.png", cv::Mat(1200, 1920, CV_8UC1, cv::Scalar(128)));
    auto args = Args(out);
    args.push_back(blank.string());
    const std::string err = FailureOf(args);
    EXPECT_NE(err.find(blank.string() + ": the board was not found in any image (left.png: "),
              std::string::npos)
        << err;
  }
  {  // a folder with no image of a rig camera
    const fs::path other = *tmp_ / "35";
    fs::create_directories(other);
    WriteImage(other / "centre.png", cv::Mat(12, 19, CV_8UC1, cv::Scalar(128)));
    auto args = Args(out);
    args.push_back(other.string());
    EXPECT_NE(FailureOf(args).find(other.string() + ": no image named after a rig camera"),
              std::string::npos);
  }
  EXPECT_FALSE(fs::exists(out));
}

}  // namespace
}  // namespace slshadow
