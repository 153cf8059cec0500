#include "workflows/multiview/multiview_demo.h"

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;

// The whole-part target on the demo part: 12 views cover at least 98 % of the part's
// reachable CAD surface (the face on the table excluded), with a merged C2M RMS within 10 % of a
// single view's. At 1/2 of the demo rig's resolution (960x600 cameras) to keep the test short.
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
  EXPECT_LE(cad.merged_c2m.rms_mm, 1.1 * r.single_view_rms_mm) << cad.Summary();
  ASSERT_TRUE(r.merge.has_truth);
  EXPECT_LT(r.merge.max_rotation_error_deg, 0.002);
  EXPECT_LT(r.merge.max_translation_error_mm, 0.002);
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

}  // namespace
}  // namespace slshadow::multiview
