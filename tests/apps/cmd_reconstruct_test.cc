// The `slshadow reconstruct` subcommand end to end (apps/cmd_reconstruct.cc) on a simulated scan
// of the demo part at half resolution: both modes, the stereo interpolation choice reaching the
// matcher, and bad input leaving nothing behind.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

using slshadow::testing::RunCli;

nlohmann::json ReadJson(const std::filesystem::path& path) {
  std::ifstream in(path);
  EXPECT_TRUE(in.good()) << path;
  return nlohmann::json::parse(in);
}

class CmdReconstruct : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir;
    Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
    for (auto& c : rig.cameras) {
      c.model.width /= 2;
      c.model.height /= 2;
      for (int k : {CameraModel::kFx, CameraModel::kFy}) c.model.params[static_cast<size_t>(k)] /= 2;
      for (int k : {CameraModel::kCx, CameraModel::kCy}) {
        c.model.params[static_cast<size_t>(k)] = (c.model.params[static_cast<size_t>(k)] + 0.5) / 2 - 0.5;
      }
    }
    SaveRig(rig, *tmp_ / "rig.yaml");
    ASSERT_EQ(RunCli({"simulate", "--rig", (*tmp_ / "rig.yaml").string(), "--scene",
                      (testing::SourceDir() / "config/demo/scene.yaml").string(), "--patterns",
                      (testing::SourceDir() / "config/demo/patterns.yaml").string(), "--out", Scan().string(),
                      "--encoding", "pgm", "--no-ground-truth", "--quiet"}),
              0);
  }
  static void TearDownTestSuite() {
    delete tmp_;
    tmp_ = nullptr;
  }
  static std::filesystem::path Dir() { return tmp_->path(); }
  static std::filesystem::path Scan() { return *tmp_ / "scan"; }
  static testing::TempDir* tmp_;
};
testing::TempDir* CmdReconstruct::tmp_ = nullptr;

TEST_F(CmdReconstruct, ProjectorModeWritesCloudAndSummary) {
  const auto out = Dir() / "projector.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--out", out.string(), "--quiet"}), 0);
  const PointCloud cloud = ReadPly(out);
  const nlohmann::json summary = ReadJson(Dir() / "projector.summary.json");
  EXPECT_EQ(summary["options"]["mode"], "projector");
  EXPECT_EQ(summary["options"]["reconstruct"]["method"], "midpoint");
  // Both cameras see the part: a half-resolution scan gives several hundred thousand points.
  EXPECT_GT(cloud.size(), 300000u);
}

TEST_F(CmdReconstruct, StereoInterpolationOptionReachesTheMatcher) {
  const auto lin = Dir() / "stereo_linear.ply", cub = Dir() / "stereo_cubic.ply", def = Dir() / "stereo_auto.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation", "linear", "--out",
                    lin.string(), "--quiet"}),
            0);
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation", "cubic", "--out",
                    cub.string(), "--quiet"}),
            0);
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--out", def.string(), "--quiet"}), 0);
  EXPECT_EQ(ReadJson(Dir() / "stereo_linear.summary.json")["options"]["reconstruct"]["stereo_interpolation"], "linear");
  EXPECT_EQ(ReadJson(Dir() / "stereo_cubic.summary.json")["options"]["reconstruct"]["stereo_interpolation"], "cubic");
  const PointCloud a = ReadPly(lin), b = ReadPly(cub), c = ReadPly(def);
  ASSERT_GT(a.size(), 300000u);
  // Decoded maps are float, so auto means linear: the same cloud bit for bit.
  ASSERT_EQ(a.size(), c.size());
  EXPECT_EQ(a.points, c.points);
  // Cubic moves the sub-pixel crossings: the clouds differ, by a fraction of the point spacing.
  bool differ = a.size() != b.size() || a.points != b.points;
  EXPECT_TRUE(differ);
}

TEST_F(CmdReconstruct, BadInputFailsWithoutWriting) {
  const auto out = Dir() / "bad.ply";
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation", "quintic", "--out",
                    out.string()}),
            0);
  EXPECT_NE(RunCli({"reconstruct", (Dir() / "missing").string(), "--out", out.string()}), 0);
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--cameras", "nosuchcamera", "--out", out.string()}), 0);
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--max-depth-mm", "nan", "--out", out.string()}), 0);
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(Dir() / "bad.summary.json"));
}

}  // namespace
}  // namespace slshadow
