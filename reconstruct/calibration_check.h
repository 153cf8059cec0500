// Calibration check: does the rig file fit the captures it reconstructs? Judged on the epipolar
// error of the dense correspondences (one figure, one name in text and JSON):
//   projector mode, both projector axes coded: the signed distance of the decoded projector
//     coordinate from the epipolar line of its camera pixel, projector px;
//   stereo, both axes coded: the decoded projector row of the left camera minus that of the right
//     camera at the matched position, projector px (rectification matched the columns; the rows
//     must then agree).
// With one coded axis the triangulation leaves no such residual. Stereo then checks the projector
// error instead when the rig has a (calibrated) projector, a third view: the left camera's decoded
// projector column minus the column the stereo point projects to, projector px. A rig without a
// projector gets the fitted projector error: the stereo points and the left camera's decoded
// columns must fit one 1-D projector (FitOneAxisProjector below: a projective row pair, u = (r1 .
// X) / (r3 . X), with a radial term when the data ask for it); the residual of that fit, projector
// px, is judged as the others are. A right rig leaves the decode noise; a camera turned about the
// baseline (its rows out of register), a wrong lens distortion or swapped cameras warp the cloud in
// a way no projector explains. Blind spots of this variant: errors that map the cloud by a 3-D
// projective transform (a similarity, e.g. a baseline length; a constant disparity offset, e.g. a
// camera turned about the rows' normal or a principal point shifted along the baseline) are
// absorbed by the fit. So is much of any error on the parts of a scene a projector fits whatever
// the rig (a plane): this variant judges a local field (CalibrationCheckSetup::local_blocks)
// against a quarter of the noise_factor (reconstruct.cc, kFittedProjectorNoiseFactor).
//
// The error is split into a systematic part and noise. A smooth field is fitted to it over the
// reference camera's image, robustly (Huber IRLS), in nested groups of terms
//   offset 1 | linear x, y | quadratic x^2, x y, y^2 | radial x r^2, y r^2
// (x, y: normalised camera coordinates scaled to +-1 across the image width). The noise is the
// robust scatter (1.4826 MAD) about the field: the decoding noise of this very capture. The
// systematic part is the field's RMS over the correspondences. It is significant when it exceeds
//   threshold = max(noise_factor x noise, 5 x noise x sqrt(8 / n), min_warning_px)
// (the second term: five standard errors of a field fitted to pure noise, for small n; the third:
// exact, noise-free maps leave no noise to judge by), or a user's fixed threshold. Each group's
// share (RMS of what it adds to the field) names what is likely wrong: offset -> a principal point
// or a rotation of the pose (both shift whole epipolar lines), linear -> a focal length or a
// rotation, quadratic -> the pose, radial -> the distortion, listed by share; the field's size
// ranks them with the gross causes: above 1 px a device bumped comes first (and a wrong rig file or
// swapped names last), above 20 px only a wrong rig file or swapped names, then a bump, are named.
// The epipolar error cannot see errors that move points along epipolar lines (e.g. a camera
// principal point shifted along the baseline): those stay invisible to any such check.
//
// The default noise_factor 1 warns when the calibration's systematic error exceeds the per-point
// decode noise, i.e. when the calibration, not the decoding, dominates a point's error.
//
// The threshold is also given in mm: the depth error a disparity error of that size causes at
// the working distance, threshold_px x Z^2 / (f B), f the focal length of the device whose
// pixels the error is in (the projector), B the baseline of the triangulating pair, Z the scan's
// median range (reconstruct.cc).
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/rigid3.h"

namespace slshadow {

// The residual checked: its name in text and its key in JSON.
enum class CalibrationResidual { kEpipolarError, kProjectorError, kFittedProjectorError };
// "epipolar error", "projector error", "fitted projector error"
std::string ToString(CalibrationResidual residual);
// "epipolar_error_px", "projector_error_px", "fitted_projector_error_px"
const char* ResidualKey(CalibrationResidual residual);

struct CalibrationCheckSetup {
  CalibrationResidual residual = CalibrationResidual::kEpipolarError;
  std::string pair;     // "<camera>-<other device>", for messages
  bool stereo = false;  // wording of the likely causes
  // Fixed threshold on the systematic part, px; 0: automatic (noise_factor x noise); infinity:
  // the check runs and reports but never warns.
  double warning_px = 0;
  double noise_factor = 1.0;       // automatic threshold in units of the noise (> 0)
  double min_warning_px = 0.01;    // floor of the automatic threshold, px
  double working_distance_mm = 0;  // Z
  // Depth error per px of epipolar error at the working distance, Z^2 / (f B); 0: not known.
  double mm_per_px = 0;
  // > 0: the systematic part is that of a local field, the smooth field plus the robust (Huber)
  // mean of the rest in each block of a grid of local_blocks blocks across the image's width
  // (square blocks; blocks of fewer than 30 correspondences add nothing), and the noise the
  // scatter about it. For residuals a fitted model leaves on part of the scene only (the fitted
  // projector error: a plane fits any projector, the relief of a part does not).
  int local_blocks = 0;
};

struct CalibrationCheck {
  static constexpr int kNumGroups = 4;
  static std::string GroupName(int group);  // "offset", "linear", "quadratic", "radial"

