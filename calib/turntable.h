// Turntable axis calibration: a calibration board standing on a turntable, seen by the cameras of
// an already calibrated rig at three or more commanded table angles, gives the table's rotation
// axis in the rig frame and the error of its angle scale (core/rig.h TurntableAxis, written as the
// rig YAML's `turntable:`, docs/formats.md "Rig YAML").
//
// Model. Pose p was captured at commanded angle a_p (degrees). A turn by the true angle
// theta(a) = scale * a about the axis through point c with unit direction n (right-handed) moves a
// rig-frame point x to T(a) x = R(n, theta(a)) (x - c) + c (TurntableAxis::RigFromTableTurn). The
// board at pose p is the board at commanded angle 0 turned by T(a_p):
//   rig_from_board(p) = T(a_p) * rig_from_board_at_zero
// and the residual of board point X (mm, board frame) seen by camera k at pixel u is
//   r = ImgFromCam(intrinsics_k, cam_from_rig_k * rig_from_board(p) * X) - u      (px)
// Intrinsics and cam_from_rig come from the rig file and are held fixed. Unknowns (11), each its
// own Ceres block: rig_from_board_at_zero (angle-axis + translation, 6), the direction (2: a step
// in the plane perpendicular to a reference direction, renormalised), the point (2: where the axis
// crosses a plane perpendicular to the reference direction), the scale (1). Minimised over all
// corners of all cameras (Levenberg-Marquardt, optionally through a robust loss).
//
// What is identifiable. The relative turns between poses fix n, c (perpendicular to n) and the
// scale. The angle offset is not: turning the board's pose at zero by any angle about the axis and
// subtracting it from the offset gives the same images, since where the board stands on the table
// is unknown. The angle origin is therefore defined as the table at commanded angle 0 itself (the
// board's pose there, extrapolated when 0 was not captured): angle_offset_deg is 0 by definition
// and its sigma 0 (not estimated). Relative motions, RigFromTableTurn(a) *
// RigFromTableTurn(b)^-1, are what a multi-view merge needs and what is estimated. The scale is
// identifiable from two distinct angles; three are required for redundancy. The point written is
// the axis point nearest to the mean board centre over all poses (about the table's height).
//
// Initialisation (closed form): each camera's view posed by PnP; the axis n is the common null
// vector of R_pq - I over all pose pairs (smallest eigenvector of sum (R_pq - I)^T (R_pq - I)),
// signed so that positive commanded steps turn positively; the scale by least squares of the
// unwrapped turn angles on the commanded differences; c from (I - R_pq) c = t_pq by least squares.
// A board whose corner labelling is symmetric under a half turn (a full chessboard or circle grid
// seen whole: the detector may number it from either end) has each view's labelling chosen to
// match the turn the commanded angles predict; a relabelled view is reported.
//
// Uncertainty: the covariance sigma^2 (J^T J)^-1 of all 11 unknowns at the solution (J Jacobi-
// scaled before inversion, as Calibrate() does), sigma^2 = sum r^2 / (2N - 11) the residual
// variance; the direction and point blocks are taken in the plane perpendicular to the solution's
// axis. Linearised, independent corner errors; the rig's own calibration errors are not included.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "calib/calibration.h"
#include "calib/guidance.h"
#include "calib/target.h"
#include "core/rig.h"

namespace slshadow {

// Board observations at several table angles, by the cameras of a calibrated rig.
struct TurntableInput {
  std::vector<RigDevice> cameras;        // models and cam_from_rig, held fixed
  std::vector<double> commanded_deg;     // per pose: the table angle the controller was told
  std::vector<std::string> pose_labels;  // per pose, for reports (e.g. the folder); may be empty
  // BoardView::device indexes `cameras`, BoardView::pose indexes `commanded_deg`; carried views
  // (BoardView::source_device) are not accepted.
  std::vector<BoardView> views;

  // Throws slshadow::Error naming the problem: no cameras, an invalid camera model, non-finite
  // angles, fewer than 3 distinct commanded angles (equal within 1e-6 deg), a view whose camera or
  // pose is out of range, a carried view, mismatched point and pixel counts, fewer than 4 points
  // in a view, non-finite points or pixels, a pose without any view.
  void Check() const;
};

struct TurntableOptions {
  int max_iterations = 100;          // Levenberg-Marquardt iterations
  LossType loss = LossType::kNone;   // robust loss on each point's residual
  double loss_scale_px = 1.0;        // residual size where the robust loss starts to bend, px
  double min_angle_span_deg = 10.0;  // the commanded angles must span at least this, deg
  // The largest turn between two poses, as the board poses measure it, must reach this (deg):
  // less means the board did not turn with the table (or the angles are a full turn apart).
  double min_measured_turn_deg = 2.0;
  // Each pose's board, posed alone, must lie within this angle (deg) of where the closed-form axis
  // and the commanded angles put it: more means a wrong or misordered angle, angles not in
  // degrees, or a board that slid on the table.
  double max_turn_mismatch_deg = 3.0;
  bool compute_covariance = true;

