// Internal to calib/ (calib/internal/: not part of the public API; include only from calib/*.cc).
// Noise models of Calibrate(): the joint model's weights (CalibrationOptions::
// correlated_carried_noise) and the view-correlated model behind
// CalibrationResult::intrinsics_covariance_view_correlated: corner errors as Gaussian-correlated
// fields across the board, carried points inheriting their source's field.
#pragma once

#include <utility>
#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>

#include "calib/internal/calibration_problem.h"

namespace slshadow::calib::internal {

// Covariance (px^2, 2x2) of the errors of point ia of view va and point ib of view vb of the same
// pose under the view-correlated noise model (CalibrationResult::correlated_covariance): each
// point's error is M e(X) + h(X), e the error field of its source device (the device itself, or
// the device its pixels were carried from, M = J then, else I) and h the carried device's own
// field; each field is Gaussian-correlated across the board, independent between devices.
Eigen::Matrix2d PointPairCovariance(const std::vector<ViewNoiseKernel>& kernels,
                                    const BoardView& va, size_t ia, const BoardView& vb, size_t ib,
                                    double spacing_mm);

// Smallest distance between two board points of a view (the grid spacing), mm.
double GridSpacing(const BoardView& v);

// The view-correlated covariance of all free parameters (the sandwich
// (J^T J)^-1 J^T Sigma J (J^T J)^-1, Sigma the errors' covariance pose by pose), for Solve. The
// rows of `crs` and `residuals` are the single-point blocks in `block_points` order (two each);
// `inv` is (J^T J)^-1. When the first guess in `kernels` shows correlation, each device's kernel is
// refitted to the residuals' moments first and written back (Solve's comment says how).
Eigen::MatrixXd ViewCorrelatedCovariance(const CalibrationInput& input,
                                         const std::vector<std::pair<int, int>>& block_points,
                                         const std::vector<double>& residuals,
                                         const ceres::CRSMatrix& crs, const Eigen::MatrixXd& inv,
                                         int cols, std::vector<ViewNoiseKernel>* kernels);

// First guess of the view-correlated noise model's kernels from the residuals at `s`: per device,
// the residuals of its points, or for a carried view their own part d = r - J r_source; sigma is
// their RMS per coordinate, and their correlation at 1 and sqrt(2) squares (rho1, rho2) fixes the
// Gaussian: length^2 = 1 / (2 ln(rho1 / rho2)), share = rho1 exp(1 / (2 length^2)), at most 1;
// rho1 <= 0.1 counts as independent errors (share 0). The fit absorbs the smooth part of the
// errors, so residuals are smaller and shorter-correlated than the errors; Solve() then fits the
// kernel to the residual moments through the residual-maker matrix I - J (J^T J)^-1 J^T.
std::vector<ViewNoiseKernel> EstimateViewKernels(const CalibrationInput& input, const State& s);

// The joint noise model's weights from the residuals at `s`: each device's corner noise (RMS per
// coordinate of its points) and k, the scale of the carry covariances: for a carried point i and
// its source point, d = r_i - J_i r_source has covariance k C_i alone (the source's error
// cancels), so k = mean(d^T C_i^-1 d) / 2 (medians with a robust loss, below).
NoiseModel EstimateNoise(const CalibrationInput& input, const State& s, bool robust);

}  // namespace slshadow::calib::internal
