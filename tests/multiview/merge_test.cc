#include "workflows/multiview/merge.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "core/error.h"
#include "core/string_printf.h"
#include "tests/multiview/synthetic_views.h"
#include "workflows/multiview/internal/pairwise.h"

namespace slshadow::multiview {
namespace {

using testing::MakeTurntableScan;
using testing::PerturbedInitialPoses;
using testing::TurntableScan;
using testing::TurntableScanOptions;

std::vector<ViewCloud> Views(const std::vector<PointCloud>& clouds,
                             const std::vector<Rigid3d>& initial) {
  std::vector<ViewCloud> views;
  for (size_t k = 0; k < clouds.size(); ++k)
    views.push_back({StringPrintf("view_%02zu", k), &clouds[k], initial[k], true, std::nullopt});
  return views;
}

struct PoseErrors {
  double max_rotation_deg = 0;
  double max_displacement_mm = 0;  // largest displacement of a view's points, over all views
  double median_rotation_deg = 0;
};

PoseErrors ErrorsAgainstTruth(const MergeResult& result, const TurntableScan& scan,
                              const std::vector<PointCloud>& clouds, int skip = -1) {
  PoseErrors e;
  std::vector<double> rot;
  for (size_t k = 0; k < result.views.size(); ++k) {
    if (static_cast<int>(k) == skip) continue;
    const double deg = RotationErrorDeg(result.views[k].part_from_rig, scan.part_from_rig[k]);
    const double mm =
        MaxDisplacementMm(result.views[k].part_from_rig, scan.part_from_rig[k], clouds[k].points);
    const Rigid3d error = result.views[k].part_from_rig * scan.part_from_rig[k].Inverse();
    const Eigen::Vector3d c = scan.axis.point_in_rig_mm;
    const Eigen::Vector3d at_centre = error * c - c;
    std::printf(
        "  %s: rotation error %.5f deg, largest point displacement %.5f mm, at the "
        "part's centre (%.5f, %.5f, %.5f) mm\n",
        result.views[k].name.c_str(), deg, mm, at_centre.x(), at_centre.y(), at_centre.z());
    e.max_rotation_deg = std::max(e.max_rotation_deg, deg);
    e.max_displacement_mm = std::max(e.max_displacement_mm, mm);
    rot.push_back(deg);
  }
  std::sort(rot.begin(), rot.end());
  e.median_rotation_deg = rot[rot.size() / 2];
  return e;
}

class MergeTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    scan_ = new TurntableScan(MakeTurntableScan(TurntableScanOptions{}));
    initial_ = new std::vector<Rigid3d>(PerturbedInitialPoses(*scan_, 0.5, 1.0, 7));
    result_ = new MergeResult(MergeViews(Views(scan_->clouds, *initial_)));
    std::printf("%s", result_->FullReport().c_str());
  }
  static void TearDownTestSuite() {
    delete result_;
    delete initial_;
    delete scan_;
  }
  static TurntableScan* scan_;
  static std::vector<Rigid3d>* initial_;
  static MergeResult* result_;
};
TurntableScan* MergeTest::scan_ = nullptr;
std::vector<Rigid3d>* MergeTest::initial_ = nullptr;
MergeResult* MergeTest::result_ = nullptr;

