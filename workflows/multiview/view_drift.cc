#include "workflows/multiview/view_drift.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Geometry>

#include "core/error.h"
#include "core/string_printf.h"

namespace slshadow::multiview {
namespace {

constexpr double kDegPerRad = 180.0 / M_PI;

// Two unit vectors perpendicular to `d` and to each other.
std::pair<Eigen::Vector3d, Eigen::Vector3d> Perpendiculars(const Eigen::Vector3d& d) {
  const Eigen::Vector3d u1 = d.unitOrthogonal();
  return {u1, d.cross(u1).normalized()};
}

// The parameters of every explanation; an explanation frees the blocks it uses.
struct DriftParameters {
  std::array<double, 4> q{};  // rig_from_part0 rotation, Eigen's order (x, y, z, w)
  std::array<double, 3> t{};
  std::array<double, 2> tilt{};          // axis direction + tilt[0] u1 + tilt[1] u2, normalised
  std::array<double, 2> shift{};         // axis point + shift[0] u1 + shift[1] u2
  std::array<double, 1> scale{};         // the table turns (1 + scale) x the stated angle
  std::array<double, 4> dq{0, 0, 0, 1};  // the slip, in the rig frame at commanded angle 0
  std::array<double, 3> dt{};

  Rigid3d Placement() const {
    return Rigid3d(Eigen::Quaterniond(q[3], q[0], q[1], q[2]), Eigen::Vector3d(t[0], t[1], t[2]));
  }
  Rigid3d Slip() const {
    return Rigid3d(Eigen::Quaterniond(dq[3], dq[0], dq[1], dq[2]),
                   Eigen::Vector3d(dt[0], dt[1], dt[2]));
  }
};

// One view: the model's pose of the part against the measured one, as six numbers in units of
// the view's sigma: the rotation between them (radians) times the probe points' RMS radius, and
// the displacement of the probe points' centre (mm). Six numbers for the six degrees of freedom a
// pose has, so a view weighs what it measures.
struct PoseResidual {
  PoseResidual(const TurntableAxis& axis, double table_deg, const Eigen::Vector3d& centre_in_part,
               double radius_mm, const Rigid3d& measured, double sigma_mm, bool after_slip)
      : axis(axis),
        table_deg(table_deg),
        centre(centre_in_part),
        radius(radius_mm),
        measured_centre(measured * centre_in_part),
        measured_rotation_inverse(measured.rotation.conjugate().normalized()),
        inv_sigma(1.0 / sigma_mm),
        after_slip(after_slip) {
    const auto [a, b] = Perpendiculars(axis.direction_in_rig.normalized());
    u1 = a;
    u2 = b;
  }

  template <typename T>
  bool operator()(const T* q, const T* t, const T* tilt, const T* shift, const T* scale,
                  const T* dq, const T* dt, T* residuals) const {
    using Vec = Eigen::Matrix<T, 3, 1>;
    using Quat = Eigen::Quaternion<T>;
    const Eigen::Map<const Quat> rot(q);
    const Eigen::Map<const Vec> trans(t);
    Vec x = rot * centre.cast<T>() + trans;
    Quat r = rot;
    if (after_slip) {
      const Eigen::Map<const Quat> slip_rot(dq);
      const Eigen::Map<const Vec> slip_trans(dt);
      x = slip_rot * x + slip_trans;
      r = slip_rot * r;
    }
    const Vec d = (axis.direction_in_rig.normalized().cast<T>() + tilt[0] * u1.cast<T>() +
                   tilt[1] * u2.cast<T>())
                      .normalized();
    const Vec c =
        axis.point_in_rig_mm.cast<T>() + shift[0] * u1.cast<T>() + shift[1] * u2.cast<T>();
    const T angle_rad =
        (T(axis.angle_scale) * (T(1.0) + scale[0]) * T(table_deg) + T(axis.angle_offset_deg)) /
        T(kDegPerRad);
    const Vec rotation_vector = d * angle_rad;
    T turn_wxyz[4];
    ceres::AngleAxisToQuaternion(rotation_vector.data(), turn_wxyz);
    const Quat turn(turn_wxyz[0], turn_wxyz[1], turn_wxyz[2], turn_wxyz[3]);
    const Vec model_centre = turn * (x - c) + c;
    const Quat off = turn * r * measured_rotation_inverse.cast<T>();
    const T off_wxyz[4] = {off.w(), off.x(), off.y(), off.z()};
    T w[3];
    ceres::QuaternionToAngleAxis(off_wxyz, w);
    for (int i = 0; i < 3; ++i) {
      residuals[i] = w[i] * T(radius * inv_sigma);
      residuals[3 + i] = (model_centre[i] - T(measured_centre[i])) * T(inv_sigma);
    }
    return true;
  }

