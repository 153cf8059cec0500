#include "workflows/multiview/multiview_demo.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <map>
#include <string>
#include <vector>

#include "core/error.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;

// The whole-part target on the demo part: 12 views cover at least 98 % of the part's
// reachable CAD surface (the face on the table excluded), with a merged C2M RMS within 10 % of a
// single view's (the median of the views' RMS, as the demo prints it). At 1/2 of the demo rig's
// resolution (960x600 cameras) to keep the test short.
TEST(MultiviewDemoTest, TwelveViewsCoverTheReachableDemoPart) {
  const testing::TempDir tmp;
  const TurntableSetup setup = testing::ScaledTurntableDemo(2);
  MultiviewDemoOptions options;
  options.views = 12;
  options.out_dir = tmp / "demo";
  options.rig = setup.rig;
  options.scene = setup.scene;
  const MultiviewDemoResult r = RunMultiviewDemo(options);
  ASSERT_TRUE(r.merge.cad.has_value());
  const CadComparison& cad = *r.merge.cad;
  EXPECT_GE(cad.coverage_reachable, 0.98) << cad.Summary();
  // The fused model is closer to the CAD than a single view: its median |C2M| is lower, and its
  // RMS within the 10 % of a single view's (median over the views). At this half
  // resolution the views' ghost points at the part's foot (one view's points a few mm in front
  // of a wall, just above the table) carried 85 % of the merged cloud's sum of squares until the
  // fusion's free-space check (merge.h step 4) rejected them: ratio 2.19 before, 0.64 after
  // (docs/benchmarks/log/2026-12-07-fusion-half-res.md).
  std::vector<double> median;
  for (const CadViewFigures& v : cad.views) median.push_back(v.c2m.median_mm);
  std::sort(median.begin(), median.end());
  EXPECT_LT(cad.merged_c2m.median_mm, median[median.size() / 2]) << cad.Summary();
  std::printf("merged C2M RMS %.4f mm, single views' median %.4f mm, ratio %.3f\n",
              cad.merged_c2m.rms_mm, r.single_view_rms_mm,
              cad.merged_c2m.rms_mm / r.single_view_rms_mm);
  ASSERT_GT(r.single_view_rms_mm, 0);
  EXPECT_LE(cad.merged_c2m.rms_mm, 1.1 * r.single_view_rms_mm) << cad.Summary();
  // The poses registered by MergeViews (pairwise ICP, pose graph) from the table angles: at half
  // the demo rig's resolution within 0.02 deg / 0.025 mm of the truth (the 0.002 deg /
  // 2 um is not reached; full resolution: docs/benchmarks.md).
  ASSERT_TRUE(r.merge.has_truth);
  EXPECT_TRUE(r.merge.refined);
  EXPECT_LT(r.merge.max_rotation_error_deg, 0.02) << r.merge.Summary();
  EXPECT_LT(r.merge.max_translation_error_mm, 0.025) << r.merge.Summary();
  for (const MergedView& v : r.merge.views) EXPECT_TRUE(v.merged) << v.name << ": " << v.reason;
  // One view covers about half: the whole turn is what reaches the rest.
  for (const CadViewFigures& v : cad.views) EXPECT_LT(v.coverage, 0.8) << v.name;
  for (const char* f : {"project/project.json", "model/report.json", "model/cad_deviation.ply",
                        "cad.ply", "multiview_demo.json"})
    EXPECT_TRUE(fs::exists(options.out_dir / f)) << f;
  EXPECT_NE(r.Table().find("whole part: coverage"), std::string::npos);
  // A second run replaces the earlier output; any other folder is refused.
  options.views = 2;
  EXPECT_EQ(RunMultiviewDemo(options).merge.views.size(), 2u);
  fs::create_directories(tmp / "other");
  options.out_dir = tmp / "other";
  EXPECT_NE(testing::ErrorOf([&] {
              RunMultiviewDemo(options);
            }).find("is not an earlier multi-view demo output"),
            std::string::npos);
  options.views = 0;
  EXPECT_THROW(RunMultiviewDemo(options), Error);
}

// The camera images of a project's views, file name -> bytes (view_00/left/0000.pgm, ...).
std::map<std::string, std::string> ViewImages(const fs::path& project) {
  std::map<std::string, std::string> images;
  for (const auto& e : fs::recursive_directory_iterator(project / "views")) {
    if (!e.is_regular_file() || e.path().extension() != ".pgm") continue;
    std::ifstream in(e.path(), std::ios::binary);
    images[fs::relative(e.path(), project).string()] =
        std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  return images;
}

// `slshadow demo --views --noise --noise-seed S` (MultiviewDemoOptions::noise_seed): the same
// seed renders bit-identical images, another seed other ones, and the noise is on (the
// noise-free images differ from both). One view at 1/4 of the demo rig's resolution.
TEST(MultiviewDemoTest, NoiseSeedReproducesItsDrawAndAnotherSeedDrawsAnother) {
  const testing::TempDir tmp;
  const TurntableSetup setup = testing::ScaledTurntableDemo(4);
  auto run = [&](const std::string& name, bool noise, uint64_t seed) {
    MultiviewDemoOptions options;
    options.views = 1;
    options.out_dir = tmp / name;
    options.rig = setup.rig;
    options.scene = setup.scene;
    options.merge.mesh = false;
    options.sensor_noise = noise;
    options.noise_seed = seed;
    RunMultiviewDemo(options);
    return ViewImages(tmp / name / "project");
  };
  const auto a = run("a", true, 7), b = run("b", true, 7), c = run("c", true, 8),
             clean = run("clean", false, 7);
  ASSERT_FALSE(a.empty());
  ASSERT_EQ(a.size(), c.size());
  EXPECT_TRUE(a == b) << "the same seed must reproduce every image bit for bit";
  size_t differ_c = 0, differ_clean = 0;
  for (const auto& [name, bytes] : a) {
    ASSERT_EQ(bytes.size(), c.at(name).size()) << name;
    if (bytes != c.at(name)) ++differ_c;
    if (bytes != clean.at(name)) ++differ_clean;
  }
  EXPECT_EQ(differ_c, a.size()) << "another seed must change every image";
  EXPECT_EQ(differ_clean, a.size()) << "--noise must change every image";
}

}  // namespace
}  // namespace slshadow::multiview