TEST_F(MergeTest, TurntableViewsRegisterToTheTruth) {
  const MergeResult& r = *result_;
  ASSERT_EQ(r.views.size(), 12u);
  EXPECT_EQ(r.NumAccepted(), 12) << r.BriefReport();
  EXPECT_EQ(r.anchor, 0);
  const PoseErrors before = [&] {
    PoseErrors e;
    for (size_t k = 1; k < 12; ++k)
      e.max_rotation_deg =
          std::max(e.max_rotation_deg, RotationErrorDeg((*initial_)[k], scan_->part_from_rig[k]));
    return e;
  }();
  EXPECT_GT(before.max_rotation_deg, 0.45);
  const PoseErrors e = ErrorsAgainstTruth(r, *scan_, scan_->clouds);
  std::printf(
      "noise 0.02 mm: largest rotation error %.5f deg (median %.5f), largest point "
      "displacement %.5f mm\n",
      e.max_rotation_deg, e.median_rotation_deg, e.max_displacement_mm);
  // Achieved at 0.02 mm noise: rotation 0.0009 deg, displacement 6 um (views 0 and 6 see the
  // part's x-facing walls at grazing incidence, so x rests on the holes and the dome). The
  // issue's 2 um is not reached on this fixture; the bound leaves margin over what is achieved.
  EXPECT_LT(e.max_rotation_deg, 0.002);
  EXPECT_LT(e.max_displacement_mm, 0.010);
  for (const auto& v : r.views) {
    EXPECT_TRUE(v.accepted) << v.name << ": " << v.reason;
    EXPECT_GE(v.pairs, 2) << v.name;
    // The noise estimate from the residuals: the injected 0.02 mm (plus sampling of curved
    // surfaces and normal noise).
    EXPECT_GT(v.noise_mm, 0.015) << v.name;
    EXPECT_LT(v.noise_mm, 0.04) << v.name;
    if (!v.anchor) {
      EXPECT_GT(v.sigma_rotation_deg, 0) << v.name;
      EXPECT_LT(v.sigma_rotation_deg, 0.002) << v.name;
      EXPECT_GT(v.sigma_translation_mm, 0) << v.name;
      // Stated 1-sigma 0.0022-0.0028 mm since the ICP weighs each point by its measured noise
      // (on this fixture's uniform noise the per-point estimates only add scatter).
      EXPECT_LT(v.sigma_translation_mm, 0.003) << v.name;
    }
  }
}

TEST_F(MergeTest, LoopClosesBetterAfterTheGlobalStep) {
  const MergeResult& r = *result_;
  ASSERT_TRUE(r.has_loop);
  EXPECT_GT(r.loop_closure_before_mm, 0);
  EXPECT_LT(r.loop_closure_after_mm, r.loop_closure_before_mm);
  EXPECT_LT(r.loop_closure_after_deg, r.loop_closure_before_deg);
}

// Points of the merged cloud (part frame) on the flat top region x in [2, 18], y in [-48, -12]
// at height 40 of the object frame, and the same for one view.
struct RegionStats {
  size_t count = 0;
  double rms_height_mm = 0;
};
RegionStats FlatRegion(const TurntableScan& scan,
                       const std::vector<Eigen::Vector3d>& points_in_part) {
  const Rigid3d object_from_part = scan.part_from_object.Inverse();
  RegionStats s;
  double sum_sq = 0;
  for (const auto& p : points_in_part) {
    const Eigen::Vector3d q = object_from_part * p;
    if (q.x() < 2 || q.x() > 18 || q.y() < -48 || q.y() > -12 || std::abs(q.z() - 40) > 0.5)
      continue;
    ++s.count;
    sum_sq += (q.z() - 40) * (q.z() - 40);
  }
  s.rms_height_mm = s.count ? std::sqrt(sum_sq / static_cast<double>(s.count)) : 0.0;
  return s;
}

TEST_F(MergeTest, OverlapsAreFusedNotStacked) {
  const MergeResult& r = *result_;
  ASSERT_FALSE(r.merged.empty());
  ASSERT_EQ(r.merged.normals.size(), r.merged.size());
  ASSERT_EQ(r.point_view.size(), r.merged.size());
  ASSERT_NE(r.merged.Scalar("sigma_mm"), nullptr);
  // The top region is seen by every view: stacking would hold about 12 x one view's points.
  std::vector<Eigen::Vector3d> view0;
  for (const auto& p : scan_->clouds[0].points) view0.push_back(r.views[0].part_from_rig * p);
  const RegionStats one = FlatRegion(*scan_, view0);
  const RegionStats merged = FlatRegion(*scan_, r.merged.points);
  std::printf(
      "flat region: one view %zu points, rms %.4f mm; merged %zu points, rms %.4f mm "
      "(cell %.3f mm)\n",
      one.count, one.rms_height_mm, merged.count, merged.rms_height_mm, r.fuse_cell_mm);
  ASSERT_GT(one.count, 500u);
  EXPECT_LT(merged.count, 2 * one.count);
  EXPECT_GT(merged.count, one.count / 3);
  // Fused within the noise: several views averaged per point.
  EXPECT_LT(merged.rms_height_mm, 0.6 * one.rms_height_mm);
  size_t multi = 0;
  for (uint8_t v : r.point_views) multi += v >= 4 ? 1 : 0;
  EXPECT_GT(multi, r.merged.size() / 4);
  // No disagreement where there is none: a small false-alarm share.
  EXPECT_LT(static_cast<double>(r.disagree_points), 0.02 * static_cast<double>(r.merged.size()));
}