  const TurntableAxis& axis;
  double table_deg;
  Eigen::Vector3d centre;
  double radius;
  Eigen::Vector3d measured_centre;
  Eigen::Quaterniond measured_rotation_inverse;
  Eigen::Vector3d u1, u2;
  double inv_sigma;
  bool after_slip;
};

// The probe points' centre and RMS distance from it (at least 1 mm).
std::pair<Eigen::Vector3d, double> ProbeCentre(const ViewDriftOptions& options) {
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& p : options.probe_points_in_part) centre += p;
  centre /= static_cast<double>(options.probe_points_in_part.size());
  double ss = 0;
  for (const Eigen::Vector3d& p : options.probe_points_in_part) ss += (p - centre).squaredNorm();
  return {centre, std::max(1.0, std::sqrt(ss / options.probe_points_in_part.size()))};
}

double ViewSigma(const ViewPose& view, const ViewDriftOptions& options) {
  return std::max(view.sigma_mm, options.sigma_floor_mm);
}

// Fits one explanation; `slip_view` >= 0 only for kPartSlipped.
DriftFit Fit(const TurntableAxis& axis, const std::vector<ViewPose>& views,
             const ViewDriftOptions& options, DriftCause cause, int slip_view,
             const Rigid3d& start) {
  DriftParameters par;
  const Eigen::Quaterniond q0 = start.rotation.normalized();
  par.q = {q0.x(), q0.y(), q0.z(), q0.w()};
  par.t = {start.translation.x(), start.translation.y(), start.translation.z()};

  ceres::Problem problem;
  const auto [centre, radius] = ProbeCentre(options);
  size_t residual_count = 0;
  for (size_t v = 0; v < views.size(); ++v) {
    const bool after = cause == DriftCause::kPartSlipped && static_cast<int>(v) >= slip_view;
    auto* cost = new ceres::AutoDiffCostFunction<PoseResidual, 6, 4, 3, 2, 2, 1, 4, 3>(
        new PoseResidual(axis, views[v].table_deg, centre, radius, views[v].rig_from_part,
                         ViewSigma(views[v], options), after));
    problem.AddResidualBlock(cost, nullptr, par.q.data(), par.t.data(), par.tilt.data(),
                             par.shift.data(), par.scale.data(), par.dq.data(), par.dt.data());
    residual_count += 6;
  }
  problem.SetManifold(par.q.data(), new ceres::EigenQuaternionManifold);
  problem.SetManifold(par.dq.data(), new ceres::EigenQuaternionManifold);
  int parameters = 6;
  if (cause != DriftCause::kAxisOff) {
    problem.SetParameterBlockConstant(par.tilt.data());
    problem.SetParameterBlockConstant(par.shift.data());
  } else {
    parameters += 4;
  }
  if (cause != DriftCause::kAngleScale) {
    problem.SetParameterBlockConstant(par.scale.data());
  } else {
    parameters += 1;
  }
  if (cause != DriftCause::kPartSlipped) {
    problem.SetParameterBlockConstant(par.dq.data());
    problem.SetParameterBlockConstant(par.dt.data());
  } else {
    parameters += 6;
  }

  ceres::Solver::Options solver;
  solver.linear_solver_type = ceres::DENSE_QR;
  solver.max_num_iterations = 200;
  solver.function_tolerance = 1e-14;
  solver.parameter_tolerance = 1e-14;
  solver.gradient_tolerance = 1e-20;
  solver.num_threads = 1;
  solver.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver, &problem, &summary);

  DriftFit fit;
  fit.cause = cause;
  fit.parameters = parameters;
  fit.chi2 = 2.0 * summary.final_cost;
  const double n = static_cast<double>(residual_count);
  fit.bic = fit.chi2 + parameters * std::log(n);
  if (cause == DriftCause::kPartSlipped) fit.bic += std::log(static_cast<double>(views.size() - 1));
  fit.rig_from_part0 = par.Placement();

