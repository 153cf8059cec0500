// calib/noise_model.cc (internal to calib/): the noise models' closed forms on hand-made views
// whose residuals are set exactly (pixels = the state's projection + a chosen offset), so each
// estimate has a value worked out by hand in the comment above its check.
#include "calib/internal/noise_model.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>

namespace slshadow::calib::internal {
namespace {

constexpr int kCols = 5, kRows = 4;
constexpr double kSpacingMm = 20;

// One pose of a 5 x 4 grid (20 mm squares) half a metre in front of device 0; device 1 (when
// asked for) 100 mm to its right.
struct Problem {
  CalibrationInput input;
  State state;
};

Problem MakeProblem(int devices) {
  Problem p;
  p.input.num_poses = 1;
  for (int d = 0; d < devices; ++d) {
    p.input.devices.push_back(CalibrationDevice::Camera("cam" + std::to_string(d), 1000, 800));
    p.state.intrinsics.push_back({800, 800, 500, 400, 0, 0, 0, 0, 0});
    p.state.aspect.push_back(0);
    p.state.dev_from_rig.push_back({0, 0, 0, -100.0 * d, 0, 0});
  }
  p.state.rig_from_board = {{0.1, -0.05, 0, -40, -30, 500}};
  p.state.pose_known = {true};
  return p;
}

// Device d's view of the grid, its pixel i at the projection plus offset(i, col, row).
template <typename Offset>
BoardView MakeView(const State& s, int device, Offset offset) {
  BoardView v;
  v.device = device;
  for (int r = 0; r < kRows; ++r) {
    for (int c = 0; c < kCols; ++c)
      v.points_in_board_mm.emplace_back(c * kSpacingMm, r * kSpacingMm, 0);
  }
  v.pixels_px.resize(v.points_in_board_mm.size());
  for (size_t i = 0; i < v.pixels_px.size(); ++i) {
    const int c = static_cast<int>(i) % kCols, r = static_cast<int>(i) / kCols;
    v.pixels_px[i] = ProjectView(s, v, i) + offset(c, r);
  }
  return v;
}

TEST(GridSpacing, SmallestDistanceBetweenBoardPoints) {
  const Problem p = MakeProblem(1);
  const BoardView v =
      MakeView(p.state, 0, [](int, int) -> Eigen::Vector2d { return Eigen::Vector2d::Zero(); });
  EXPECT_DOUBLE_EQ(GridSpacing(v), kSpacingMm);
  BoardView one;
  one.points_in_board_mm = {Eigen::Vector3d(1, 2, 0)};
  EXPECT_EQ(GridSpacing(one), 1.0);  // no pair: one square
  one.points_in_board_mm.push_back(one.points_in_board_mm[0]);
  EXPECT_EQ(GridSpacing(one), 1.0);  // coincident points: not a spacing
}

// Same device: sigma^2 at distance 0, sigma^2 share exp(-delta^2 / (2 length^2)) at delta squares;
// devices whose errors are independent: zero; a carried view inherits its source's field through
// J and adds its own.
TEST(PointPairCovariance, GaussianKernelAcrossTheBoardAndCarriedFields) {
  const Problem p = MakeProblem(2);
  const auto zero = [](int, int) -> Eigen::Vector2d { return Eigen::Vector2d::Zero(); };
  const BoardView a = MakeView(p.state, 0, zero), b = MakeView(p.state, 1, zero);
  std::vector<ViewNoiseKernel> kernels(2);
  kernels[0] = {.sigma_px = 0.5, .share = 0.6, .length_squares = 1.5};
  kernels[1] = {.sigma_px = 0.2, .share = 0.3, .length_squares = 0.8};
  const Eigen::Matrix2d identity = Eigen::Matrix2d::Identity();
  const auto rho0 = [&](double delta) {
    return delta == 0 ? 0.25 : 0.25 * 0.6 * std::exp(-delta * delta / (2 * 1.5 * 1.5));
  };
  const auto rho1 = [&](double delta) {
    return delta == 0 ? 0.04 : 0.04 * 0.3 * std::exp(-delta * delta / (2 * 0.8 * 0.8));
  };
  EXPECT_TRUE(PointPairCovariance(kernels, a, 0, a, 0, kSpacingMm).isApprox(rho0(0) * identity));
  EXPECT_TRUE(PointPairCovariance(kernels, a, 0, a, 1, kSpacingMm).isApprox(rho0(1) * identity));
  // Points 0 and kCols + 1: one square across, one down.
  EXPECT_TRUE(PointPairCovariance(kernels, a, 0, a, kCols + 1, kSpacingMm)
                  .isApprox(rho0(std::sqrt(2)) * identity));
  EXPECT_TRUE(PointPairCovariance(kernels, a, 3, b, 3, kSpacingMm).isZero());

  // Device 1 carried from device 0: pixel i made from device 0's pixel i through J.
  BoardView c = b;
  Eigen::Matrix2d J;
  J << 2, 0.5, -0.25, 1;
  c.source_device = 0;
  for (size_t i = 0; i < c.pixels_px.size(); ++i) {
    c.source_points.push_back(static_cast<int>(i));
    c.source_jacobians.push_back(J);
    c.carry_covariances_px2.push_back(identity);
  }
  EXPECT_TRUE(PointPairCovariance(kernels, c, 2, a, 2, kSpacingMm).isApprox(rho0(0) * J));
  EXPECT_TRUE(
      PointPairCovariance(kernels, a, 0, c, 1, kSpacingMm).isApprox(rho0(1) * J.transpose()));
  EXPECT_TRUE(PointPairCovariance(kernels, c, 0, c, 1, kSpacingMm)
                  .isApprox(rho0(1) * J * J.transpose() + rho1(1) * identity));
  EXPECT_TRUE(PointPairCovariance(kernels, c, 4, b, 4, kSpacingMm).isZero());
}

// Every residual (0.3, 0.4): per-coordinate variance samples |r|^2 / 2 = 0.125, so sigma is
// sqrt(0.125) from their mean and sqrt(0.125 / ln 2) from their median (robust); no carried view:
// the carry scale stays 1; a pose not yet known contributes nothing.
TEST(EstimateNoise, SigmaFromTheResidualsMeanOrMedian) {
  Problem p = MakeProblem(1);
  p.input.views.push_back(
      MakeView(p.state, 0, [](int, int) -> Eigen::Vector2d { return Eigen::Vector2d(0.3, 0.4); }));
  const NoiseModel plain = EstimateNoise(p.input, p.state, false);
  ASSERT_EQ(plain.sigma_px.size(), 1u);
  EXPECT_NEAR(plain.sigma_px[0], std::sqrt(0.125), 1e-9);
  EXPECT_EQ(plain.carry_scale, 1.0);
  const NoiseModel robust = EstimateNoise(p.input, p.state, true);
  EXPECT_NEAR(robust.sigma_px[0], std::sqrt(0.125 / std::log(2.0)), 1e-9);
  p.state.pose_known = {false};
  EXPECT_EQ(EstimateNoise(p.input, p.state, false).sigma_px[0], 1.0);
}

// A carried view whose pixels are the projection + J (its source's residual) + d, d = (0.2, 0)
// and carry covariance diag(0.01, 0.04): d^T C^-1 d / 2 = 2 for every point, so k = 2; the
// carried device's sigma comes from its whole residual r = J r_source + d.
TEST(EstimateNoise, CarryScaleFromTheCarriedViewsOwnPart) {
  Problem p = MakeProblem(2);
  const Eigen::Vector2d r0(0.1, -0.05), d(0.2, 0);
  Eigen::Matrix2d J, C;
  J << 1.5, 0.2, 0, 0.8;
  C << 0.01, 0, 0, 0.04;
  p.input.views.push_back(MakeView(p.state, 0, [&](int, int) -> Eigen::Vector2d { return r0; }));
  BoardView carried = MakeView(p.state, 1, [&](int, int) -> Eigen::Vector2d { return J * r0 + d; });
  carried.source_device = 0;
  for (size_t i = 0; i < carried.pixels_px.size(); ++i) {
    carried.source_points.push_back(static_cast<int>(i));
    carried.source_jacobians.push_back(J);
    carried.carry_covariances_px2.push_back(C);
  }
  p.input.views.push_back(carried);
  const NoiseModel noise = EstimateNoise(p.input, p.state, false);
  EXPECT_NEAR(noise.carry_scale, 2.0, 1e-9);
  EXPECT_NEAR(noise.sigma_px[0], r0.norm() / std::sqrt(2), 1e-9);
  EXPECT_NEAR(noise.sigma_px[1], (J * r0 + d).norm() / std::sqrt(2), 1e-9);
  EXPECT_NEAR(EstimateNoise(p.input, p.state, true).carry_scale, 2.0 / std::log(2.0), 1e-9);
}

// The kernels' first guess from lag-1 and lag-sqrt(2) correlations. Equal residuals everywhere:
// rho1 = rho2 = 1, the ratio floored at 1.05, so length^2 = 1 / (2 ln 1.05) and the share
// min(1, rho1 exp(1 / (2 length^2))) = min(1, 1.05) = 1. Signs alternating like a chessboard:
// neighbours anti-correlated (rho1 = -1), independent errors (share 0, length 1).
TEST(EstimateViewKernels, CorrelationLengthAndShareFromNeighbouringResiduals) {
  Problem p = MakeProblem(1);
  p.input.views.push_back(
      MakeView(p.state, 0, [](int, int) -> Eigen::Vector2d { return Eigen::Vector2d(0.3, 0.4); }));
  std::vector<ViewNoiseKernel> k = EstimateViewKernels(p.input, p.state);
  ASSERT_EQ(k.size(), 1u);
  EXPECT_NEAR(k[0].sigma_px, std::sqrt(0.125), 1e-9);
  EXPECT_NEAR(k[0].length_squares, std::sqrt(1 / (2 * std::log(1.05))), 1e-9);
  EXPECT_DOUBLE_EQ(k[0].share, 1.0);

  p.input.views[0] = MakeView(p.state, 0, [](int c, int r) -> Eigen::Vector2d {
    return Eigen::Vector2d(0.3, 0.4) * ((c + r) % 2 == 0 ? 1.0 : -1.0);
  });
  k = EstimateViewKernels(p.input, p.state);
  EXPECT_NEAR(k[0].sigma_px, std::sqrt(0.125), 1e-9);
  EXPECT_EQ(k[0].share, 0.0);
  EXPECT_EQ(k[0].length_squares, 1.0);
}

// Independent errors (share 0, as EstimateViewKernels' first guess says for uncorrelated
// residuals): no refit, and the sandwich (J^T J)^-1 J^T (sigma^2 I) J (J^T J)^-1 collapses to
// sigma^2 (J^T J)^-1 whatever J is (a fixed pseudo-random dense J over 3 columns, as a CRS matrix).
TEST(ViewCorrelatedCovariance, IndependentErrorsGiveSigmaSquaredTimesTheInverse) {
  Problem p = MakeProblem(1);
  p.input.views.push_back(
      MakeView(p.state, 0, [](int, int) -> Eigen::Vector2d { return Eigen::Vector2d::Zero(); }));
  const int points = 6, cols = 3;
  std::vector<std::pair<int, int>> block_points;
  for (int i = 0; i < points; ++i) block_points.emplace_back(0, i);
  Eigen::MatrixXd j(2 * points, cols);
  for (int r = 0; r < j.rows(); ++r) {
    for (int c = 0; c < cols; ++c) j(r, c) = std::sin(1.0 + 0.7 * (c + 1) * r + c);
  }
  ceres::CRSMatrix crs;
  crs.num_rows = static_cast<int>(j.rows());
  crs.num_cols = cols;
  crs.rows.push_back(0);
  for (int r = 0; r < j.rows(); ++r) {
    for (int c = 0; c < cols; ++c) {
      crs.cols.push_back(c);
      crs.values.push_back(j(r, c));
    }
    crs.rows.push_back(static_cast<int>(crs.cols.size()));
  }
  std::vector<double> residuals(static_cast<size_t>(j.rows()));
  for (size_t k = 0; k < residuals.size(); ++k) residuals[k] = 0.1 * std::cos(2.0 * k);
  const Eigen::MatrixXd inv = (j.transpose() * j).inverse();
  std::vector<ViewNoiseKernel> kernels = {{.sigma_px = 0.5, .share = 0, .length_squares = 1}};
  const Eigen::MatrixXd cov =
      ViewCorrelatedCovariance(p.input, block_points, residuals, crs, inv, cols, &kernels);
  EXPECT_TRUE(cov.isApprox(0.25 * inv, 1e-9)) << cov << "\n\n" << 0.25 * inv;
  EXPECT_EQ(kernels[0].share, 0.0);  // not refitted
  EXPECT_EQ(kernels[0].sigma_px, 0.5);
}

}  // namespace
}  // namespace slshadow::calib::internal
