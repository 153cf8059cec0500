// The registration's degenerate directions (workflows/multiview/internal/pairwise.h,
// MergeOptions::icp_degenerate_ratio): a pair whose overlap leaves directions free (planes slide
// along themselves) holds them at its initial relative pose (the table's) instead of sliding and
// being rejected. On a synthetic plane (the free directions known exactly) and on the multi-view
// issue's self-occluding part, made of planes (config/demo/occlusion_turntable_scene.yaml), on the
// demo turntable at 1/2 of the demo rig's resolution, against the simulated truth. On by default
// (icp_degenerate_ratio 1e-3): a view whose table angle is 20 deg wrong, held so (only the
// horizontal faces overlap), is left out by the free-space check (internal/sight_check.h), named.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/error.h"
#include "core/mesh.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "sim/scene.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/internal/pairwise.h"
#include "workflows/multiview/internal/pose_graph.h"
#include "workflows/multiview/merge.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/views.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;

// A noisy square patch of the plane z = 500 (the camera at the origin looks at it), points on a
// jittered 0.3 mm grid.
PointCloud Plane(uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, 0.005);
  std::uniform_real_distribution<double> jitter(-0.1, 0.1);
  PointCloud c;
  for (double x = -20; x <= 20; x += 0.3)
    for (double y = -20; y <= 20; y += 0.3)
      c.points.emplace_back(x + jitter(rng), y + jitter(rng), 500 + noise(rng));
  return c;
}

// MergeOptions::icp_normal_neighbors: the ICP's normals are PCA over that many neighbours
// whatever normals the cloud brings; 0 keeps the cloud's. A plane with 0.02 mm noise whose
// normals are off by about 6 deg (the reconstruction's central differences over +-1 pixel at the
// demo rig's noise).
TEST(RegistrationTest, IcpNormalsFromAWiderNeighbourhoodReplaceTheCloudsNoisyNormals) {
  std::mt19937 rng(5);
  std::normal_distribution<double> noise(0.0, 0.02), tilt(0.0, 0.07);
  std::uniform_real_distribution<double> jitter(-0.1, 0.1);
  PointCloud c;
  for (double x = -10; x <= 10; x += 0.3)
    for (double y = -10; y <= 10; y += 0.3) {
      c.points.emplace_back(x + jitter(rng), y + jitter(rng), 500 + noise(rng));
      c.normals.push_back(Eigen::Vector3d(tilt(rng), tilt(rng), -1).normalized().cast<float>());
    }
  auto rms_deg = [](const std::vector<Eigen::Vector3d>& normals) {
    double sum = 0;
    for (const auto& n : normals) {
      EXPECT_LT(n.z(), 0) << "oriented as the cloud's (towards the camera)";
      const double a = std::acos(std::min(1.0, std::abs(n.z())));
      sum += a * a;
    }
    return std::sqrt(sum / static_cast<double>(normals.size())) * 180 / M_PI;
  };
  MergeOptions options;
  options.icp_normal_neighbors = 0;
  internal::ViewGeometry given;
  internal::PrepareView(c, options, &given);
  ASSERT_EQ(given.icp_normals.size(), c.size());
  EXPECT_EQ(given.icp_normals, given.normals);
  EXPECT_GT(rms_deg(given.icp_normals), 4.0);
  options.icp_normal_neighbors = 30;
  // By default (icp_table_normals_only) the wide normals serve the table sample only: a view
  // without one (here no turntable axis) keeps the cloud's.
  internal::ViewGeometry untabled;
  internal::PrepareView(c, options, &untabled);
  EXPECT_EQ(untabled.icp_normals, untabled.normals);
  options.icp_table_normals_only = false;
  internal::ViewGeometry wide;
  internal::PrepareView(c, options, &wide);
  const double wide_deg = rms_deg(wide.icp_normals);
  std::printf("ICP normals off the plane's: %.2f deg (the cloud's), %.2f deg (PCA, k = 30)\n",
              rms_deg(given.icp_normals), wide_deg);
  EXPECT_LT(wide_deg, 1.5);
  // The cloud's normals stay what the fusion uses.
  EXPECT_EQ(wide.normals, given.normals);
  options.icp_normal_neighbors = 2;
  EXPECT_THROW(options.Check(), Error);
}