  // Throws slshadow::Error naming the first violated constraint.
  void Check() const;
};

// Residuals of one view (one camera, one pose).
struct TurntableViewStats {
  int camera = 0;
  int pose = 0;
  std::string label;
  int num_points = 0;
  double rms_px = 0;
  double max_px = 0;
  bool relabelled = false;  // its corner labelling was turned by a half turn (see the top)
};

struct TurntableResult {
  // The axis with its sigmas (1-sigma; direction: worst-direction angle, deg; point: worst
  // direction perpendicular to the axis, mm). angle_offset_deg = 0 by definition (see the top).
  TurntableAxis axis;
  Rigid3d rig_from_board_at_zero;  // the board at commanded angle 0 (x_in_rig = T * x_in_board)
  // Covariance of (direction along u, direction along v [rad], point along u, point along v [mm],
  // scale), u and v the unit vectors below (perpendicular to axis.direction_in_rig and to each
  // other, u x v = direction); zero when not computed or not estimable.
  Eigen::Matrix<double, 5, 5> covariance = Eigen::Matrix<double, 5, 5>::Zero();
  Eigen::Vector3d tangent_u = Eigen::Vector3d::UnitX();
  Eigen::Vector3d tangent_v = Eigen::Vector3d::UnitZ();
  bool covariance_available = false;
  // xmin xmax ymin ymax of all board points: the half turn of a relabelled view maps (x, y) to
  // (xmin + xmax - x, ymin + ymax - y).
  Eigen::Vector4d board_extent_mm = Eigen::Vector4d::Zero();
  // Per pose: the true angle axis.TrueAngleDeg(commanded_deg[p]) and its 1-sigma (|a_p| * sigma
  // of the scale: angles are relative to the table at commanded 0).
  std::vector<double> true_angle_deg;
  std::vector<double> sigma_true_angle_deg;

  // Summary, in the spirit of ceres::Solver::Summary.
  int num_points = 0;
  int num_poses = 0;
  double initial_rms_px = 0;  // at the closed-form initialisation
  double rms_px = 0;          // sqrt(sum |r|^2 / N points)
  double max_px = 0;
  double residual_sigma_px = 0;  // per coordinate, sqrt(sum r^2 / (2N - 11))
  int iterations = 0;
  bool converged = false;
  std::string termination;  // Ceres' message
  int num_relabelled = 0;
  std::vector<TurntableViewStats> views;

  std::string BriefReport() const;  // one line
  std::string FullReport() const;   // the axis with sigmas, then one line per view
};

// Estimates the axis. Throws slshadow::Error on bad input (input.Check(), options.Check()), on
// commanded angles spanning less than options.min_angle_span_deg, on board poses that do not
// turn (largest measured turn < options.min_measured_turn_deg), that no camera could pose, or
// that the commanded angles do not explain (options.max_turn_mismatch_deg; a measured scale
// outside (0.5, 2)).
TurntableResult CalibrateTurntable(const TurntableInput& input, const TurntableOptions& options);

// Where the result puts the pixels of input.views[view], px, in the view's point order (NaN for
// a point behind the camera); for a relabelled view, the half-turned labelling the solve used.
// Throws slshadow::Error when `view` is out of range.
std::vector<Eigen::Vector2d> ReprojectTurntable(const TurntableInput& input,
                                                const TurntableResult& result, size_t view);

// The input from image folders, one per pose: folders[p] holds the images taken at commanded
// angle commanded_deg[p], one per rig camera that saw it, named after the camera
// (`<camera name>.<ext>`, ext as calib/calibration_input.h ImageFiles accepts, case ignored). A
// camera without an image in a folder, or whose image shows no board, has no view of that pose
// (the image checks say why). Throws slshadow::Error naming the folder when it does not exist,
// when it holds no image of any rig camera or two of one camera, when no camera found the board
// in it, when an image's size differs from its camera's, and when the counts of folders and
// angles differ. Appends one ImageCheck per image read.
TurntableInput TurntableInputFromFolders(const Rig& rig, const TargetSpec& spec,
                                         const std::vector<std::filesystem::path>& folders,
                                         const std::vector<double>& commanded_deg,
                                         std::vector<ImageCheck>* checks);

// The commanded angle a folder is named by: its name, a decimal number optionally followed by
// "deg" ("030", "-15.5", "30deg"). Throws slshadow::Error naming the folder otherwise.
double CommandedAngleFromFolderName(const std::filesystem::path& folder);

}  // namespace slshadow