TEST(MergeViews, CorruptedViewIsNamedAndLeftOut) {
  const TurntableScan scan = MakeTurntableScan(TurntableScanOptions{});
  std::vector<Rigid3d> initial = PerturbedInitialPoses(scan, 0.5, 1.0, 11);
  // View 5 with its table angle wrong by 20 deg.
  initial[5] = scan.axis.RigFromTableTurn(scan.angles_deg[5] + 20).Inverse();
  const MergeResult r = MergeViews(Views(scan.clouds, initial));
  std::printf("%s", r.FullReport().c_str());
  EXPECT_FALSE(r.views[5].accepted);
  EXPECT_FALSE(r.views[5].reason.empty());
  EXPECT_NE(r.BriefReport().find("left out view_05"), std::string::npos);
  EXPECT_EQ(r.NumAccepted(), 11);
  for (int p : r.point_view) EXPECT_NE(p, 5);
  const PoseErrors e = ErrorsAgainstTruth(r, scan, scan.clouds, 5);
  EXPECT_LT(e.max_rotation_deg, 0.002);
  EXPECT_LT(e.max_displacement_mm, 0.010);
}

// The turntable model: the rig's axis off by 0.2 deg and 0.3 mm, view 7's table stopped 0.3 deg
// short of its commanded angle. The pose graph on the model fits the axis and the angles back.
TEST(MergeViews, TurntableModelFitsTheAxisAndTheAngles) {
  const TurntableScan scan = MakeTurntableScan(TurntableScanOptions{});
  TurntableAxis wrong = scan.axis;
  const Eigen::Vector3d across = scan.axis.direction_in_rig.unitOrthogonal();
  wrong.direction_in_rig = Eigen::AngleAxisd(0.2 * M_PI / 180, across) * scan.axis.direction_in_rig;
  wrong.point_in_rig_mm += 0.3 * across.cross(scan.axis.direction_in_rig);
  std::vector<double> commanded = scan.angles_deg;
  commanded[7] += 0.3;
  std::vector<ViewCloud> views;
  for (size_t k = 0; k < scan.clouds.size(); ++k)
    views.push_back({StringPrintf("view_%02zu", k), &scan.clouds[k],
                     wrong.RigFromTableTurn(commanded[k]).Inverse(), true, commanded[k]});
  MergeOptions options;
  options.turntable = wrong;
  const MergeResult r = MergeViews(views, options);
  std::printf("%s", r.FullReport().c_str());
  ASSERT_TRUE(r.turntable_model);
  EXPECT_EQ(r.NumAccepted(), 12) << r.BriefReport();
  // The axis: direction and the truth's point's distance from the fitted line.
  const double direction_error_deg =
      std::acos(std::min(1.0, r.axis_direction_in_rig.dot(scan.axis.direction_in_rig))) * 180 /
      M_PI;
  const Eigen::Vector3d d = scan.axis.point_in_rig_mm - r.axis_point_in_rig_mm;
  const double point_error_mm =
      (d - r.axis_direction_in_rig * r.axis_direction_in_rig.dot(d)).norm();
  std::printf("axis error %.5f deg / %.5f mm (start 0.2 deg / 0.3 mm)\n", direction_error_deg,
              point_error_mm);
  EXPECT_LT(direction_error_deg, 0.005);
  EXPECT_LT(point_error_mm, 0.01);
  ASSERT_TRUE(r.views[7].table_angle_deg.has_value());
  EXPECT_NEAR(r.views[7].table_angle_correction_deg, -0.3, 0.003);
  const PoseErrors e = ErrorsAgainstTruth(r, scan, scan.clouds);
  // Achieved: 0.0008 deg, 2.1 um (six free unknowns per view: 0.0011 deg, 5.0 um).
  EXPECT_LT(e.max_rotation_deg, 0.002);
  EXPECT_LT(e.max_displacement_mm, 0.004);
  for (const auto& v : r.views) {
    if (v.anchor) continue;
    EXPECT_GT(v.sigma_table_angle_deg, 0) << v.name;
    EXPECT_GT(v.sigma_rotation_deg, 0) << v.name;
  }
  // Six free unknowns per view on the same input, for the record.
  options.turntable_model = false;
  const MergeResult six = MergeViews(views, options);
  EXPECT_FALSE(six.turntable_model);
  const PoseErrors e6 = ErrorsAgainstTruth(six, scan, scan.clouds);
  std::printf("turntable model: %.5f deg / %.5f mm; six DOF per view: %.5f deg / %.5f mm\n",
              e.max_rotation_deg, e.max_displacement_mm, e6.max_rotation_deg,
              e6.max_displacement_mm);
  EXPECT_LT(e.max_displacement_mm, e6.max_displacement_mm);
}