// One plane seen twice, the second view's initial pose 0.3 / 0.2 mm off along the plane, 0.05 mm
// off across it, turned 0.1 deg about the plane's normal and tilted 0.05 deg. The plane fixes the
// height and the tilts; the two in-plane translations and the turn about the normal are free: the
// ICP keeps them at the initial pose (without this a plane's ICP slides on the correspondences'
// jitter) and the pair's information there is the prior's.
TEST(RegistrationTest, APlaneFixesThreeDirectionsAndHoldsTheOtherThreeAtThePrior) {
  const PointCloud a = Plane(1), b = Plane(2);
  MergeOptions options;
  options.icp_degenerate_ratio = 1e-3;
  internal::ViewGeometry ga, gb;
  internal::PrepareView(a, options, &ga);
  internal::PrepareView(b, options, &gb);
  const double turn = 0.1 * M_PI / 180, tilt = 0.05 * M_PI / 180;
  const Eigen::Quaterniond rotation(Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitZ()) *
                                    Eigen::AngleAxisd(tilt, Eigen::Vector3d::UnitX()));
  // The tilt about the x axis through the patch's centre (0, 0, 500).
  const Eigen::Vector3d centre(0, 0, 500);
  const Rigid3d initial(rotation, Eigen::Vector3d(0.3, 0.2, 0.05) + centre - rotation * centre);
  const internal::IcpOutcome o = internal::RegisterPair(ga, gb, initial, options);
  EXPECT_TRUE(o.converged);
  ASSERT_EQ(o.degenerate.size(), 3u);
  int rotations = 0;
  for (const auto& d : o.degenerate) {
    if (d.rotation) {
      ++rotations;
      EXPECT_GT(std::abs(d.axis.z()), 0.999);  // the turn about the normal
    } else {
      EXPECT_LT(std::abs(d.axis.z()), 0.001);  // a translation along the plane
    }
    EXPECT_LT(d.ratio, 1e-3);
  }
  EXPECT_EQ(rotations, 1);
  EXPECT_LT(o.min_eigen_ratio, 1e-3);
  // The fixed directions found (the plane z = 500 back onto itself), the free ones left as they
  // were: the centre stays where the initial pose put it along the plane.
  const Eigen::Vector3d moved = o.a_from_b * centre;
  EXPECT_NEAR(moved.z(), 500.0, 0.002);
  EXPECT_NEAR(moved.x(), 0.3, 1e-4);
  EXPECT_NEAR(moved.y(), 0.2, 1e-4);
  const Eigen::Vector3d normal = o.a_from_b.rotation * Eigen::Vector3d::UnitZ();
  EXPECT_LT(std::acos(std::min(1.0, normal.z())) * 180 / M_PI, 0.002);
  const Eigen::Vector3d x_axis = o.a_from_b.rotation * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(std::atan2(x_axis.y(), x_axis.x()), turn, 2e-6);
  // The information along the free translations is the prior's (1 / prior_sigma_mm^2), along the
  // fixed height far more.
  const double prior_info = 1.0 / (options.prior_sigma_mm * options.prior_sigma_mm);
  Eigen::Matrix<double, 6, 1> along_x = Eigen::Matrix<double, 6, 1>::Zero();
  along_x(3) = 1;
  EXPECT_NEAR(along_x.dot(o.information * along_x) / prior_info, 1.0, 0.05);
  Eigen::Matrix<double, 6, 1> along_z = Eigen::Matrix<double, 6, 1>::Zero();
  along_z(5) = 1;
  EXPECT_GT(along_z.dot(o.information * along_z), 1e4 * prior_info);

  // With the degeneracy test off nothing is held: the same pair's information along the plane is
  // only what the normals' noise gives it.
  options.icp_degenerate_ratio = 0;
  const internal::IcpOutcome plain = internal::RegisterPair(ga, gb, initial, options);
  EXPECT_TRUE(plain.degenerate.empty());
}

