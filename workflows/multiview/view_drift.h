// The diagnosis across the views of a turntable scan (issue 33, `slshadow shadow PROJECT`): each
// view's measured pose of the part (the twin's pose stage on that view) against the pose the rig's
// turntable model predicts for it, x_rig = axis.RigFromTableTurn(commanded) * rig_from_part0 * x.
//
// Four explanations are fitted to the poses of all views, each with the part's placement on the
// table (rig_from_part0, 6 degrees of freedom) free:
//   none          the turntable model as the rig states it;
//   axis off      the axis direction tilted (2) and its point shifted (2): the views drift from the
//                 model by a rotation that grows with the angle turned;
//   angle scale   the table turns (1 + s) times the commanded angle (1): a rotation about the axis
//                 that grows in proportion to the angle;
//   part slipped  the part moved on the table between view k-1 and view k (6, for each k): the
//                 views from k on share one displacement, the views before it none.
// A pose is compared at probe points on the part (its bounding-box corners), so rotation and
// translation weigh in millimetres; each view's residual is scaled by its pose uncertainty (with a
// floor for the reconstruction's own systematic error). The explanation with the lowest Bayesian
// information criterion (chi^2 + parameters x ln(residuals)) is named when it beats "none" by at
// least `min_evidence`; nothing else is named. A calibration error is not among them: it repeats
// in every view in the camera frame, so the per-view diagnosis names it, and the views' poses keep
// to the turntable model.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "core/rig.h"
#include "core/rigid3.h"

namespace slshadow::multiview {

// One view's measured pose of the part.
struct ViewPose {
  std::string name;
  double table_deg = 0;   // the commanded table angle (the project's)
  Rigid3d rig_from_part;  // measured (the twin's pose stage), part frame = the part file's
  double sigma_mm = 0;    // 1-sigma of a probe point under this pose (0: the floor only)
};

struct ViewDriftOptions {
  // Where pose differences are measured, in the part frame (mm); at least one point.
  std::vector<Eigen::Vector3d> probe_points_in_part;
  // A view's sigma is max(sigma_mm, this): the reconstruction's systematic pose error per view.
  double sigma_floor_mm = 0.002;
  // BIC improvement over "none" needed to name a cause.
  double min_evidence = 25.0;
  void Check() const;  // throws slshadow::Error naming the field
};

enum class DriftCause { kNone, kAxisOff, kAngleScale, kPartSlipped };
std::string ToString(DriftCause cause);  // "none", "axis_off", "angle_scale", "part_slipped"

struct DriftFit {
  DriftCause cause = DriftCause::kNone;
  int parameters = 0;
  double chi2 = 0;
  double bic = 0;
  double rms_mm = 0;       // of the probe-point residuals
  Rigid3d rig_from_part0;  // the part's placement at commanded angle 0
  // kAxisOff: the fitted axis against the stated one.
  double axis_tilt_deg = 0;
  double axis_shift_mm = 0;
  // kAngleScale: the table turns (1 + angle_scale_error) x the stated scale.
  double angle_scale_error = 0;
  // kPartSlipped: the first view after the slip (index into the views) and the slip at the part's
  // centre (mm) and its rotation (deg).
  int slip_view = -1;
  double slip_mm = 0;
  double slip_deg = 0;
};

struct ViewDriftDiagnosis {
  std::vector<DriftFit> fits;  // none, axis off, angle scale, the best slip
  DriftCause cause = DriftCause::kNone;
  std::string finding;  // one sentence naming the cause and its size, or that there is none
  // Per view, in the views' order: how far the view is off the stated model anchored at the first
  // view (the placement the first view's pose gives): the largest probe-point displacement (mm)
  // and the rotation (deg).
  std::vector<double> view_residual_mm;
  std::vector<double> view_rotation_deg;
  const DriftFit& Best() const;  // the fit of `cause`
  nlohmann::json ToJson(const std::vector<ViewPose>& views) const;
};

// Throws slshadow::Error when fewer than 3 views are given, or a view is not finite.
ViewDriftDiagnosis DiagnoseViewDrift(const TurntableAxis& axis, const std::vector<ViewPose>& views,
                                     const ViewDriftOptions& options);

}  // namespace slshadow::multiview
