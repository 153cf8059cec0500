#include "workflows/multiview/plan.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "core/error.h"
#include "core/mesh.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;

constexpr size_t kSamples = 40000;

// The demo part (1/4 of the demo rig's resolution): the plan reaches 98 % of the reachable
// surface with no more views than uniform steps need, its coverage accounting equals a prediction
// of the planned views made from scratch, and a virtual scan of the planned views confirms it: per
// CAD sample the scan's coverage (merged at the table's poses, compared with the CAD) agrees with
// the prediction on at least 99 % of the samples off the table, the disagreements listed by reason.
TEST(PlanTest, TheDemoPlanReachesItsTargetWithNoMoreViewsThanUniformSteps) {
  const TurntableSetup setup = testing::ScaledTurntableDemo(4);
  const TriangleMesh cad = PartSurface(setup.scene);
  PlanOptions options;
  options.prediction = WithSceneRadiometry(options.prediction, setup.scene);
  options.prediction.samples = kSamples;
  options.step_deg = 15;  // refined every 5 deg about the chosen angles (the default)
  options.target = 0.98;
  const ViewPlan plan = PlanTurntableViews(cad, setup.rig, options);
  std::cout << plan.Table();
  ASSERT_TRUE(plan.reached);
  ASSERT_FALSE(plan.greedy_coverage.empty());
  EXPECT_GE(plan.greedy_coverage.back(), 0.98);
  for (size_t k = 1; k < plan.greedy_coverage.size(); ++k)
    EXPECT_GT(plan.greedy_coverage[k], plan.greedy_coverage[k - 1]);
  ASSERT_GT(plan.uniform_needed, 0);
  EXPECT_LE(plan.views.views.size(), static_cast<size_t>(plan.uniform_needed));
  EXPECT_EQ(plan.grid_candidates, 24u);
  EXPECT_GT(plan.candidates, 24u);
  ASSERT_EQ(plan.views.views.size(), plan.greedy_deg.size());
  for (size_t k = 1; k < plan.views.views.size(); ++k)
    EXPECT_LT(*plan.views.views[k - 1].table_deg, *plan.views.views[k].table_deg);
  // One view cannot cover the part, so the plan is a real choice.
  EXPECT_GE(plan.views.views.size(), 3u);
  // Against the grid alone: the same reachable surface (refining does not move the target), no
  // fewer views, and with as many at most the refined plan's coverage.
  PlanOptions grid_options = options;
  grid_options.refine_deg = 0;
  const ViewPlan grid = PlanTurntableViews(cad, setup.rig, grid_options);
  EXPECT_EQ(grid.reachable, plan.reachable);
  EXPECT_EQ(grid.candidates, 24u);
  ASSERT_TRUE(grid.reached);
  EXPECT_GE(grid.views.views.size(), plan.views.views.size());
  if (grid.views.views.size() == plan.views.views.size()) {
    EXPECT_LE(grid.greedy_coverage.back(), plan.greedy_coverage.back());
  }

  // A fresh prediction of the planned views reconstructs exactly the samples the plan counted.
  const CoveragePrediction predicted = PredictCoverage(
      cad, setup.rig, PosesOfViews(plan.views, setup.rig), setup.rig.turntable, options.prediction);
  const size_t reconstructed =
      predicted.reason_samples[static_cast<size_t>(PredictedReason::kReconstructed)];
  EXPECT_NEAR(static_cast<double>(reconstructed),
              plan.greedy_coverage.back() * static_cast<double>(plan.reachable), 0.5);
  EXPECT_EQ(predicted.OffTable(), plan.off_table);

  const testing::TempDir tmp;
  SimulateProject(setup.scene, setup.rig, testing::ScaledDemoPatterns(setup.rig), plan.views,
                  tmp / "project");
  const PlanCheck confirmed =
      CheckPlanAgainstProject(cad, setup.rig, tmp / "project", options.prediction);
  const PredictionCheck& check = confirmed.check;
  std::cout << check.Summary();
  // The project's views are the plan's: the same prediction.
  EXPECT_EQ(confirmed.prediction.reason_samples, predicted.reason_samples);
  EXPECT_GT(check.compared, kSamples / 2);
  EXPECT_GE(check.agreement, 0.99) << check.Summary();
  // With the reconstruction's depth-discontinuity filter on each view's rendered maps: measured
  // 99.39 % (173 / 9 -> 153 / 24 disagreements).
  CoveragePredictionOptions rendered = options.prediction;
  rendered.rendered_reconstruction = true;
  const PlanCheck by_rendering = CheckPlanAgainstProject(cad, setup.rig, tmp / "project", rendered);
  std::cout << "rendered: " << by_rendering.check.Summary();
  EXPECT_GE(by_rendering.check.agreement, 0.99) << by_rendering.check.Summary();
  // The planned coverage holds: the scan covers the target share of the reachable surface less at
  // most the 1 % the prediction may miss.
  EXPECT_GE(check.scanned_coverage, options.target * plan.reachable_share - 0.01)
      << check.Summary();
}