// The self-occluding part on the demo turntable (the scene file on the 1/4 demo rig with the
// file's axis): it is made of planes, so a pair of views 90 deg apart shares mostly the part's
// horizontal faces, which leave the rotation about the table axis and the translations along the
// table free.
TurntableSetup ScaledOcclusionPart(int scale) {
  const fs::path config = fs::path(SLSHADOW_SOURCE_DIR) / "config/demo";
  TurntableSetup setup;
  setup.scene = LoadScene(config / "occlusion_turntable_scene.yaml");
  setup.rig = testing::ScaledDemoRig(scale);
  setup.rig.turntable = LoadRig(config / "turntable_rig.yaml").turntable;
  return setup;
}

// Parses "rotation about (x, y, z)" (ViewPose::prior_directions); false when another kind.
bool RotationAxis(const std::string& text, Eigen::Vector3d* axis) {
  return std::sscanf(text.c_str(), "rotation about (%lf, %lf, %lf)", &axis->x(), &axis->y(),
                     &axis->z()) == 3;
}

constexpr double kRatio = MergeOptions().icp_degenerate_ratio;  // the default (on)
static_assert(kRatio > 0);

class OcclusionPartRegistration : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir();
    setup_ = new TurntableSetup(ScaledOcclusionPart(2));
    for (int views : {4, 12})
      SimulateProject(setup_->scene, setup_->rig, testing::ScaledDemoPatterns(setup_->rig),
                      FullTurnViews(views, 0), Project(views));
    // The 4 views' images with view_02's recorded table angle 20 deg off (project 0).
    fs::copy(Project(4), Project(0), fs::copy_options::recursive);
    ProjectManifest p = LoadProject(Project(0));
    *p.views[2].spec.table_deg += 20.0;
    SaveProject(p, Project(0));
  }
  static void TearDownTestSuite() {
    delete setup_;
    delete tmp_;
  }
  static fs::path Project(int views) { return tmp_->path() / std::to_string(views); }
  static ProjectMergeResult Merge(int views, double degenerate_ratio) {
    ProjectMergeOptions options;
    options.mesh = false;
    options.registration.icp_degenerate_ratio = degenerate_ratio;
    ProjectMergeResult r = MergeProject(Project(views), nullptr, options);
    std::printf("%s", r.Summary().c_str());
    return r;
  }
  static testing::TempDir* tmp_;
  static TurntableSetup* setup_;
};
testing::TempDir* OcclusionPartRegistration::tmp_ = nullptr;
TurntableSetup* OcclusionPartRegistration::setup_ = nullptr;

// Four views 90 deg apart: every view is merged, each non-anchor view names the rotation about
// the table axis among the directions the table's prior fixed, and the poses are within a few um
// of the truth (the table's exact poses).
TEST_F(OcclusionPartRegistration, FourViewsAllMergedTheFreeDirectionsHeldAtTheTable) {
  const ProjectMergeResult r = Merge(4, kRatio);
  ASSERT_TRUE(r.has_truth);
  const Eigen::Vector3d axis = setup_->rig.turntable->direction_in_rig.normalized();
  for (const MergedView& v : r.views) {
    EXPECT_TRUE(v.merged) << v.name << ": " << v.reason;
    if (v.anchor) continue;
    bool about_axis = false;
    for (const std::string& d : v.prior_directions) {
      Eigen::Vector3d u;
      // The part frame is the rig frame at table angle 0, where the axis is the rig's.
      if (RotationAxis(d, &u)) about_axis = about_axis || std::abs(u.normalized().dot(axis)) > 0.99;
    }
    EXPECT_TRUE(about_axis) << v.name;
  }
  EXPECT_LT(r.max_rotation_error_deg, 0.005);    // 0.00055 deg on 2026-12-07
  EXPECT_LT(r.max_translation_error_mm, 0.005);  // 0.0019 mm
  // The right start passes the free-space check (no view's points where another saw through).
  for (const PairRegistration& p : r.registration.pairs) {
    std::printf("pair %d <- %d: seen through %.4f\n", p.view_a, p.view_b, p.seen_through);
    EXPECT_LE(p.seen_through, MergeOptions().max_seen_through);
  }

  // Without it the pairs slide: their views are left out, or merged far off (0.04 deg / 0.24 mm
  // with the noise-level stop of the ICP, icp_noise_tolerance).
  const ProjectMergeResult plain = Merge(4, 0.0);
  int left_out = 0;
  for (const MergedView& v : plain.views) left_out += v.merged ? 0 : 1;
  EXPECT_TRUE(left_out > 0 || plain.max_translation_error_mm > 10 * r.max_translation_error_mm)
      << plain.max_translation_error_mm;
}