  // The RMS of the residuals in mm (unscaled: rotation at the probe radius, centre displacement).
  double ss = 0;
  for (size_t v = 0; v < views.size(); ++v) {
    const bool after = cause == DriftCause::kPartSlipped && static_cast<int>(v) >= slip_view;
    const PoseResidual r(axis, views[v].table_deg, centre, radius, views[v].rig_from_part, 1.0,
                         after);
    std::array<double, 6> e{};
    r(par.q.data(), par.t.data(), par.tilt.data(), par.shift.data(), par.scale.data(),
      par.dq.data(), par.dt.data(), e.data());
    for (double x : e) ss += x * x;
  }
  fit.rms_mm = std::sqrt(ss / std::max(1.0, n));

  if (cause == DriftCause::kAxisOff) {
    fit.axis_tilt_deg = std::atan(std::hypot(par.tilt[0], par.tilt[1])) * kDegPerRad;
    fit.axis_shift_mm = std::hypot(par.shift[0], par.shift[1]);
  } else if (cause == DriftCause::kAngleScale) {
    fit.angle_scale_error = par.scale[0];
  } else if (cause == DriftCause::kPartSlipped) {
    fit.slip_view = slip_view;
    const Eigen::Vector3d c0 = fit.rig_from_part0 * centre;
    const Rigid3d slip = par.Slip();
    fit.slip_mm = (slip * c0 - c0).norm();
    fit.slip_deg = Eigen::AngleAxisd(slip.rotation.normalized()).angle() * kDegPerRad;
  }
  return fit;
}

}  // namespace

void ViewDriftOptions::Check() const {
  SLSHADOW_THROW_IF(probe_points_in_part.empty(),
                    "view drift: probe_points_in_part is empty; expected at least one point");
  for (const Eigen::Vector3d& p : probe_points_in_part) {
    SLSHADOW_THROW_IF(!p.allFinite(), "view drift: probe_points_in_part holds a non-finite point");
  }
  SLSHADOW_THROW_IF(!(sigma_floor_mm > 0) || !std::isfinite(sigma_floor_mm),
                    "view drift: sigma_floor_mm is ", sigma_floor_mm, "; expected > 0");
  SLSHADOW_THROW_IF(!(min_evidence >= 0) || !std::isfinite(min_evidence),
                    "view drift: min_evidence is ", min_evidence, "; expected >= 0");
}

std::string ToString(DriftCause cause) {
  switch (cause) {
    case DriftCause::kNone:
      return "none";
    case DriftCause::kAxisOff:
      return "axis_off";
    case DriftCause::kAngleScale:
      return "angle_scale";
    case DriftCause::kPartSlipped:
      return "part_slipped";
  }
  return "none";
}

const DriftFit& ViewDriftDiagnosis::Best() const {
  for (const DriftFit& f : fits) {
    if (f.cause == cause) return f;
  }
  SLSHADOW_THROW("view drift: no fit for the cause '", ToString(cause), "'");
}

nlohmann::json ViewDriftDiagnosis::ToJson(const std::vector<ViewPose>& views) const {
  nlohmann::json j;
  j["cause"] = ToString(cause);
  j["finding"] = finding;
  nlohmann::json fits_json = nlohmann::json::array();
  for (const DriftFit& f : fits) {
    nlohmann::json fj = {{"cause", ToString(f.cause)},
                         {"parameters", f.parameters},
                         {"chi2", f.chi2},
                         {"bic", f.bic},
                         {"rms_mm", f.rms_mm}};
    if (f.cause == DriftCause::kAxisOff) {
      fj["axis_tilt_deg"] = f.axis_tilt_deg;
      fj["axis_shift_mm"] = f.axis_shift_mm;
    } else if (f.cause == DriftCause::kAngleScale) {
      fj["angle_scale_error"] = f.angle_scale_error;
    } else if (f.cause == DriftCause::kPartSlipped) {
      fj["slip_after_view"] = views.at(static_cast<size_t>(f.slip_view) - 1).name;
      fj["slip_before_view"] = views.at(static_cast<size_t>(f.slip_view)).name;
      fj["slip_mm"] = f.slip_mm;
      fj["slip_deg"] = f.slip_deg;
    }
    fits_json.push_back(fj);
  }
  j["fits"] = fits_json;
  nlohmann::json per_view = nlohmann::json::array();
  for (size_t v = 0; v < views.size(); ++v) {
    per_view.push_back({{"view", views[v].name},
                        {"table_deg", views[v].table_deg},
                        {"residual_mm", view_residual_mm.at(v)},
                        {"rotation_deg", view_rotation_deg.at(v)}});
  }
  j["views"] = per_view;
  return j;
}