// The ICP sample of a table view (MergeOptions::icp_table_share): the share drawn where the
// points fix the table angle has points that move farther along their normals per radian of
// table turn, |n . (u x (p - c))|, than the evenly strided sample of the same size. With
// icp_table_angles (the default) it is a second sample beside the strided one; without, the one
// ICP sample.
TEST(MergeViews, TableSampleDrawsThePointsThatFixTheTableAngle) {
  const TurntableScan scan = MakeTurntableScan(TurntableScanOptions{});
  const PointCloud& cloud = scan.clouds[1];
  const Eigen::Vector3d u = scan.axis.direction_in_rig.normalized();
  auto mean_g = [&](const internal::ViewGeometry& g, const std::vector<uint32_t>& sample) {
    double sum = 0;
    for (uint32_t i : sample)
      sum += std::abs(g.normals[i].dot(u.cross(cloud.points[i] - scan.axis.point_in_rig_mm)));
    return sum / static_cast<double>(sample.size());
  };
  MergeOptions options;
  options.icp_points = 4000;
  options.icp_table_share = 0;
  internal::ViewGeometry strided, table, one, hand;
  internal::PrepareView(cloud, options, &strided, &scan.axis);
  EXPECT_TRUE(strided.table_sample.empty());
  options.icp_table_share = 0.5;
  internal::PrepareView(cloud, options, &table, &scan.axis);
  internal::PrepareView(cloud, options, &hand, nullptr);  // a hand view: strided only
  options.icp_table_angles = false;
  internal::PrepareView(cloud, options, &one, &scan.axis);
  std::printf(
      "mean |g| of the ICP sample: strided %.2f mm, half by the table turn %.2f mm (the table "
      "angles' sample), %.2f mm (the one sample)\n",
      mean_g(strided, strided.icp_sample), mean_g(table, table.table_sample),
      mean_g(one, one.icp_sample));
  EXPECT_GT(mean_g(table, table.table_sample), 1.3 * mean_g(strided, strided.icp_sample));
  EXPECT_EQ(table.icp_sample, strided.icp_sample);  // the axis' sample stays strided
  EXPECT_GT(mean_g(one, one.icp_sample), 1.3 * mean_g(strided, strided.icp_sample));
  EXPECT_EQ(hand.icp_sample, strided.icp_sample);
  EXPECT_TRUE(hand.table_sample.empty());
  // About icp_points points, none twice.
  EXPECT_GT(table.table_sample.size(), 3600u);
  EXPECT_LE(table.table_sample.size(), 4100u);
  std::vector<uint32_t> sorted = table.table_sample;
  std::sort(sorted.begin(), sorted.end());
  EXPECT_EQ(std::adjacent_find(sorted.begin(), sorted.end()), sorted.end());
}

