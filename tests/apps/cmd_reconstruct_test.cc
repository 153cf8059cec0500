// The `slshadow reconstruct` subcommand end to end (apps/cmd_reconstruct.cc) on a simulated scan
// of the demo part at half resolution: both modes, the stereo interpolation choice reaching the
// matcher, and bad input leaving nothing behind.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/commands.h"
#include "core/image_set.h"
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
      for (int k : {CameraModel::kFx, CameraModel::kFy})
        c.model.params[static_cast<size_t>(k)] /= 2;
      for (int k : {CameraModel::kCx, CameraModel::kCy}) {
        c.model.params[static_cast<size_t>(k)] =
            (c.model.params[static_cast<size_t>(k)] + 0.5) / 2 - 0.5;
      }
    }
    SaveRig(rig, *tmp_ / "rig.yaml");
    ASSERT_EQ(RunCli({"simulate", "--rig", (*tmp_ / "rig.yaml").string(), "--scene",
                      (testing::SourceDir() / "config/demo/scene.yaml").string(), "--patterns",
                      (testing::SourceDir() / "config/demo/patterns.yaml").string(), "--out",
                      Scan().string(), "--encoding", "pgm", "--no-ground-truth", "--quiet"}),
              0);
  }
  static void TearDownTestSuite() {
    delete tmp_;
    tmp_ = nullptr;
  }
  static std::filesystem::path Dir() { return tmp_->path(); }
  static std::filesystem::path Scan() { return *tmp_ / "scan"; }
  // A copy of the scan whose manifest holds `rig` instead of the scan's own.
  static std::filesystem::path CopyWithRig(const std::string& name, const Rig& rig) {
    const auto copy = Dir() / name;
    std::filesystem::copy(Scan(), copy, std::filesystem::copy_options::recursive);
    nlohmann::json manifest = ReadJson(copy / "manifest.json");
    manifest["rig"] = RigToJson(rig);
    std::ofstream(copy / "manifest.json") << manifest.dump(2);
    return copy;
  }
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
  // The calibration check of each reconstruction is in the summary, beside its residual map.
  ASSERT_EQ(summary["residual_maps"].size(), 2u);
  for (size_t k = 0; k < 2; ++k) {
    const nlohmann::json& check = summary["reconstructions"][k]["calibration_check"];
    EXPECT_TRUE(check["available"].get<bool>()) << check.dump();
    EXPECT_FALSE(check["warning"].get<bool>()) << check.dump();  // the scan's own rig
    EXPECT_EQ(summary["residual_maps"][k]["calibration_warning"], false);
    EXPECT_DOUBLE_EQ(summary["residual_maps"][k]["scale_max_px"].get<double>(),
                     2 * check["threshold_px"].get<double>());
    EXPECT_TRUE(std::filesystem::exists(summary["residual_maps"][k]["file"].get<std::string>()));
  }
}

// A rig file with the left camera's principal point 1 px off (cx, cy): the check warns on stderr,
// names the cause, and the summary records it beside the residual map; the cloud is still written.
TEST_F(CmdReconstruct, CalibrationCheckWarnsAboutAWrongRigFile) {
  const ImageSet scan = ImageSet::Open(Scan());
  Rig wrong = scan.rig();
  wrong.cameras[0].model.params[CameraModel::kCx] += 1.0;
  wrong.cameras[0].model.params[CameraModel::kCy] += 1.0;
  const auto copy = CopyWithRig("scan_wrong_rig", wrong);
  const auto out = Dir() / "wrong.ply";
  ASSERT_EQ(RunCli({"reconstruct", copy.string(), "--out", out.string(), "--quiet"}), 0);
  const nlohmann::json summary = ReadJson(Dir() / "wrong.summary.json");
  const nlohmann::json& left = summary["reconstructions"][0]["calibration_check"];
  EXPECT_TRUE(left["warning"].get<bool>()) << left.dump();
  EXPECT_NE(left["message"].get<std::string>().find("principal point"), std::string::npos);
  EXPECT_EQ(summary["residual_maps"][0]["calibration_warning"], true);
  EXPECT_FALSE(summary["residual_maps"][0]["likely_causes"].empty());
  EXPECT_FALSE(summary["reconstructions"][1]["calibration_check"]["warning"]
                   .get<bool>());  // right camera fits
  // A fixed threshold overrides the automatic one.
  const auto out2 = Dir() / "wrong_fixed.ply";
  ASSERT_EQ(RunCli({"reconstruct", copy.string(), "--out", out2.string(), "--quiet",
                    "--calibration-warning-px", "50"}),
            0);
  const nlohmann::json fixed =
      ReadJson(Dir() / "wrong_fixed.summary.json")["reconstructions"][0]["calibration_check"];
  EXPECT_EQ(fixed["threshold_source"], "user");
  EXPECT_FALSE(fixed["warning"].get<bool>());
}