// The command line: the views file it writes is the plan's and loads as slshadow scan reads it;
// bad options exit non-zero naming the option and write nothing.
TEST(PlanTest, CommandWritesTheViewsFile) {
  const testing::TempDir tmp;
  const fs::path config = fs::path(SLSHADOW_SOURCE_DIR) / "config/demo";
  const std::string out = (tmp / "views.yaml").string();
  const std::string coverage = (tmp / "coverage.ply").string();
  const std::string rig = (config / "turntable_rig.yaml").string();
  const std::string scene = (config / "turntable_scene.yaml").string();
  std::vector<std::string> args = {"slshadow plan", "--rig",       rig,          "--part",
                                   scene,           "--turntable", "--target",   "0.95",
                                   "--step-deg",    "30",          "--samples",  "20000",
                                   "--out",         out,           "--coverage", coverage};
  const auto run = [](std::vector<std::string> a) {
    std::vector<char*> argv;
    for (std::string& s : a) argv.push_back(s.data());
    return app::RunPlan(static_cast<int>(argv.size()), argv.data());
  };
  ASSERT_EQ(run(args), 0);
  const ViewsFile views = LoadViews(out);
  ASSERT_FALSE(views.views.empty());
  for (const ViewSpec& v : views.views) {
    ASSERT_TRUE(v.table_deg.has_value());
    // On the 30 deg grid or refined about it every 5 deg (PlanOptions::refine_deg), in [0, 360).
    EXPECT_NEAR(std::fmod(*v.table_deg, 5.0), 0.0, 1e-9) << v.name;
    EXPECT_GE(*v.table_deg, 0.0);
    EXPECT_LT(*v.table_deg, 360.0);
  }
  EXPECT_TRUE(fs::exists(coverage));
  // The same plan from the library.
  const PlanPart part = LoadPlanPart(scene);
  PlanOptions options;
  options.prediction = WithSceneRadiometry(options.prediction, *part.scene);
  options.prediction.samples = 20000;
  options.step_deg = 30;
  options.target = 0.95;
  EXPECT_EQ(ViewsToJson(PlanTurntableViews(part.cad, LoadRig(rig), options).views),
            ViewsToJson(views));

  const std::string bad = (tmp / "bad.yaml").string();
  std::vector<std::string> bad_args = args;
  bad_args[7] = "1.5";  // --target
  bad_args[13] = bad;   // --out
  EXPECT_NE(testing::ErrorOf([&] { run(bad_args); }).find("--target"), std::string::npos);
  EXPECT_FALSE(fs::exists(bad));
  PlanOptions bad_refine;
  bad_refine.refine_deg = -5;
  EXPECT_NE(testing::ErrorOf([&] { bad_refine.Check(); }).find("--refine-deg"), std::string::npos);
  bad_refine.refine_deg = 5;
  bad_refine.max_evaluations = 0;
  EXPECT_NE(testing::ErrorOf([&] { bad_refine.Check(); }).find("--search-budget"),
            std::string::npos);
  // Without --turntable: placements by hand, tilted and turned about the part's centre; the views
  // file holds hand-placed views with their poses, the plan the library makes.
  std::vector<std::string> by_hand = args;
  by_hand.erase(by_hand.begin() + 5);
  const std::string hand = (tmp / "hand.yaml").string();
  by_hand[12] = hand;
  by_hand.insert(by_hand.end(), {"--tilts-deg", "0,90"});
  ASSERT_EQ(run(by_hand), 0);
  const ViewsFile hand_views = LoadViews(hand);
  ASSERT_FALSE(hand_views.views.empty());
  for (const ViewSpec& v : hand_views.views) {
    EXPECT_FALSE(v.table_deg.has_value()) << v.name;
    EXPECT_TRUE(v.part_from_rig_guess.has_value()) << v.name;
  }
  const Rig the_rig = LoadRig(rig);
  // The same plan from the library (poses to the text's precision).
  const ViewsFile library =
      PlanViews(part.cad, the_rig, PlacementCandidates(part.cad, the_rig, {0, 90}, 30),
                std::nullopt, options)
          .views;
  ASSERT_EQ(library.views.size(), hand_views.views.size());
  for (size_t k = 0; k < library.views.size(); ++k) {
    const Rigid3d a = *library.views[k].part_from_rig_guess;
    const Rigid3d b = *hand_views.views[k].part_from_rig_guess;
    EXPECT_EQ(library.views[k].name, hand_views.views[k].name);
    EXPECT_LT(a.rotation.angularDistance(b.rotation), 1e-9) << k;
    EXPECT_LT((a.translation - b.translation).norm(), 1e-9) << k;
  }
  // A bad tilt: named, nothing written.
  std::vector<std::string> bad_tilt = by_hand;
  bad_tilt[12] = bad;
  bad_tilt.back() = "0,270";
  EXPECT_NE(testing::ErrorOf([&] { run(bad_tilt); }).find("--tilts-deg"), std::string::npos);
  EXPECT_FALSE(fs::exists(bad));
  // An unknown option: CLI11's non-zero exit.
  std::vector<std::string> unknown = args;
  unknown.push_back("--no-such-option");
  EXPECT_NE(run(unknown), 0);
}