  bool available = false;
  std::string unavailable_reason;  // when !available: why (one clause, "because ...")
  std::string pair;
  CalibrationResidual residual = CalibrationResidual::kEpipolarError;
  int64_t count = 0;             // correspondences used
  double median_px = 0;          // signed median of the residual, projector px
  double noise_px = 0;           // robust scatter about the fitted field, projector px
  double systematic_px = 0;      // RMS of the fitted field over the correspondences, projector px
  int local_blocks = 0;          // blocks of the local field (setup.local_blocks); 0: smooth only
  double threshold_px = 0;       // what systematic_px is judged against
  std::string threshold_source;  // "noise" (automatic), "floor" (min_warning_px) or "user"
  double threshold_mm = 0;       // threshold_px as depth error at the working distance (0: unknown)
  double working_distance_mm = 0;
  std::array<double, kNumGroups> group_rms_px{};  // what each nested group adds to the field
  // Ranked, most likely first, by the field's size (above ~20 px: a wrong rig file or swapped
  // names; 1-20 px: a device bumped, then the shape) and shape (the groups in order of share).
  std::vector<std::string> likely_causes;
  // kFittedProjectorError: the fitted projector (OneAxisProjectorFit::Describe()); empty otherwise.
  std::string fitted_projector;
  bool warn = false;

  // One line: the warning (warn), the passed verdict, or "not available, because ...".
  std::string Message() const;
  nlohmann::json ToJson() const;
};

// The check of signed epipolar errors `error_px` at normalised camera coordinates (x, y) (the
// reference camera's undistorted image plane, scaled so that the image's half width is ~1).
// Non-finite entries are ignored; fewer than 100 finite ones make the check unavailable.
CalibrationCheck FitCalibrationCheck(const std::vector<float>& x, const std::vector<float>& y,
                                     const std::vector<float>& error_px,
                                     const CalibrationCheckSetup& setup);

// The check that cannot run, with its reason ("only projector columns are coded: ...").
CalibrationCheck UnavailableCalibrationCheck(const std::string& pair, const std::string& reason);

// A 1-D projector (one coded axis): the projector column a point of the rig frame projects to,
//   u = fx x (1 + k1 r^2 + k2 r^4) + cx,  (x, y) = (X_p / Z_p, Y_p / Z_p),  X_p = proj_from_rig X,
// OpenCV's model (core/camera_model.h) without tangential terms, of which only the column is seen.
// Without the radial terms it is the projective row pair u = (r1 . X) / (r3 . X) (7 degrees of
// freedom; the projector's position along its y axis is then a gauge, fixed at the data's centroid
// row); the radial terms make that row observable.
struct OneAxisProjectorFit {
  bool ok = false;  // false: too few points, or a degenerate fit (reason says which)
  std::string reason;
  Rigid3d proj_from_rig;
  double fx = 0, cx = 0, k1 = 0, k2 = 0;  // projector px; dimensionless
  bool radial = false;                    // k1, k2 fitted (the data asked for them)
  int64_t count = 0;                      // points fitted (after subsampling)
  double rms_px = 0;                      // robust (Huber-weighted) RMS residual, projector px
  double pinhole_rms_px = 0;              // the same without the radial terms
  // The distance of a camera centre `center_in_rig` from the projector's axis line (the line all
  // column planes share, along the projector's y axis), mm: the baseline that triangulates against
  // the columns.
  double BaselineMm(const Eigen::Vector3d& center_in_rig) const;
  // The column of a point, projector px; NaN behind the projector.
  double Column(const Eigen::Vector3d& point_in_rig) const;
  // "pinhole" or "radial (k1 ..., k2 ...)", with fx, cx and the RMS.
  std::string Describe() const;
};

// Fits a 1-D projector to points (rig frame, mm) and their decoded columns (projector px):
// linear least squares on the normalised data (the row pair's DLT, Hartley normalisation), then
// Levenberg-Marquardt on the column residual with Huber weights (bounded influence of mismatches),
// first without, then with the radial terms; the radial fit is kept when it lowers the residual
// sum of squares by more than 25 x the noise variance per added parameter (the data ask for it).
// At most max_points evenly spaced pairs are used. Non-finite pairs are ignored; fewer than 100
// finite ones, or a fit whose points lie mostly behind it, give ok = false. Never throws.
OneAxisProjectorFit FitOneAxisProjector(const std::vector<Eigen::Vector3d>& points_in_rig,
                                        const std::vector<double>& column_px,
                                        size_t max_points = 20000);

}  // namespace slshadow