// The same 4 views, view_02's table angle 20 deg wrong: at that start only the horizontal faces
// match, as at the right one (the part's geometry leaves the rotation about the axis free in both),
// and the hold keeps the wrong angle; but view_02's walls then stand where its neighbours saw
// through, so its pairs are rejected and the view left out, named; the others stay merged.
TEST_F(OcclusionPartRegistration, AWrongTableAngleHeldByThePriorIsLeftOutNamed) {
  const ProjectMergeResult r = Merge(0, kRatio);
  ASSERT_TRUE(r.has_truth);
  for (const MergedView& v : r.views) {
    if (v.name == "view_02") {
      EXPECT_FALSE(v.merged);
      EXPECT_NE(v.reason.find("saw through"), std::string::npos) << v.reason;
      EXPECT_NE(v.reason.find("the start is wrong"), std::string::npos) << v.reason;
    } else {
      EXPECT_TRUE(v.merged) << v.name << ": " << v.reason;
    }
  }
  EXPECT_LT(r.max_rotation_error_deg, 0.005);  // of the merged views
  EXPECT_LT(r.max_translation_error_mm, 0.005);
  // Every kept pair that held a direction passed the check; the rejected ones are view_02's.
  for (const PairRegistration& p : r.registration.pairs) {
    if (p.seen_through < 0) continue;
    const auto& names = r.registration.views;
    const bool of_view_02 = names[static_cast<size_t>(p.view_a)].name == "view_02" ||
                            names[static_cast<size_t>(p.view_b)].name == "view_02";
    std::printf("pair %d <- %d: seen through %.4f\n", p.view_a, p.view_b, p.seen_through);
    EXPECT_EQ(p.seen_through > MergeOptions().max_seen_through, of_view_02);
  }
}

// Twelve views 30 deg apart: every view merged, the poses within 0.05 deg / 0.02 mm of the
// truth. At the full rig 0.0018 deg / 0.0010 mm (before the degeneracy test 0.035 deg /
// 0.0045 mm; docs/benchmarks/log/2026-12-07-registration-noise.md); at this half resolution
// 0.023 deg / 0.010 mm: the 30-deg pairs' rotation about the axis, just above the degeneracy
// bound, is biased on the sparser points (not understood yet).
TEST_F(OcclusionPartRegistration, TwelveViewsAllMergedNearTheTruth) {
  const ProjectMergeResult r = Merge(12, kRatio);
  ASSERT_TRUE(r.has_truth);
  for (const MergedView& v : r.views) EXPECT_TRUE(v.merged) << v.name << ": " << v.reason;
  EXPECT_LT(r.max_rotation_error_deg, 0.05);
  EXPECT_LT(r.max_translation_error_mm, 0.02);
}

