// Calibration of cameras and projectors from board observations, by one Ceres bundle adjustment.
//
// One problem covers single-camera, stereo, camera-projector and whole-rig calibration: D devices
// (cameras, or a projector as an inverse camera whose "pixels" are projector pixels) observe a
// planar board in P poses. Unknowns, each its own Ceres parameter block:
//   intrinsics of device d  fx fy cx cy k1 k2 p1 p2 k3 (core/camera_model.h, OpenCV's model)
//   dev_from_rig of d > 0   angle-axis (rad) + translation (mm); device 0 defines the rig frame
//   rig_from_board of pose p  angle-axis + translation
// Residual of a board point X (mm, board frame) seen by device d in pose p at pixel u:
//   r = ImgFromCam(intrinsics_d, dev_from_rig_d * rig_from_board_p * X) - u      (px)
// (with estimate_board_warp, X's z is offset by the shared board warp, see CalibrationOptions).
// minimised in the least-squares sense, optionally through a robust loss.
//
// Initialisation (Zhang 2000): per device, intrinsics from the board homographies
// (cv::initCameraMatrix2D), zero distortion, poses by cv::solvePnP, then a per-device bundle
// adjustment; devices are then chained to device 0 through shared poses (median relative pose)
// and everything is refined jointly.
#pragma once

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/rig.h"
#include "core/rigid3.h"

namespace slshadow {

// Observations of one board pose by one device.
struct BoardView {
  int device = 0;     // index into CalibrationInput::devices
  int pose = 0;       // board pose index, 0 .. num_poses-1; views of one pose share its pose
  std::string label;  // for reports, e.g. the image file
  std::vector<Eigen::Vector3d> points_in_board_mm;
  std::vector<Eigen::Vector2d> pixels_px;  // same length as points_in_board_mm

  // Only for a view whose pixels were carried from another device's detections of the same pose
  // (projector corners mapped from the camera's by local homographies, calib/projector.h); empty
  // otherwise, else one entry per point. Pixel i was made from the pixel c of point
  // source_points[i] in `source_device`'s view of this pose: an error e in c moves pixel i by
  // source_jacobians[i] * e, and the carrying adds its own error of covariance
  // carry_covariances_px2[i] (px^2; its shape and relative size matter, its scale is estimated).
  int source_device = -1;
  std::vector<int> source_points;
  std::vector<Eigen::Matrix2d> source_jacobians;       // d pixel / d source pixel
  std::vector<Eigen::Matrix2d> carry_covariances_px2;  // symmetric positive definite
  bool IsCarried() const { return source_device >= 0; }
  void DropCarry();  // makes the view an ordinary one (for a problem without its source device)
};

struct CalibrationDevice {
  std::string name;
  int width = 0;  // image size, px
  int height = 0;
  bool is_projector = false;
  // Starting intrinsics; when absent they are estimated from the homographies.
  std::optional<CameraModel> initial;
  // Keep `initial` fixed (e.g. calibrate a projector against an already calibrated camera).
  bool hold_intrinsics = false;
  // Per-device model selection, on top of CalibrationOptions' holds (which apply to every
  // device): CameraModel parameter indices held at their initial value (0 for distortion when
  // there is no initial model), e.g. {kP1, kP2, kK3} for a projector whose few poses cannot
  // support tangential distortion and k3 (chosen by calib/model_selection.h).
  std::vector<int> held_params;

  // A camera or a projector by name (size 0: taken from its first image), every other field at
  // its default; set the others by name.
  static CalibrationDevice Camera(std::string name, int width = 0, int height = 0) {
    CalibrationDevice d;
    d.name = std::move(name);
    d.width = width;
    d.height = height;
    return d;
  }
  static CalibrationDevice Projector(std::string name, int width, int height) {
    CalibrationDevice d = Camera(std::move(name), width, height);
    d.is_projector = true;
    return d;
  }
};

struct CalibrationInput {
  std::vector<CalibrationDevice> devices;  // device 0 defines the rig frame
  int num_poses = 0;
  std::vector<BoardView> views;