// The same on the whole merge: the turntable model from the exact axis and angles, the table
// angles' errors (the fitted angle's departure from the commanded, here the true, one) with half
// of the sample drawn by the table turn and with the strided sample alone. On this fixture's
// uniform noise (0.02 mm along the normal, whatever the incidence) the strided sample does better
// (largest 0.00053 against 0.00105 deg; RMS over seeds 1 and 2 0.00056 against 0.00077 deg),
// which is why the table sample fits the angles only (icp_table_angles, on by default with
// k = 30 normals on that sample: variant 3; docs/benchmarks/log/2026-12-07-registration-
// rotation.md, 2026-12-08-rotation-noise-3.md). Here: no view lost, all within 0.002 deg.
TEST(MergeViews, TableSampleKeepsTheTableAngles) {
  const TurntableScan scan = MakeTurntableScan(TurntableScanOptions{});
  std::vector<ViewCloud> views;
  for (size_t k = 0; k < scan.clouds.size(); ++k)
    views.push_back({StringPrintf("view_%02zu", k), &scan.clouds[k],
                     scan.axis.RigFromTableTurn(scan.angles_deg[k]).Inverse(), true,
                     scan.angles_deg[k]});
  double largest[4] = {0, 0, 0, 0};
  std::vector<MergeResult> runs;
  for (int variant = 0; variant < 4; ++variant) {
    MergeOptions options;
    options.turntable = scan.axis;
    options.icp_table_share = variant == 0 ? 0.0 : 0.5;
    options.icp_table_angles = variant >= 2;
    // Variant 3: k = 30 PCA normals on the table sample only (icp_table_normals_only).
    options.icp_normal_neighbors = variant == 3 ? 30 : 0;
    options.icp_table_normals_only = variant == 3;
    runs.push_back(MergeViews(views, options));
    const MergeResult& r = runs.back();
    ASSERT_TRUE(r.turntable_model);
    EXPECT_EQ(r.NumAccepted(), 12) << r.BriefReport();
    for (const auto& v : r.views) {
      if (v.anchor) continue;
      ASSERT_TRUE(v.table_angle_deg.has_value()) << v.name;
      largest[variant] = std::max(largest[variant], std::abs(v.table_angle_correction_deg));
    }
  }
  std::printf(
      "largest table angle error: strided %.5f deg, half by the table turn %.5f deg, the axis "
      "strided and the angles by the table turn (icp_table_angles) %.5f deg, the same with "
      "k = 30 normals on the table sample only %.5f deg\n",
      largest[0], largest[1], largest[2], largest[3]);
  EXPECT_LT(largest[1], 0.002);
  EXPECT_LT(largest[0], 0.002);
  EXPECT_LT(largest[2], 0.002);
  EXPECT_LT(largest[3], 0.002);
  // Run j's axis is run i's; the largest difference of their table angles.
  auto same_axis = [&](size_t i, size_t j) {
    EXPECT_LT((runs[j].axis_direction_in_rig - runs[i].axis_direction_in_rig).norm(), 1e-9);
    EXPECT_LT((runs[j].axis_point_in_rig_mm - runs[i].axis_point_in_rig_mm).norm(), 1e-7);
  };
  auto angles_apart = [&](size_t i, size_t j) {
    double d = 0;
    for (size_t v = 0; v < runs[i].views.size(); ++v)
      d = std::max(d, std::abs(runs[j].views[v].table_angle_correction_deg -
                               runs[i].views[v].table_angle_correction_deg));
    return d;
  };
  // icp_table_normals_only: the strided phase with the clouds' own normals, so the axis is
  // variant 0's although icp_normal_neighbors is 30; the angles are not variant 2's.
  same_axis(0, 3);
  EXPECT_GT(angles_apart(2, 3), 1e-6);
  // icp_table_angles: the axis is the strided sample's (the same pairs and graph as variant 0),
  // held while the angles are re-fitted; the angles are not the strided ones.
  same_axis(0, 2);
  EXPECT_GT((runs[1].axis_point_in_rig_mm - runs[0].axis_point_in_rig_mm).norm(), 1e-6);
  EXPECT_GT(angles_apart(0, 2), 1e-6);
  EXPECT_GT(runs[2].axis_sigma_point_mm, 0);
}

