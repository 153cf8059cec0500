// The views of a project reconstructed as independent jobs (`slshadow merge --reconstruct-only
// --shard I/N --reconstructions DIR`, workflows/multiview/view_reconstruction.h), then merged from
// the stored reconstructions: the model equals the one a single merge writes byte for byte (the
// oracle: the same command without shards), whatever the shards' order; stored reconstructions
// read back bit for bit; one made from other images or with other options is refused by name.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/mesh.h"
#include "core/shard.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/view_reconstruction.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;
using slshadow::testing::RunCli;

class MergeShards : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir();
    testing::WriteQuarterDemoProject(tmp_->path(), 5, 10);
  }
  static void TearDownTestSuite() { delete tmp_; }
  static std::string Path(const std::string& name) { return (*tmp_ / name).string(); }
  // Runs `slshadow merge ARGS`; *out gets what it printed, *err what it wrote to stderr.
  static int Merge(std::vector<std::string> args, std::string* out, std::string* err = nullptr) {
    args.insert(args.begin(), "merge");
    ::testing::internal::CaptureStdout();
    ::testing::internal::CaptureStderr();
    const int rc = RunCli(args);
    *out = ::testing::internal::GetCapturedStdout();
    const std::string e = ::testing::internal::GetCapturedStderr();
    if (err) *err = e;
    return rc;
  }
  static std::string Bytes(const fs::path& path) {
    std::ifstream in(path, std::ios::binary);
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  }
  // report.json without what depends on where step 1 ran and on the clock.
  static nlohmann::json Figures(const fs::path& model) {
    nlohmann::json j = nlohmann::json::parse(ReadTextFile(model / "report.json"));
    for (auto& v : j["views"]) {
      v.erase("reconstruct_s");
      v.erase("reconstruction");
    }
    j.erase("time_s");
    if (j["cad"].is_object()) j["cad"].erase("seconds");
    if (j.contains("registration")) j["registration"].erase("time_s");
    return j;
  }
  static testing::TempDir* tmp_;
};
testing::TempDir* MergeShards::tmp_ = nullptr;

TEST_F(MergeShards, ShardsThenMergeWriteTheModelOneMergeWrites) {
  std::string out;
  ASSERT_EQ(Merge({Path("project"), "--out", Path("one"), "--cad", Path("cad.ply"), "--no-mesh",
                   "--no-html", "--quiet"},
                  &out),
            0)
      << out;
  // Three shards, run out of order, as a scheduler may.
  int reconstructed = 0;
  for (const char* shard : {"2/3", "0/3", "1/3"}) {
    ASSERT_EQ(Merge({Path("project"), "--reconstructions", Path("recon"), "--reconstruct-only",
                     "--shard", shard},
                    &out),
              0)
        << out;
    EXPECT_NE(out.find(std::string("shard ") + shard), std::string::npos) << out;
    const size_t at = out.find(" reconstructed");
    ASSERT_NE(at, std::string::npos) << out;
    reconstructed += std::stoi(out.substr(out.rfind(' ', at - 1) + 1));
  }
  EXPECT_EQ(reconstructed, 5);
  for (int i = 0; i < 5; ++i) {
    const fs::path view = *tmp_ / "recon" / ("view_0" + std::to_string(i));
    EXPECT_TRUE(fs::exists(view / "reconstruction.json")) << view;
    EXPECT_TRUE(fs::exists(view / "cloud.ply")) << view;
    EXPECT_TRUE(fs::exists(view / "dark_left.png")) << view;
    EXPECT_TRUE(fs::exists(view / "dark_right.png")) << view;
  }
  // A shard run again finds its views stored.
  ASSERT_EQ(Merge({Path("project"), "--reconstructions", Path("recon"), "--reconstruct-only",
                   "--shard", "1/3"},
                  &out),
            0);
  EXPECT_NE(out.find("0 reconstructed, 2 already stored"), std::string::npos) << out;

  ASSERT_EQ(Merge({Path("project"), "--reconstructions", Path("recon"), "--out", Path("sharded"),
                   "--cad", Path("cad.ply"), "--no-mesh", "--no-html", "--quiet"},
                  &out),
            0)
      << out;
  for (const char* file : {"merged.ply", "cad_deviation.ply", "cad_coverage.ply"}) {
    EXPECT_EQ(Bytes(*tmp_ / "one" / file), Bytes(*tmp_ / "sharded" / file)) << file;
  }
  EXPECT_EQ(Figures(*tmp_ / "one"), Figures(*tmp_ / "sharded"));
  // Five views 72 deg apart at 1/4 resolution: every pair's overlap leaves the rotation about the
  // axis weak, and the table's prior holds it (merge.h icp_degenerate_ratio). Without the hold
  // view_01 was merged 0.88 deg off the exact initial pose while stating 0.018 deg (1-sigma).
  // (The figures held in a local: a range-for over a member of a temporary dangles.)
  const nlohmann::json one = Figures(*tmp_ / "one");
  ASSERT_EQ(one["views"].size(), 5u);
  for (const auto& v : one["views"]) {
    EXPECT_TRUE(v["merged"].get<bool>()) << v["name"];
    EXPECT_LT(v["rotation_error_deg"].get<double>(), 0.02) << v["name"];
    EXPECT_LT(v["translation_error_mm"].get<double>(), 0.05) << v["name"];
  }
  const nlohmann::json report =
      nlohmann::json::parse(ReadTextFile(*tmp_ / "sharded" / "report.json"));
  for (const auto& v : report["views"]) {
    EXPECT_EQ(v["reconstruction"].get<std::string>().rfind("read from ", 0), 0u) << v;
  }
  // Holding only the pairs that would slide (--hold-gate-sigmas, MergeOptions::
  // icp_hold_gate_sigmas): the pairs that, registered without the hold, depart from the table's
  // prior by more than 3 of its sigmas along their weak directions are held again (without any
  // hold view_01 ends 0.88 deg off); the others keep their own result, which here costs
  // accuracy (0.036 deg against 0.006 deg with every pair held), so the gate is off
  // by default (docs/benchmarks/log/2026-12-08-rotation-noise-3.md).
  ASSERT_EQ(
      Merge({Path("project"), "--reconstructions", Path("recon"), "--out", Path("gated"), "--cad",
             Path("cad.ply"), "--no-mesh", "--no-html", "--quiet", "--hold-gate-sigmas", "3"},
            &out),
      0)
      << out;
  const nlohmann::json gated = nlohmann::json::parse(ReadTextFile(*tmp_ / "gated" / "report.json"));
  ASSERT_EQ(gated["views"].size(), 5u);
  double largest[2] = {0, 0};
  for (const auto& v : one["views"])
    largest[0] = std::max(largest[0], v["rotation_error_deg"].get<double>());
  for (const auto& v : gated["views"]) {
    EXPECT_TRUE(v["merged"].get<bool>()) << v["name"];
    EXPECT_LT(v["rotation_error_deg"].get<double>(), 0.1) << v["name"];
    EXPECT_LT(v["translation_error_mm"].get<double>(), 0.1) << v["name"];
    largest[1] = std::max(largest[1], v["rotation_error_deg"].get<double>());
  }
  size_t held = 0, pairs = 0;
  for (const auto& p : gated["registration"]["pairs"]) {
    ++pairs;
    if (!p["degenerate"].empty()) ++held;
  }
  std::printf(
      "--hold-gate-sigmas 3: %zu of %zu pairs held; largest rotation error %.5f deg (every "
      "pair held: %.5f deg)\n",
      held, pairs, largest[1], largest[0]);
  EXPECT_GT(held, 0u);
  EXPECT_LT(held, pairs);
}