ViewDriftDiagnosis DiagnoseViewDrift(const TurntableAxis& axis, const std::vector<ViewPose>& views,
                                     const ViewDriftOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(views.size() < 3, "view drift: ", views.size(),
                    " views with a pose; expected at least 3 to tell a drift from a placement");
  for (const ViewPose& v : views) {
    SLSHADOW_THROW_IF(!std::isfinite(v.table_deg) || !v.rig_from_part.translation.allFinite() ||
                          !v.rig_from_part.rotation.coeffs().allFinite() ||
                          !std::isfinite(v.sigma_mm),
                      "view drift: view '", v.name, "' has a non-finite angle, pose or sigma");
  }
  // The placement at angle 0 from the first view, where every explanation starts.
  const Rigid3d start =
      axis.RigFromTableTurn(views.front().table_deg).Inverse() * views.front().rig_from_part;

  ViewDriftDiagnosis d;
  d.fits.push_back(Fit(axis, views, options, DriftCause::kNone, -1, start));
  d.fits.push_back(Fit(axis, views, options, DriftCause::kAxisOff, -1, d.fits[0].rig_from_part0));
  d.fits.push_back(
      Fit(axis, views, options, DriftCause::kAngleScale, -1, d.fits[0].rig_from_part0));
  DriftFit best_slip;
  best_slip.bic = std::numeric_limits<double>::infinity();
  for (int k = 1; k < static_cast<int>(views.size()); ++k) {
    DriftFit f = Fit(axis, views, options, DriftCause::kPartSlipped, k, d.fits[0].rig_from_part0);
    if (f.bic < best_slip.bic) best_slip = f;
  }
  d.fits.push_back(best_slip);

  const DriftFit& none = d.fits[0];
  const DriftFit* best = &none;
  for (const DriftFit& f : d.fits) {
    if (f.bic < best->bic) best = &f;
  }
  d.cause = (best != &none && none.bic - best->bic >= options.min_evidence) ? best->cause
                                                                            : DriftCause::kNone;

  // Per-view residuals under the stated model anchored at the first view (so a drift shows as it
  // grows from there).
  for (const ViewPose& v : views) {
    const Rigid3d model = axis.RigFromTableTurn(v.table_deg) * start;
    double worst = 0;
    for (const Eigen::Vector3d& p : options.probe_points_in_part) {
      worst = std::max(worst, (model * p - v.rig_from_part * p).norm());
    }
    d.view_residual_mm.push_back(worst);
    const Eigen::Quaterniond off = (v.rig_from_part.rotation * model.rotation.conjugate());
    d.view_rotation_deg.push_back(Eigen::AngleAxisd(off.normalized()).angle() * kDegPerRad);
  }
  const double worst_mm = *std::max_element(d.view_residual_mm.begin(), d.view_residual_mm.end());

  const DriftFit& b = d.Best();
  switch (d.cause) {
    case DriftCause::kNone:
      d.finding = StringPrintf(
          "the views keep to the turntable model: the largest view is %.4f mm off it from the "
          "first view (RMS %.4f mm over all views)",
          worst_mm, none.rms_mm);
      break;
    case DriftCause::kAxisOff:
      d.finding = StringPrintf(
          "the turntable axis is off: %.4f deg tilted and %.4f mm shifted from the rig's; the "
          "views drift from the model with the angle turned (up to %.4f mm); recalibrate the "
          "axis (slshadow calibrate turntable)",
          b.axis_tilt_deg, b.axis_shift_mm, worst_mm);
      break;
    case DriftCause::kAngleScale:
      d.finding = StringPrintf(
          "the table's angle scale is off by %+.4f %%: the views turn about the axis in "
          "proportion to the angle commanded (up to %.4f mm); recalibrate the axis (slshadow "
          "calibrate turntable)",
          100.0 * b.angle_scale_error, worst_mm);
      break;
    case DriftCause::kPartSlipped:
      d.finding = StringPrintf(
          "the part slipped on the table between views '%s' and '%s': %.4f mm and %.4f deg; the "
          "views from '%s' on share the displacement",
          views[static_cast<size_t>(b.slip_view) - 1].name.c_str(),
          views[static_cast<size_t>(b.slip_view)].name.c_str(), b.slip_mm, b.slip_deg,
          views[static_cast<size_t>(b.slip_view)].name.c_str());
      break;
  }
  return d;
}

}  // namespace slshadow::multiview
