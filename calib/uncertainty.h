// How far a calibration can be trusted, in pixels across the image (after mrcal,
// doc/uncertainty.org and doc/differencing.org).
//
// Projection uncertainty: for a pixel q, take the ray r = Unproject(q) of the estimated model;
// the projection of r moves with the intrinsics p by J = d ImgFromCam(p, r) / d p (2x9), so its
// covariance is J Sigma_p J^T, Sigma_p the marginal intrinsics covariance from the bundle
// adjustment (ceres::Covariance, scaled by the residual variance; it already accounts for the
// board poses being estimated too). The map reports the worst-direction standard deviation
// sqrt(lambda_max(J Sigma_p J^T)), px. Linearised, for points far from the camera (a ray, not a
// point at a finite distance), intrinsics only (extrinsic uncertainty is not in this map).
//
// Frame rotation: a small rotation of the camera frame is undone by the board poses, so a shift
// of cx traded for a rotation of every pose is nearly free, and the raw intrinsics covariance
// overstates how much projections really move (mrcal's point). With `compensate_rotation` the
// map removes, for each parameter perturbation, the best-fitting frame rotation over the whole
// image: M_q = J_q - K_q (sum K^T K)^-1 (sum K^T J), K_q = d proj / d rotation, covariance
// M_q Sigma_p M_q^T. The difference map likewise fits the rotation between the two models'
// frames before measuring.
//
// Cross-validation: calibrate two disjoint halves of the board poses (even and odd indices) and,
// for each pixel q, project the ray Unproject_A(q) with model B: |Project_B(...) - q|, px. When
// the model fits and the data suffice, this difference is comparable to the predicted
// uncertainty (times about sqrt(2)); much larger means model error or too little data.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "calib/calibration.h"

namespace slshadow {

// A scalar field sampled on a grid of cells covering one device's image.
struct PixelMap {
  cv::Mat values;   // CV_32FC1, rows x cols cells; NaN where not defined (unprojection failed)
  int cell_px = 0;  // each cell is cell_px x cell_px image pixels; values at cell centres
  double median = 0;
  double p95 = 0;
  double max = 0;
  double centre = 0;  // at the image centre cell
  // Image pixel (OpenCV convention) at the centre of cell (col, row).
  static Eigen::Vector2d CellCentre(int col, int row, int cell_px) {
    return {(col + 0.5) * cell_px - 0.5, (row + 0.5) * cell_px - 0.5};
  }
};

// Covariance (2x2, px^2) of the projection of the ray through `pixel` under intrinsics
// covariance `covariance`. std::nullopt when the pixel cannot be unprojected.
std::optional<Eigen::Matrix2d> ProjectionCovariance(const CameraModel& model,
                                                    const Matrix9d& covariance,
                                                    const Eigen::Vector2d& pixel);

// Worst-direction projection standard deviation (px) on a grid of `cell_px` cells.
PixelMap ProjectionUncertaintyMap(const CameraModel& model, const Matrix9d& covariance,
                                  int cell_px = 16, bool compensate_rotation = true);

// |Project_b(Unproject_a(q)) - q| (px) on a grid of `cell_px` cells. Both models must have the
// same image size (throws slshadow::Error otherwise).
PixelMap ProjectionDifferenceMap(const CameraModel& a, const CameraModel& b, int cell_px = 16,
                                 bool fit_rotation = true);

// Whether the corner errors are independent, as the covariance assumes: the correlation of the
// residuals of neighbouring board points (one grid spacing apart, the smallest distance between
// two points of a view) within each view of `device`, sum(r_i . r_j) / (pairs * mean |r|^2).
// About 0 (slightly negative, the fit absorbs a little) for independent errors; clearly positive
// means errors shared across a pose (board deformation, detector or decoding bias), which the
// covariance does not see: it is then optimistic. NaN when no view of the device has a
// neighbour pair.
double NeighbourResidualCorrelation(const CalibrationInput& input, const CalibrationResult& result,
                                    int device);

// The covariance a report should quote for one device. The standard one
// (CalibrationResult::intrinsics_covariance) assumes independent corner errors; when the residuals
// show errors shared across each view (summary.view_noise[device].share > 0, from the neighbour
// residual correlation) and the view-correlated covariance widens fx's sigma by more than
// `max_ratio` (GuidanceOptions::max_correlated_sigma_ratio, 1.5: the criterion of calibrate's
// warning), the view-correlated one (intrinsics_covariance_view_correlated) is quoted instead:
// the standard one is then optimistic (docs/benchmarks/log/calibration.md). Otherwise the
// standard one, unchanged.
struct QuotedCovariance {
  bool available = false;        // a standard covariance exists for the device (else all zero)
  bool view_correlated = false;  // which one `covariance` is
  Matrix9d covariance = Matrix9d::Zero();
  double fx_sigma_ratio =
      1;  // view-correlated / standard sigma of fx (1 when there is no view-correlated one)
  std::string reason;  // one line, for reports
};
QuotedCovariance PreferredCovariance(const CalibrationResult& result, int device,
                                     double max_ratio = 1.5);

struct CrossValidation {
  std::vector<CameraModel> half_a;            // per device, from the even poses
  std::vector<CameraModel> half_b;            // per device, from the odd poses
  std::vector<PixelMap> difference;           // per device
  std::vector<CalibrationSummary> summaries;  // of the two halves
};

// Calibrates the even and the odd board poses separately with the same options and compares
// the models per device. Throws slshadow::Error when a half cannot be calibrated (too few views:
// cross-validation needs at least 4 poses per device).
CrossValidation CrossValidate(const CalibrationInput& input, const CalibrationOptions& options,
                              int cell_px = 16);

// Whether CrossValidate can run: every device has views of at least 2 distinct even and 2
// distinct odd poses.
bool CanCrossValidate(const CalibrationInput& input);

}  // namespace slshadow