// Placements by hand (1/4 rig): each candidate turns the part about its centre (which stays put)
// and about "up" (the table axis) for a tilt of 0; the general planner given the table's own
// angles as candidates picks what the turntable planner picks; a placement plan reaches its
// target and a fresh prediction of its views reconstructs what the plan counted.
TEST(PlanTest, PlacementsByHand) {
  const TurntableSetup setup = testing::ScaledTurntableDemo(4);
  const TriangleMesh cad = PartSurface(setup.scene);
  const Eigen::Vector3d centre = 0.5 * (cad.BoundsMin() + cad.BoundsMax());
  const Eigen::Vector3d up = setup.rig.turntable->direction_in_rig.normalized();
  const std::vector<ViewCandidate> placed = PlacementCandidates(cad, setup.rig, {0, 90, 180}, 45);
  ASSERT_EQ(placed.size(), 24u);
  for (size_t k = 0; k < placed.size(); ++k) {
    const Rigid3d rig_from_part = placed[k].view.part_from_rig_guess->Inverse();
    EXPECT_LT((rig_from_part * centre - centre).norm(), 1e-9) << placed[k].label;
    const double tilt = k < 8 ? 0 : (k < 16 ? 90 : 180);
    EXPECT_NEAR(up.dot(rig_from_part.rotation * up), std::cos(tilt * M_PI / 180), 1e-9)
        << placed[k].label;
  }
  EXPECT_THROW(PlacementCandidates(cad, setup.rig, {}, 45), Error);

  PlanOptions options;
  options.prediction = WithSceneRadiometry(options.prediction, setup.scene);
  options.prediction.samples = 20000;
  options.step_deg = 30;
  options.refine_deg = 0;  // the same candidates as the table views below
  options.target = 0.98;
  const ViewPlan table_plan = PlanTurntableViews(cad, setup.rig, options);
  std::vector<ViewCandidate> table_candidates;
  for (const ViewSpec& v : FullTurnViews(12, 0).views) table_candidates.push_back({v.name, v});
  const ViewPlan general =
      PlanViews(cad, setup.rig, table_candidates, setup.rig.turntable, options);
  // The same candidates, reachable surface and fewest views; the table plan's search also starts
  // from evenly spaced angles, so it covers at least as much with them.
  EXPECT_EQ(general.reachable, table_plan.reachable);
  EXPECT_EQ(general.greedy_deg.size(), table_plan.greedy_deg.size());
  EXPECT_EQ(general.one_fewer_coverage, table_plan.one_fewer_coverage);
  ASSERT_TRUE(general.reached);
  EXPECT_GE(table_plan.greedy_coverage.back(), general.greedy_coverage.back());

  const ViewPlan hand = PlanViews(cad, setup.rig, placed, std::nullopt, options);
  std::cout << hand.Table();
  ASSERT_TRUE(hand.reached);
  EXPECT_TRUE(hand.greedy_deg.empty());
  EXPECT_TRUE(hand.uniform_coverage.empty());
  EXPECT_EQ(hand.off_table, hand.samples);  // nothing on a table
  const CoveragePrediction predicted = PredictCoverage(
      cad, setup.rig, PosesOfViews(hand.views, setup.rig), std::nullopt, options.prediction);
  EXPECT_NEAR(static_cast<double>(
                  predicted.reason_samples[static_cast<size_t>(PredictedReason::kReconstructed)]),
              hand.greedy_coverage.back() * static_cast<double>(hand.reachable), 0.5);
}

}  // namespace
}  // namespace slshadow::multiview