// The same through GNU parallel (the recipe of `slshadow merge --help` and docs/sweeps.md): 3
// shards on 2 job slots, separate processes, one thread each; then the merge reads them.
TEST_F(MergeShards, GnuParallelShardsGiveTheModelOneMergeWrites) {
  ASSERT_EQ(std::system("parallel --version > /dev/null 2>&1"), 0)
      << "GNU parallel is not installed (scripts/setup.sh installs it)";
  std::string out;
  if (!fs::exists(*tmp_ / "one")) {
    ASSERT_EQ(Merge({Path("project"), "--out", Path("one"), "--cad", Path("cad.ply"), "--no-mesh",
                     "--no-html", "--quiet"},
                    &out),
              0)
        << out;
  }
  const std::string bin = SLSHADOW_BINARY;
  const std::string cmd = "parallel --will-cite --halt now,fail=1 -j 2 " + bin + " merge " +
                          Path("project") + " --reconstructions " + Path("par_recon") +
                          " --reconstruct-only --threads 1 --quiet --shard {}/3 ::: 2 1 0";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  ASSERT_EQ(std::system((bin + " merge " + Path("project") + " --reconstructions " +
                         Path("par_recon") + " --out " + Path("par") + " --cad " + Path("cad.ply") +
                         " --no-mesh --no-html --quiet")
                            .c_str()),
            0);
  for (const char* file : {"merged.ply", "cad_deviation.ply", "cad_coverage.ply"}) {
    EXPECT_EQ(Bytes(*tmp_ / "one" / file), Bytes(*tmp_ / "par" / file)) << file;
  }
  EXPECT_EQ(Figures(*tmp_ / "one"), Figures(*tmp_ / "par"));
}

