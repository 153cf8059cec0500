// The diagnosis across views on poses made from a known turntable: the stated axis, an axis off
// by 0.05 deg, a table turning 0.1 % more than commanded, a part slipped 0.2 mm between two views.
// Each is named, with its size, and nothing else; per-view pose noise at the floor's level.
#include "workflows/multiview/view_drift.h"

#include <random>

#include <gtest/gtest.h>

#include "core/error.h"

namespace slshadow::multiview {
namespace {

constexpr double kRad = M_PI / 180.0;

TurntableAxis StatedAxis() {
  TurntableAxis axis;
  axis.direction_in_rig = Eigen::Vector3d(0.05, -0.95, -0.3).normalized();
  axis.point_in_rig_mm = Eigen::Vector3d(2.0, 40.0, 480.0);
  return axis;
}

ViewDriftOptions Options() {
  ViewDriftOptions o;
  for (int i = 0; i < 8; ++i) {
    o.probe_points_in_part.emplace_back((i & 1) ? 30 : -30, (i & 2) ? 20 : -20, (i & 4) ? 25 : 0);
  }
  return o;
}

const Rigid3d kPlacement(
    Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 2, 3).normalized())),
    Eigen::Vector3d(1.5, 35.0, 470.0));

// Views every 45 deg with their true poses under `truth`, the slip (in the rig frame at angle 0)
// applied from view `slip_view` on, and pose noise of `noise_mm` at the probe points' scale.
std::vector<ViewPose> MakeViews(const TurntableAxis& truth, int slip_view, const Rigid3d& slip,
                                double noise_mm, uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<ViewPose> views;
  for (int v = 0; v < 8; ++v) {
    const double deg = 45.0 * v;
    Rigid3d placement = kPlacement;
    if (slip_view >= 0 && v >= slip_view) placement = slip * placement;
    Rigid3d pose = truth.RigFromTableTurn(deg) * placement;
    // Noise about the probe points' centre (0, 0, 12.5) in the part frame: a rotation of
    // noise / 38 mm radians (38 mm: the probe points' RMS radius) and a shift of noise mm, per
    // axis.
    const Eigen::Vector3d w(n(rng), n(rng), n(rng));
    const Eigen::Vector3d t(n(rng), n(rng), n(rng));
    const Eigen::Vector3d centre(0, 0, 12.5);
    const Eigen::Quaterniond r = QuaternionFromRotationVector(w * noise_mm / 38.0);
    pose = pose * Rigid3d(r, centre - r * centre + t * noise_mm);
    views.push_back({"view_0" + std::to_string(v), deg, pose, 0.0});
  }
  return views;
}

TEST(ViewDrift, StatedTurntableNamesNothing) {
  const ViewDriftDiagnosis d =
      DiagnoseViewDrift(StatedAxis(), MakeViews(StatedAxis(), -1, {}, 0.001, 1), Options());
  EXPECT_EQ(d.cause, DriftCause::kNone) << d.finding;
  EXPECT_LT(d.fits[0].rms_mm, 0.003);
  EXPECT_EQ(d.view_residual_mm.size(), 8u);
}

TEST(ViewDrift, AxisOffIsNamedWithItsTilt) {
  TurntableAxis truth = StatedAxis();
  const Eigen::Vector3d perp = truth.direction_in_rig.unitOrthogonal();
  truth.direction_in_rig =
      (Eigen::AngleAxisd(0.05 * kRad, perp) * truth.direction_in_rig).normalized();
  const auto views = MakeViews(truth, -1, {}, 0.001, 2);
  const ViewDriftDiagnosis d = DiagnoseViewDrift(StatedAxis(), views, Options());
  ASSERT_EQ(d.cause, DriftCause::kAxisOff) << d.finding;
  EXPECT_NEAR(d.Best().axis_tilt_deg, 0.05, 0.005);
  // The drift grows with the angle turned: the view at 180 deg is off the most.
  EXPECT_GT(d.view_residual_mm[4], 2 * d.view_residual_mm[1]);
  EXPECT_LT(d.view_residual_mm[0], 0.01);
  EXPECT_NE(d.finding.find("axis is off"), std::string::npos);
  EXPECT_EQ(d.ToJson(views)["cause"], "axis_off");
}

TEST(ViewDrift, AngleScaleIsNamedWithItsSize) {
  TurntableAxis truth = StatedAxis();
  truth.angle_scale = 1.001;
  const ViewDriftDiagnosis d =
      DiagnoseViewDrift(StatedAxis(), MakeViews(truth, -1, {}, 0.001, 3), Options());
  ASSERT_EQ(d.cause, DriftCause::kAngleScale) << d.finding;
  EXPECT_NEAR(d.Best().angle_scale_error, 0.001, 0.00005);
}

TEST(ViewDrift, SlipIsNamedBetweenItsViews) {
  const Rigid3d slip(Eigen::Quaterniond::Identity(), Eigen::Vector3d(0.2, 0.0, 0.0));
  const auto views = MakeViews(StatedAxis(), 5, slip, 0.001, 4);
  const ViewDriftDiagnosis d = DiagnoseViewDrift(StatedAxis(), views, Options());
  ASSERT_EQ(d.cause, DriftCause::kPartSlipped) << d.finding;
  EXPECT_EQ(d.Best().slip_view, 5);
  EXPECT_NEAR(d.Best().slip_mm, 0.2, 0.01);
  EXPECT_NE(d.finding.find("'view_04' and 'view_05'"), std::string::npos) << d.finding;
  const nlohmann::json j = d.ToJson(views);
  EXPECT_EQ(j["fits"][3]["slip_before_view"], "view_05");
}

TEST(ViewDrift, NoiseAloneAcrossSeedsNamesNothing) {
  // At the floor's noise level, twenty seeds of the stated turntable: no false cause.
  for (uint32_t seed = 10; seed < 30; ++seed) {
    const ViewDriftDiagnosis d =
        DiagnoseViewDrift(StatedAxis(), MakeViews(StatedAxis(), -1, {}, 0.002, seed), Options());
    EXPECT_EQ(d.cause, DriftCause::kNone) << "seed " << seed << ": " << d.finding;
  }
}

TEST(ViewDrift, BadInputIsNamed) {
  auto views = MakeViews(StatedAxis(), -1, {}, 0.0, 5);
  views.resize(2);
  EXPECT_THROW(DiagnoseViewDrift(StatedAxis(), views, Options()), Error);
  views = MakeViews(StatedAxis(), -1, {}, 0.0, 5);
  views[3].table_deg = std::nan("");
  try {
    DiagnoseViewDrift(StatedAxis(), views, Options());
    FAIL();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("view_03"), std::string::npos) << e.what();
  }
  ViewDriftOptions empty;
  EXPECT_THROW(DiagnoseViewDrift(StatedAxis(), MakeViews(StatedAxis(), -1, {}, 0.0, 5), empty),
               Error);
}

}  // namespace
}  // namespace slshadow::multiview