  // Throws slshadow::Error naming the problem: no devices, a bad size, a view whose device or pose
  // is out of range, mismatched point/pixel counts, a carried view whose source view is missing or
  // whose source points or matrices do not match it, fewer than 4 points in a view, collinear
  // board points, a device with fewer than 2 views (unless it has `initial` intrinsics and
  // shares a pose with another device), a device not connected to device 0 by shared poses,
  // hold_intrinsics without initial intrinsics.
  void Check() const;
};

enum class LossType { kNone, kHuber, kCauchy };
std::string ToString(LossType loss);              // "none", "huber", "cauchy"
LossType LossTypeFromString(const std::string&);  // throws slshadow::Error on unknown names

struct CalibrationOptions {
  bool fix_aspect_ratio = false;     // fy / fx held at its initial value (1 when estimated)
  double aspect_ratio = 1.0;         // fy / fx used when fix_aspect_ratio and no initial model
  bool fix_principal_point = false;  // cx, cy held at the image centre or the initial model
  bool zero_tangential = false;      // p1 = p2 = 0
  bool fix_k3 = false;               // k3 = 0 (or its initial value)
  bool fix_intrinsics = false;       // only poses are estimated (stereo with known cameras)
  LossType loss = LossType::kNone;   // robust loss on each point's residual
  double loss_scale_px = 1.0;        // residual size where the robust loss starts to bend, px
  int max_iterations = 200;          // Levenberg-Marquardt iterations per solve
  double outlier_view_factor =
      3.0;  // a view is an outlier when its RMS > factor * its device's median view RMS
  bool compute_covariance = true;  // intrinsics covariance from the Jacobian at the solution
  // Estimate a board warp shared by all poses: z += w_x (1 - s^2) + w_y (1 - t^2) mm, (s, t) the
  // point's position across the board's extent scaled to [-1, 1] (mrcal's board deformation).
  bool estimate_board_warp = false;
  // Noise model of carried views (BoardView::source_device, e.g. projector corners made from the
  // camera's): true weighs each carried point jointly with its source point. The 4x4 covariance of
  // (source residual, carried residual) is [[s^2 I, s^2 J^T], [s^2 J, s^2 J J^T + k C]], s the
  // source device's corner noise, J = source_jacobians[i], C = carry_covariances_px2[i]; s and k
  // are estimated from the residuals of a solve with independent weighting and re-estimated once
  // (CalibrationSummary::noise_sigma_px, carry_scale; from medians with a robust loss, so that
  // outliers do not set the weights), and each pair's stacked residual is
  // whitened by the inverse Cholesky factor inside one cost (the robust loss applies to the
  // whitened 4-vector, its scale loss_scale_px / s). Every other point of device d is weighted by
  // 1 / s_d. false: every point is an independent, equally weighted 2D residual (the carried
  // point's share of its source's error then counts twice). Off by default: on real captures
  // the residuals can be correlated across the corners of a pose, which neither model describes,
  // and the joint model's covariance is then the more optimistic of the two
  // (docs/benchmarks/log/calibration.md); it is the right model when the corner errors are
  // independent (tested).
  bool correlated_carried_noise = false;
  // Bound every estimated device's principal point to its image: -0.5 <= cx <= width - 0.5 and
  // -0.5 <= cy <= height - 0.5 (pixel centres at integers), as Ceres parameter bounds (a start
  // outside is clamped first). Off by default: a projector with lens offset (a table projector
  // throwing upwards) has its principal point outside its image, and the kamino data put it there
  // (docs/benchmarks.md, "Calibration"). Use it when the optics are known to be centred and the
  // data are too weak to locate the principal point. A bound that is active is reported
  // (CalibrationSummary::bounds_active); the covariance is then the unconstrained linearisation
  // at the bounded solution.
  bool principal_point_inside = false;