TEST_F(MergeShards, AStoredReconstructionReadsBackBitForBit) {
  const fs::path view_dir = *tmp_ / "project" / "views" / "view_01";
  const ImageSet image_set = ImageSet::Open(view_dir);
  ViewReconstructOptions options;
  options.reconstruct.report_residuals = false;
  const ViewReconstruction made = ReconstructProjectView(image_set, options);
  ASSERT_GT(made.cloud.size(), 1000u);
  ASSERT_EQ(made.dark.size(), 2u);
  const ViewReconstructionKey key = ViewReconstructionKey::For("view_01", view_dir, options);
  WriteViewReconstruction(*tmp_ / "roundtrip", key, made);
  const std::optional<ViewReconstruction> read = ReadViewReconstruction(*tmp_ / "roundtrip", key);
  ASSERT_TRUE(read.has_value());
  EXPECT_EQ(read->accepted_points, made.accepted_points);
  ASSERT_EQ(read->cloud.size(), made.cloud.size());
  for (size_t k = 0; k < made.cloud.size(); ++k) {
    ASSERT_EQ(read->cloud.points[k], made.cloud.points[k]) << k;
    ASSERT_EQ(read->cloud.normals[k], made.cloud.normals[k]) << k;
  }
  ASSERT_EQ(read->cloud.scalars.size(), made.cloud.scalars.size());
  for (size_t s = 0; s < made.cloud.scalars.size(); ++s) {
    EXPECT_EQ(read->cloud.scalars[s].name, made.cloud.scalars[s].name);
    EXPECT_EQ(read->cloud.scalars[s].values, made.cloud.scalars[s].values);
  }
  size_t dark = 0;
  for (size_t c = 0; c < 2; ++c) {
    EXPECT_EQ(read->dark[c].camera, made.dark[c].camera);
    EXPECT_EQ(read->dark[c].width, made.dark[c].width);
    EXPECT_EQ(read->dark[c].dark, made.dark[c].dark);
    for (uint8_t d : made.dark[c].dark) dark += d;
  }
  // The table's far side and the background are dark: the record is not trivially empty.
  EXPECT_GT(dark, 0u);
  // Nothing stored for another view.
  ViewReconstructionKey other = key;
  other.view = "view_02";
  EXPECT_FALSE(ReadViewReconstruction(*tmp_ / "roundtrip", other).has_value());
}

TEST_F(MergeShards, AReconstructionOfOtherOptionsOrOtherImagesIsRefusedByName) {
  std::string out, err;
  ASSERT_EQ(Merge({Path("project"), "--reconstructions", Path("stale"), "--reconstruct-only",
                   "--shard", "0/5"},
                  &out),
            0)
      << out;
  // Other options: the merge names the file, the field and both values; nothing is written.
  EXPECT_NE(Merge({Path("project"), "--reconstructions", Path("stale"), "--out", Path("m1"),
                   "--max-points-per-view", "1000"},
                  &out, &err),
            0);
  EXPECT_NE(err.find("view_00/reconstruction.json: options.max_points_per_view: 400000"),
            std::string::npos)
      << err;
  EXPECT_NE(err.find("1000"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(*tmp_ / "m1"));
  EXPECT_NE(Merge({Path("project"), "--reconstructions", Path("stale"), "--out", Path("m1"),
                   "--mode", "projector"},
                  &out, &err),
            0);
  EXPECT_NE(err.find("options.mode: \"stereo\""), std::string::npos) << err;
  // Other images: the view's manifest changed since (a view scanned again).
  fs::copy(*tmp_ / "project", *tmp_ / "rescanned", fs::copy_options::recursive);
  {
    std::ofstream append(*tmp_ / "rescanned" / "views" / "view_00" / "manifest.json",
                         std::ios::app);
    append << "\n";
  }
  EXPECT_NE(Merge({Path("rescanned"), "--reconstructions", Path("stale"), "--out", Path("m1")},
                  &out, &err),
            0);
  EXPECT_NE(err.find("view_00/reconstruction.json: manifest_fnv1a64: "), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(*tmp_ / "m1"));
  // The command line's own errors.
  EXPECT_NE(Merge({Path("project"), "--reconstruct-only"}, &out, &err), 0);
  EXPECT_NE(err.find("--reconstruct-only: needs --reconstructions"), std::string::npos) << err;
  EXPECT_NE(Merge({Path("project"), "--reconstructions", Path("stale"), "--reconstruct-only",
                   "--shard", "5/5"},
                  &out, &err),
            0);
  EXPECT_NE(err.find("--shard: '5/5' is not I/N"), std::string::npos) << err;
  EXPECT_NE(Merge({Path("project"), "--out", Path("m1"), "--shard", "0/2"}, &out, &err), 0);
  EXPECT_NE(err.find("only with --reconstruct-only"), std::string::npos) << err;
  EXPECT_NE(Merge({Path("project")}, &out, &err), 0);
  EXPECT_NE(err.find("--out: required"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(*tmp_ / "m1"));
}

TEST(Shard, BlocksCoverEveryItemOnceInOrder) {
  for (int n = 1; n <= 7; ++n) {
    for (size_t items : {0u, 1u, 5u, 12u, 13u}) {
      size_t next = 0;
      for (int i = 0; i < n; ++i) {
        const Shard s{i, n};
        EXPECT_EQ(s.Begin(items), next);
        EXPECT_LE(s.End(items) - s.Begin(items), items / static_cast<size_t>(n) + 1);
        next = s.End(items);
      }
      EXPECT_EQ(next, items);
    }
  }
  EXPECT_EQ(ParseShard("2/4", "--shard").index, 2);
  EXPECT_EQ(ParseShard("2/4", "--shard").count, 4);
  for (const char* bad : {"", "1", "4/4", "-1/4", "1/0", "a/2", "1/2x", "1 /2"}) {
    EXPECT_THROW(ParseShard(bad, "--shard"), Error) << bad;
  }
}

}  // namespace
}  // namespace slshadow::multiview