// A rig file so wrong that no point passes the gates: an error naming the reason, nothing written.
TEST_F(CmdReconstruct, NoPointsIsAnErrorWithItsReason) {
  const ImageSet scan = ImageSet::Open(Scan());
  Rig wrong = scan.rig();
  wrong.projector->cam_from_rig.translation.y() += 40;  // the projector 40 mm off
  const auto copy = CopyWithRig("scan_far_off_rig", wrong);
  const auto out = Dir() / "none.ply";
  ::testing::internal::CaptureStderr();
  const int code = RunCli({"reconstruct", copy.string(), "--out", out.string(), "--quiet"});
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(code, 0);
  EXPECT_NE(err.find("0 points"), std::string::npos) << err;
  EXPECT_NE(err.find("cells"), std::string::npos) << err;
  EXPECT_NE(err.find("wrong rig file"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(Dir() / "none.summary.json"));
}

TEST_F(CmdReconstruct, StereoInterpolationOptionReachesTheMatcher) {
  const auto lin = Dir() / "stereo_linear.ply", cub = Dir() / "stereo_cubic.ply",
             def = Dir() / "stereo_auto.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation",
                    "linear", "--out", lin.string(), "--quiet"}),
            0);
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation",
                    "cubic", "--out", cub.string(), "--quiet"}),
            0);
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--out", def.string(),
                    "--quiet"}),
            0);
  EXPECT_EQ(
      ReadJson(Dir() /
               "stereo_linear.summary.json")["options"]["reconstruct"]["stereo_interpolation"],
      "linear");
  EXPECT_EQ(ReadJson(Dir() /
                     "stereo_cubic.summary.json")["options"]["reconstruct"]["stereo_interpolation"],
            "cubic");
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
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--mode", "stereo", "--stereo-interpolation",
                    "quintic", "--out", out.string()}),
            0);
  EXPECT_NE(RunCli({"reconstruct", (Dir() / "missing").string(), "--out", out.string()}), 0);
  EXPECT_NE(
      RunCli({"reconstruct", Scan().string(), "--cameras", "nosuchcamera", "--out", out.string()}),
      0);
  EXPECT_NE(
      RunCli({"reconstruct", Scan().string(), "--max-depth-mm", "nan", "--out", out.string()}), 0);
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(Dir() / "bad.summary.json"));
}