// The six-DOF pose graph's covariance scaled by how much the pairs disagree with each other
// beyond their information (internal/pose_graph.h, variance_factor): three views in a loop whose
// pairs' translations along x disagree by d = 3 mm, each pair's 1-sigma 0.1 mm. Least squares
// spreads d over the three pairs (d / 3 each, 10 sigma): chi^2 = 3 x 100 over 6 x 3 - 6 x 2 = 6
// degrees of freedom, a factor 50, also per view (each view's two pairs). The covariance is 50x
// that of the same graph with consistent pairs; with d = 0.3 mm (chi^2 / dof = 0.5) it is not
// shrunk (factor at least 1).
TEST(PoseGraphVarianceFactor, DisagreeingPairsWidenTheCovariance) {
  auto solve = [](double d) {
    internal::Matrix6d info = internal::Matrix6d::Zero();
    info.diagonal() << 1e6, 1e6, 1e6, 100, 100, 100;  // 0.057 deg, 0.1 mm
    auto along_x = [](double x) { return Rigid3d(Eigen::Quaterniond::Identity(), {x, 0, 0}); };
    const std::vector<internal::GraphEdge> edges = {
        {0, 1, along_x(10), info}, {1, 2, along_x(10), info}, {0, 2, along_x(20 + d), info}};
    const std::vector<Rigid3d> initial = {along_x(0), along_x(10), along_x(20)};
    return internal::OptimizePoseGraph(initial, {true, true, true}, 0, edges, true);
  };
  const internal::GraphSolution consistent = solve(0.0), disagreeing = solve(3.0);
  ASSERT_TRUE(consistent.covariance_ok);
  ASSERT_TRUE(disagreeing.covariance_ok);
  EXPECT_NEAR(consistent.variance_factor, 1.0, 1e-9);
  EXPECT_NEAR(disagreeing.variance_factor, 50.0, 0.5);
  for (size_t v : {1, 2}) {
    EXPECT_NEAR(disagreeing.view_variance_factor[v], 50.0, 0.5) << v;
    EXPECT_NEAR(disagreeing.covariance[v](3, 3) / consistent.covariance[v](3, 3), 50.0, 0.5) << v;
  }
  const internal::GraphSolution small = solve(0.3);
  EXPECT_NEAR(small.variance_factor, 1.0, 1e-9);  // chi^2 / dof 0.5: not shrunk
  EXPECT_NEAR(small.covariance[1](3, 3) / consistent.covariance[1](3, 3), 1.0, 0.01);
}