  // Throws slshadow::Error naming the first violated constraint.
  void Check() const;
};

// Residual statistics of one view (one device, one pose).
struct ViewStats {
  int device = 0;
  int pose = 0;
  std::string label;
  int num_points = 0;
  double rms_px = 0;
  double max_px = 0;     // worst point residual
  bool outlier = false;  // rms_px > outlier_view_factor * median view RMS of the device
};

struct DeviceStats {
  std::string name;
  int num_views = 0;
  int num_points = 0;
  double rms_px = 0;
  double max_px = 0;
};

// What the solver did, in the spirit of ceres::Solver::Summary.
struct CalibrationSummary {
  double initial_cost =
      0;  // Ceres cost (half the sum of squared, loss-mapped residuals) at the start
  double final_cost = 0;
  double rms_px = 0;  // over all points and devices: sqrt(sum |r|^2 / N points)
  double max_px = 0;
  double residual_sigma_px = 0;  // per-coordinate noise estimate sqrt(sum r^2 / (2N - free params))
  int num_points = 0;
  int num_free_parameters = 0;
  int iterations = 0;
  double solve_time_s = 0;  // initialisation and all solves
  bool converged = false;
  std::string termination;  // Ceres' message
  std::vector<DeviceStats> devices;
  std::vector<ViewStats> views;
  int num_outlier_views = 0;
  // Noise model of the final solve (CalibrationOptions::correlated_carried_noise): when
  // joint_noise, each device's own corner noise (px per coordinate, estimated), the factor k on
  // the carried views' carry covariances, and chi^2 / dof of the whitened residuals (the factor
  // the covariance is scaled by instead of residual_sigma_px^2).
  bool joint_noise = false;
  std::vector<double> noise_sigma_px;  // per device
  double carry_scale = 0;
  double variance_factor = 0;
  // The view-correlated noise model behind
  // CalibrationResult::intrinsics_covariance_view_correlated, per device (for a carried device: its
  // own error, beyond the source's carried through J): sigma per coordinate, and the correlation of
  // two corners delta squares apart, share * exp(-delta^2 / (2 length^2)). Fitted to the residuals'
  // moments at 0, 1 and sqrt(2) squares through the residual-maker matrix (the fit absorbs part of
  // correlated errors). share 0: the residuals look independent (neighbour correlation <= 0.1).
  struct ViewNoise {
    double sigma_px = 0;
    double share = 0;
    double length_squares = 1;
  };
  std::vector<ViewNoise> view_noise;
  // With CalibrationOptions::principal_point_inside: one entry per principal-point coordinate
  // that ended on its bound, e.g. "projector cy = 767.5 (upper bound)"; empty otherwise.
  std::vector<std::string> bounds_active;

  std::string BriefReport() const;  // one line
  std::string FullReport() const;   // multi-line: per device and per view, outliers marked
};

using Matrix9d = Eigen::Matrix<double, 9, 9>;

struct CalibrationResult {
  std::vector<RigDevice> devices;  // models and cam_from_rig (device 0: identity)
  // Per pose: rig_from_board (x_in_rig = rig_from_board * x_in_board), absent when no device saw
  // it.
  std::vector<std::optional<Rigid3d>> rig_from_board;
  // Per device: covariance of (fx fy cx cy k1 k2 p1 p2 k3), scaled by residual_sigma_px^2 (with
  // summary.joint_noise: J of the whitened residuals, scaled by summary.variance_factor): the
  // marginal of sigma^2 (J^T J)^-1 over all free parameters (board poses and rig poses included),
  // J the Jacobian at the solution (Jacobi-scaled before inversion). Held parameters have zero
  // rows (fy follows fx when the aspect is fixed; held devices are all zero). Empty when not
  // computed or not estimable (J^T J rank-deficient to 1e-12 after scaling).
  std::vector<Matrix9d> intrinsics_covariance;
  // The same marginal under a noise model whose corner errors are correlated within each pose
  // (summary.view_noise: a Gaussian-correlated error field per device across the board, carried
  // views inheriting their source's field through source_jacobians): the sandwich
  // (J^T J)^-1 J^T Sigma J (J^T J)^-1, Sigma the errors' covariance pose by pose, poses
  // independent. Equals intrinsics_covariance (up to the dof correction) when the residuals look
  // independent. Empty when not computed (no covariance, fix_intrinsics, correlated_carried_noise).
  std::vector<Matrix9d> intrinsics_covariance_view_correlated;
  Eigen::Vector2d board_warp_mm = Eigen::Vector2d::Zero();  // (w_x, w_y); zero unless estimated
  Eigen::Vector4d board_extent_mm =
      Eigen::Vector4d::Zero();  // xmin xmax ymin ymax of the board points
  CalibrationSummary summary;
};

// Calibrates all devices of `input`. Throws slshadow::Error on bad input (input.Check(),
// options.Check()) and when a device cannot be initialised (degenerate views).
CalibrationResult Calibrate(const CalibrationInput& input, const CalibrationOptions& options);

// Board-to-device reprojection of one view with the result's parameters, px.
std::vector<Eigen::Vector2d> Reproject(const CalibrationResult& result, const BoardView& view);

}  // namespace slshadow