std::string ReadFile(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// --rig: another rig than the manifest's, the manifest untouched, the summary saying which.
TEST_F(CmdReconstruct, RigOptionUsesAnotherRigAndRecordsIt) {
  const std::string manifest = ReadFile(Scan() / "manifest.json");
  Rig moved = LoadRig(Dir() / "rig.yaml");
  moved.name = "refined";
  // A 0.2 % longer baseline (what a refinement may change): the same epipolar geometry, a scaled
  // cloud.
  moved.projector->cam_from_rig.translation *= 1.002;
  SaveRig(moved, Dir() / "refined.yaml");
  const auto base = Dir() / "rig_base.ply", refined = Dir() / "rig_refined.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--cameras", "left", "--out", base.string(),
                    "--quiet"}),
            0);
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--cameras", "left", "--rig",
                    (Dir() / "refined.yaml").string(), "--out", refined.string(), "--quiet"}),
            0);
  EXPECT_EQ(ReadFile(Scan() / "manifest.json"), manifest);
  const nlohmann::json a = ReadJson(Dir() / "rig_base.summary.json"),
                       b = ReadJson(Dir() / "rig_refined.summary.json");
  EXPECT_EQ(a["rig"]["source"], "manifest");
  EXPECT_EQ(b["rig"]["source"], "file");
  EXPECT_EQ(b["rig"]["name"], "refined");
  EXPECT_NE(b["rig"]["file"].get<std::string>().find("refined.yaml"), std::string::npos);
  const PointCloud pa = ReadPly(base), pb = ReadPly(refined);
  ASSERT_GT(pa.size(), 100000u);
  ASSERT_GT(pb.size(), 100000u);
  EXPECT_NE(pa.points, pb.points);
}

// A rig without a projector: the default mode is stereo; projector mode says to use stereo.
TEST_F(CmdReconstruct, ProjectorlessRigDefaultsToStereo) {
  Rig cameras_only = LoadRig(Dir() / "rig.yaml");
  cameras_only.projector.reset();
  SaveRig(cameras_only, Dir() / "cameras_only.yaml");
  const auto out = Dir() / "auto_stereo.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--rig", (Dir() / "cameras_only.yaml").string(),
                    "--out", out.string(), "--quiet"}),
            0);
  EXPECT_EQ(ReadJson(Dir() / "auto_stereo.summary.json")["options"]["mode"], "stereo");
  EXPECT_GT(ReadPly(out).size(), 100000u);
  // With the manifest's rig (it has a projector) the default stays projector mode (above).
  const auto bad = Dir() / "projector_without_projector.ply";
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--rig", (Dir() / "cameras_only.yaml").string(),
                    "--mode", "projector", "--out", bad.string()}),
            0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("has no projector"), std::string::npos) << err;
  EXPECT_NE(err.find("--mode stereo"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(bad));
}

// A reconstruction with no point is an error that says why, and writes nothing.
TEST_F(CmdReconstruct, ZeroPointsIsAnErrorWithTheReason) {
  const auto out = Dir() / "empty.ply";
  ::testing::internal::CaptureStderr();
  EXPECT_NE(RunCli({"reconstruct", Scan().string(), "--max-depth-mm", "10", "--min-depth-mm", "1",
                    "--out", out.string(), "--quiet"}),
            0);
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(err.find("0 points"), std::string::npos) << err;
  EXPECT_NE(err.find("outside the depth range"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(out));
  EXPECT_FALSE(std::filesystem::exists(Dir() / "empty.summary.json"));
}

// --strict: the scan's own rig passes and writes; a rig file whose calibration check warns, or a
// minimum share of points the scan cannot reach, ends with a non-zero exit naming the reason, and
// an output already at --out is left as it was.
TEST_F(CmdReconstruct, StrictModeRefusesAWarningAndWritesNothing) {
  const auto good = Dir() / "strict_good.ply";
  ASSERT_EQ(RunCli({"reconstruct", Scan().string(), "--out", good.string(), "--quiet", "--strict"}),
            0);
  EXPECT_TRUE(std::filesystem::exists(good));

  Rig wrong = ImageSet::Open(Scan()).rig();
  wrong.cameras[0].model.params[CameraModel::kCx] += 1.0;
  wrong.cameras[0].model.params[CameraModel::kCy] += 1.0;
  const auto copy = CopyWithRig("scan_strict_wrong_rig", wrong);
  const auto out = Dir() / "strict_wrong.ply";
  std::ofstream(out) << "an earlier cloud";
  ::testing::internal::CaptureStderr();
  const int code =
      RunCli({"reconstruct", copy.string(), "--out", out.string(), "--quiet", "--strict"});
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(code, 0);
  EXPECT_NE(err.find("--strict"), std::string::npos) << err;
  EXPECT_NE(err.find("left-projector: the calibration check warns"), std::string::npos) << err;
  EXPECT_EQ(err.find("right-projector: the calibration check warns"), std::string::npos) << err;
  EXPECT_NE(err.find("nothing written"), std::string::npos) << err;
  std::ifstream in(out);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), "an earlier cloud");
  EXPECT_FALSE(std::filesystem::exists(Dir() / "strict_wrong.summary.json"));

  // Every decoded pixel a point is more than any scan gives (filters and gates reject some).
  const auto all = Dir() / "strict_all.ply";
  ::testing::internal::CaptureStderr();
  const int code_all = RunCli({"reconstruct", Scan().string(), "--out", all.string(), "--quiet",
                               "--strict", "--strict-min-points", "1"});
  const std::string err_all = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(code_all, 0);
  EXPECT_NE(err_all.find("under the 100.0 % minimum"), std::string::npos) << err_all;
  EXPECT_FALSE(std::filesystem::exists(all));
  // The share is checked as an option.
  EXPECT_NE(
      RunCli({"reconstruct", Scan().string(), "--out", all.string(), "--strict-min-points", "1.5"}),
      0);
}