// Hand-placed views (issue 32; docs/benchmarks/log/2026-12-07-degeneracy-default.md, B and C;
// 2026-12-07-hand-sigma.md): the demo part at 1/4 rig, 8 views 45 deg apart from a start angle,
// view_00 a table view, views 1-7 put down by hand on the table (no table angle, no guess: global
// registration). Their pairs leave the rotation about the vertical weakly fixed (smallest
// eigenvalue ratio 2e-4 .. 4e-4) and hold nothing.
class HandViewRegistration : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir();
    const TurntableSetup setup = testing::ScaledTurntableDemo(4);
    cad_ = new TriangleMesh(PartSurface(setup.scene));
    for (int start : {0, 10}) {
      const fs::path dir = Project(start);
      SimulateProject(setup.scene, setup.rig, testing::ScaledDemoPatterns(setup.rig),
                      FullTurnViews(8, start), dir);
      ProjectManifest p = LoadProject(dir);
      for (size_t i = 1; i < p.views.size(); ++i) {
        p.views[i].spec.table_deg.reset();
        p.views[i].spec.placed_on_table = true;
      }
      SaveProject(p, dir);
    }
  }
  static void TearDownTestSuite() {
    delete cad_;
    delete tmp_;
  }
  static fs::path Project(int start) { return tmp_->path() / ("hand" + std::to_string(start)); }
  static ProjectMergeResult Merge(int start, const ProjectMergeOptions& options) {
    const ProjectMergeResult r = MergeProject(Project(start), cad_, options);
    std::printf("%s", r.Summary().c_str());
    for (const PairRegistration& q : r.registration.pairs)
      std::printf(
          "pair %d <- %d: kept %d, eigen ratio %.2e, seen through %.4f, spread %.2f, graph error "
          "%.4f deg, untested floor %.4f deg\n",
          q.view_a, q.view_b, q.kept ? 1 : 0, q.min_eigen_ratio, q.seen_through, q.spread_factor,
          q.graph_error_deg, q.untested_floor_deg);
    return r;
  }
  static ProjectMergeOptions Defaults() {
    ProjectMergeOptions options;
    options.mesh = false;
    return options;
  }
  // Every merged hand view near the truth and within 3 x its stated 1-sigma (rotation and the
  // centroid's translation); every left-out view named by the registration. Returns the merged
  // hand views.
  static int CheckHandViews(const ProjectMergeResult& r, double max_error_deg = 0.2) {
    EXPECT_TRUE(r.has_truth);
    EXPECT_TRUE(r.views[0].merged) << r.views[0].reason;
    int registered = 0;
    for (size_t i = 1; i < r.views.size(); ++i) {
      const MergedView& v = r.views[i];
      if (!v.merged) {
        EXPECT_NE(v.reason.find("registration: "), std::string::npos) << v.name << ": " << v.reason;
        continue;
      }
      ++registered;
      std::printf(
          "%s: %.4f deg, 1-sigma %.5f -> %.5f deg (%.1f -> %.1f sigma); %.4f mm, 1-sigma %.5f -> "
          "%.5f mm (%.1f -> %.1f sigma)\n",
          v.name.c_str(), v.rotation_error_deg, v.graph_sigma_rotation_deg, v.sigma_rotation_deg,
          v.rotation_error_deg / v.graph_sigma_rotation_deg,
          v.rotation_error_deg / v.sigma_rotation_deg, v.translation_error_mm,
          v.graph_sigma_translation_mm, v.sigma_translation_mm,
          v.translation_error_mm / v.graph_sigma_translation_mm,
          v.translation_error_mm / v.sigma_translation_mm);
      EXPECT_LT(v.rotation_error_deg, max_error_deg) << v.name;
      EXPECT_LT(v.translation_error_mm, 0.2) << v.name;
      EXPECT_LE(v.rotation_error_deg, 3 * v.sigma_rotation_deg) << v.name;
      EXPECT_LE(v.translation_error_mm, 3 * v.sigma_translation_mm) << v.name;
      EXPECT_GE(v.sigma_rotation_deg, v.graph_sigma_rotation_deg) << v.name;
    }
    return registered;
  }
  static testing::TempDir* tmp_;
  static TriangleMesh* cad_;
};
testing::TempDir* HandViewRegistration::tmp_ = nullptr;
TriangleMesh* HandViewRegistration::cad_ = nullptr;

// From 10 deg: view_07's global registration started 58.6 mm off and its one pair
// (view_00 <- view_07, RMS 0.028 mm) kept it there: merged 60.3 mm off. The free-space check on
// such weak hand pairs leaves it out, named (15 % of its points where view_00 saw through).
// Views 01 and 02, held by the chain view_00 <- view_02 <- view_01, are 0.075 deg off the truth,
// 7.6 x the graph's 1-sigma; the spread of their pairs over blocks of the overlap states it.
// That start is RANSAC's single most supported hypothesis (the merge's global_candidates 1).
// Comparing candidates on the full cloud (compare::Register's default, the shadow's) starts
// view_07 0.09 mm off: it is merged, within 3 sigma.
TEST_F(HandViewRegistration, AHandViewSlidAlongAWeakDirectionIsLeftOutNamed) {
  const ProjectMergeResult r = Merge(10, Defaults());
  EXPECT_GE(CheckHandViews(r), 1);
  const MergedView& seventh = r.views[7];
  EXPECT_FALSE(seventh.merged);
  EXPECT_NE(seventh.reason.find("saw through"), std::string::npos) << seventh.reason;

  ProjectMergeOptions compare_candidates = Defaults();
  compare_candidates.registration.global.global_candidates =
      compare::RegistrationOptions{}.global_candidates;
  const ProjectMergeResult compared = Merge(10, compare_candidates);
  EXPECT_GE(CheckHandViews(compared), 1);
  EXPECT_TRUE(compared.views[7].merged) << compared.views[7].reason;
}