TEST(MergeViews, BumpInOneViewIsFlaggedAndKeptApart) {
  const TurntableScan scan = MakeTurntableScan(TurntableScanOptions{});
  std::vector<PointCloud> clouds = scan.clouds;
  constexpr int kBumpView = 3;
  constexpr double kHeight = 0.3, kRadius = 6;
  testing::AddBump(scan, kBumpView, kHeight, kRadius, &clouds[kBumpView]);
  const MergeResult r = MergeViews(Views(clouds, PerturbedInitialPoses(scan, 0.5, 1.0, 13)));
  std::printf("%s\n", r.BriefReport().c_str());
  ASSERT_EQ(r.NumAccepted(), 12);
  const Rigid3d object_from_part = scan.part_from_object.Inverse();
  const Eigen::Vector3d spot = testing::FlatSpotInObject();
  size_t inner = 0, inner_flagged = 0, apart_raised = 0, outer = 0, outer_flagged = 0;
  for (size_t i = 0; i < r.merged.size(); ++i) {
    const Eigen::Vector3d q = object_from_part * r.merged.points[i];
    if (std::abs(q.z() - spot.z()) > 1.0) continue;
    const double d = std::hypot(q.x() - spot.x(), q.y() - spot.y());
    if (d < 0.4 * kRadius) {
      ++inner;
      inner_flagged += r.disagree[i];
      if (r.point_view[i] == kBumpView && r.point_views[i] == 1 && r.disagree[i] &&
          q.z() - spot.z() > 0.5 * kHeight)
        ++apart_raised;
    } else if (d > kRadius + 2 && d < kRadius + 8 && q.x() > 2 && q.x() < 18) {
      ++outer;
      outer_flagged += r.disagree[i];
    }
  }
  std::printf(
      "bump: %zu of %zu points flagged inside, %zu of the bump view kept apart; %zu of "
      "%zu flagged around it\n",
      inner_flagged, inner, apart_raised, outer_flagged, outer);
  ASSERT_GT(inner, 50u);
  // At about one point per view and cell, some cells hold no point of the bump view and cannot
  // disagree; measured: 62 of 110 flagged, 32 raised points of the bump view kept apart.
  EXPECT_GT(static_cast<double>(inner_flagged), 0.4 * static_cast<double>(inner));
  EXPECT_GT(apart_raised, inner / 5);
  ASSERT_GT(outer, 100u);
  EXPECT_LT(static_cast<double>(outer_flagged), 0.05 * static_cast<double>(outer));
}

TEST(MergeViews, OptionsCheckNamesTheField) {
  MergeOptions o;
  EXPECT_NO_THROW(o.Check());
  o.initial_gate_mm = 0;
  try {
    o.Check();
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("initial_gate_mm"), std::string::npos) << e.what();
  }
  o = MergeOptions();
  o.min_pair_overlap = 1.5;
  EXPECT_THROW(o.Check(), Error);
  o = MergeOptions();
  o.max_pair_rms_ratio = 1.0;
  EXPECT_THROW(o.Check(), Error);
  o = MergeOptions();
  o.icp_max_surface_variation = 0.5;
  EXPECT_THROW(o.Check(), Error);
  o = MergeOptions();
  o.fuse_cell_mm = -1;
  EXPECT_THROW(o.Check(), Error);
  o = MergeOptions();
  o.icp_table_share = 1.5;
  try {
    o.Check();
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("icp_table_share"), std::string::npos) << e.what();
  }
  o = MergeOptions();
  o.icp_hold_gate_sigmas = -1;
  try {
    o.Check();
    FAIL() << "no throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("icp_hold_gate_sigmas"), std::string::npos) << e.what();
  }
}

TEST(MergeViews, BadInputThrows) {
  EXPECT_THROW(MergeViews({}), Error);
  PointCloud cloud;
  for (int i = 0; i < 100; ++i) cloud.points.emplace_back(i % 10, i / 10, 500);
  EXPECT_THROW(MergeViews({{"a", nullptr, Rigid3d(), true, std::nullopt}}), Error);
  EXPECT_THROW(MergeViews({{"a", &cloud, Rigid3d(), true, std::nullopt},
                           {"a", &cloud, Rigid3d(), true, std::nullopt}}),
               Error);
  PointCloud tiny;
  tiny.points.emplace_back(0, 0, 500);
  EXPECT_THROW(MergeViews({{"a", &tiny, Rigid3d(), true, std::nullopt}}), Error);
}

}  // namespace
}  // namespace slshadow::multiview