// One coded axis (columns only): camera-projector has no calibration check. The command says so
// on stderr and still writes; --strict refuses it; stereo of the same capture checks the rig
// against the projector (one-axis stereo's projector error) and passes --strict.
TEST_F(CmdReconstruct, OneAxisCaptureIsNotedAndRefusedInStrictMode) {
  const auto spec = Dir() / "columns_only.yaml";
  std::ofstream(spec) << "kind: phase_shift\nprojector_width: 1280\nprojector_height: 800\n"
                         "code_x: true\ncode_y: false\nphase_steps: 4\nperiod_px: 16\n";
  const auto scan = Dir() / "scan_columns";
  ASSERT_EQ(RunCli({"simulate", "--rig", (Dir() / "rig.yaml").string(), "--scene",
                    (testing::SourceDir() / "config/demo/scene.yaml").string(), "--patterns",
                    spec.string(), "--out", scan.string(), "--encoding", "pgm", "--no-ground-truth",
                    "--quiet"}),
            0);
  const auto out = Dir() / "columns.ply";
  ::testing::internal::CaptureStderr();
  const int code = RunCli({"reconstruct", scan.string(), "--out", out.string(), "--quiet"});
  const std::string err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(code, 0) << err;
  EXPECT_TRUE(std::filesystem::exists(out));
  EXPECT_NE(err.find("slshadow: note: calibration check: not available for left-projector"),
            std::string::npos)
      << err;

  const auto strict_out = Dir() / "columns_strict.ply";
  ::testing::internal::CaptureStderr();
  const int strict_code =
      RunCli({"reconstruct", scan.string(), "--out", strict_out.string(), "--quiet", "--strict"});
  const std::string strict_err = ::testing::internal::GetCapturedStderr();
  EXPECT_NE(strict_code, 0);
  EXPECT_NE(strict_err.find("left-projector: no calibration check, because"), std::string::npos)
      << strict_err;
  EXPECT_FALSE(std::filesystem::exists(strict_out));

  const auto stereo_out = Dir() / "columns_stereo.ply";
  ::testing::internal::CaptureStderr();
  const int stereo_code = RunCli({"reconstruct", scan.string(), "--out", stereo_out.string(),
                                  "--quiet", "--mode", "stereo", "--strict"});
  const std::string stereo_err = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(stereo_code, 0) << stereo_err;
  EXPECT_TRUE(std::filesystem::exists(stereo_out));
}

}  // namespace
}  // namespace slshadow