// From 0 deg: views 01, 02 and 07 merged, 2.6 - 4.8 x the graph's 1-sigma off.
TEST_F(HandViewRegistration, MergedHandViewsAreWithinThreeStatedSigmas) {
  EXPECT_GE(CheckHandViews(Merge(0, Defaults())), 1);
}

// With the candidates compared (compare::Register's default) from 0 deg, views 03, 05 and 06
// register too, but view_05 hangs on one weak pair (view_00 <- view_05) and view_06 on view_05
// (view_05 <- view_06): no loop tests them, and they are 0.23 deg off while their pairs' spread
// states 0.046 deg (5 sigma). A weak pair a loop tests shows what such a pair can be off
// (view_00 <- view_02, rejected: 0.215 deg off the graph), and every weak pair no loop tests is
// given that as the floor of its weakest direction's 1-sigma: all merged within 3 sigma.
TEST_F(HandViewRegistration, AWeakPairNoLoopTestsStatesWhatATestedOneWasOff) {
  ProjectMergeOptions options = Defaults();
  options.registration.global.global_candidates = compare::RegistrationOptions{}.global_candidates;
  const ProjectMergeResult r = Merge(0, options);
  EXPECT_GE(CheckHandViews(r, 0.3), 5);
  double tested_deg = 0;
  for (const PairRegistration& p : r.registration.pairs)
    if (p.min_eigen_ratio < options.registration.icp_degenerate_ratio)
      tested_deg = std::max(tested_deg, p.graph_error_deg);
  EXPECT_GT(tested_deg, 0.1);
  for (size_t i : {5, 6}) {
    ASSERT_TRUE(r.views[i].merged) << r.views[i].name << ": " << r.views[i].reason;
    EXPECT_GT(r.views[i].rotation_error_deg, 0.2) << "the fixture's bias is still there";
    EXPECT_GT(r.views[i].sigma_rotation_deg, 0.1) << r.views[i].name;
  }
  int floored = 0;
  for (const PairRegistration& p : r.registration.pairs) {
    if (p.untested_floor_deg == 0) continue;
    ++floored;
    EXPECT_TRUE(p.kept);
    EXPECT_DOUBLE_EQ(p.untested_floor_deg, tested_deg);
  }
  EXPECT_GE(floored, 2);  // view_00 <- view_05 and view_05 <- view_06 at least
}

// The departure bounds also bound a hand view's 1-sigma: at 0.02 deg (below the 1-sigma the
// spread gives views 01 and 02 from 10 deg, 0.04 deg) they are left out, named with the figure;
// without the spread (hand_spread_blocks 0) the graph's 0.0098 deg passes and they are merged.
TEST_F(HandViewRegistration, AHandViewWiderThanTheDepartureBoundIsLeftOutNamed) {
  ProjectMergeOptions options = Defaults();
  options.registration.max_initial_departure_deg = 0.02;
  const ProjectMergeResult r = Merge(10, options);
  for (size_t i : {1, 2}) {
    EXPECT_FALSE(r.views[i].merged) << r.views[i].name;
    EXPECT_NE(r.views[i].reason.find("its pairs do not fix its pose: 1-sigma"), std::string::npos)
        << r.views[i].name << ": " << r.views[i].reason;
  }
  options.registration.hand_spread_blocks = 0;
  const ProjectMergeResult graph_only = Merge(10, options);
  for (size_t i : {1, 2}) EXPECT_TRUE(graph_only.views[i].merged) << graph_only.views[i].reason;
}

}  // namespace
}  // namespace slshadow::multiview
