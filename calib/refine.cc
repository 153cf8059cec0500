#include "calib/refine.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>
#include <string>

#include <Eigen/Dense>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <ceres/sphere_manifold.h>

#include "core/statistics.h"

#include "core/error.h"
#include "core/threads.h"

namespace slshadow {
namespace {

// Sampson distance of x_p^T [t]x R x_c = 0, scaled by f (projector px).
struct EpipolarFunctor {
  EpipolarFunctor(const Eigen::Vector3d& c, const Eigen::Vector3d& p, double length, double f)
      : xc(c), xp(p), baseline(length), focal(f) {}
  // `scale`: new / old focal length of the second device; its ray becomes (x/s, y/s, 1).
  template <typename T>
  bool operator()(const T* rvec, const T* direction, const T* scale, T* residual) const {
    const T c[3] = {T(xc.x()), T(xc.y()), T(xc.z())};
    T rc[3];
    ceres::AngleAxisRotatePoint(rvec, c, rc);
    const T t[3] = {T(baseline) * direction[0], T(baseline) * direction[1],
                    T(baseline) * direction[2]};
    // E x_c = t x (R x_c).
    const T ex[3] = {t[1] * rc[2] - t[2] * rc[1], t[2] * rc[0] - t[0] * rc[2],
                     t[0] * rc[1] - t[1] * rc[0]};
    const T p[3] = {T(xp.x()) / scale[0], T(xp.y()) / scale[0], T(xp.z())};
    const T e = p[0] * ex[0] + p[1] * ex[1] + p[2] * ex[2];
    // E^T x_p = R^T (x_p x t)  (since x_p . (t x v) = (x_p x t) . v).
    const T pxt[3] = {p[1] * t[2] - p[2] * t[1], p[2] * t[0] - p[0] * t[2],
                      p[0] * t[1] - p[1] * t[0]};
    const T minus_r[3] = {-rvec[0], -rvec[1], -rvec[2]};
    T etx[3];
    ceres::AngleAxisRotatePoint(minus_r, pxt, etx);
    const T denom = ex[0] * ex[0] + ex[1] * ex[1] + etx[0] * etx[0] + etx[1] * etx[1];
    residual[0] = T(focal) * scale[0] * e / sqrt(denom + T(1e-30));
    return true;
  }
  Eigen::Vector3d xc, xp;
  double baseline, focal;
};

struct Rays {
  std::vector<Eigen::Vector3d> cam, proj;
};

// Rays of both devices; `proj` is the second device of the pair (projector or camera_b).
Rays Unproject(const CameraModel& cam, const CameraModel& proj,
               const std::vector<Correspondence>& corr) {
  Rays r;
  for (const auto& c : corr) {
    const auto a = cam.UndistortToNormalized(c.camera_px);
    const auto b = proj.UndistortToNormalized(c.projector_px);
    if (!a || !b) continue;
    r.cam.emplace_back(a->x(), a->y(), 1.0);
    r.proj.emplace_back(b->x(), b->y(), 1.0);
  }
  return r;
}

EpipolarStats Stats(std::vector<double> abs_res) {
  EpipolarStats s;
  s.count = static_cast<int>(abs_res.size());
  if (abs_res.empty()) return s;
  const Summary summary = Summarize(std::move(abs_res));  // core/statistics.h: nearest rank
  s.rms_px = summary.rms;
  s.median_px = summary.median;
  s.p95_px = summary.p95_abs;  // of magnitudes
  return s;
}

std::vector<double> Residuals(const Rays& rays, const Rigid3d& proj_from_cam, double focal) {
  const Eigen::Vector3d r = RotationVectorFromQuaternion(proj_from_cam.rotation);
  const double length = proj_from_cam.translation.norm();
  const Eigen::Vector3d dir = proj_from_cam.translation / std::max(length, 1e-300);
  const double one = 1.0;
  std::vector<double> out;
  for (size_t i = 0; i < rays.cam.size(); ++i) {
    double res = 0;
    EpipolarFunctor(rays.cam[i], rays.proj[i], length, focal)(r.data(), dir.data(), &one, &res);
    out.push_back(std::abs(res));
  }
  return out;
}

struct PairResult {
  Rigid3d b_from_a;
  CameraModel model_b;
  EpipolarStats before, after;
  double rotation_change_rad = 0, direction_change_rad = 0, focal_scale = 1;
  bool converged = false;
  double front_share = 0, inlier_share = 0;
  bool scale_verified = false;
  std::string scale_note;  // how the scale was set
};

// Depths (along the rays, in ray units) of the midpoint triangulation of rays xa (frame a) and xb
// (frame b); nullopt for parallel rays.
std::optional<Eigen::Vector2d> Depths(const Rigid3d& b_from_a, const Eigen::Vector3d& xa,
                                      const Eigen::Vector3d& xb) {
  const Eigen::Matrix3d rt = b_from_a.rotation.toRotationMatrix().transpose();
  const Eigen::Vector3d cb = -rt * b_from_a.translation, db = rt * xb;
  Eigen::Matrix<double, 3, 2> a;
  a.col(0) = xa;
  a.col(1) = -db;
  const Eigen::Matrix2d n = a.transpose() * a;
  if (std::abs(n.determinant()) < 1e-12 * n.trace() * n.trace()) return std::nullopt;
  return Eigen::Vector2d(n.ldlt().solve(a.transpose() * cb));
}

// The midpoint of a correspondence in frame a (mm at the pose's scale).
std::optional<Eigen::Vector3d> Triangulate(const CameraModel& ma, const CameraModel& mb,
                                           const Rigid3d& b_from_a, const Correspondence& c) {
  const auto a = ma.UndistortToNormalized(c.camera_px);
  const auto b = mb.UndistortToNormalized(c.projector_px);
  if (!a || !b) return std::nullopt;
  const Eigen::Vector3d xa(a->x(), a->y(), 1), xb(b->x(), b->y(), 1);
  const auto d = Depths(b_from_a, xa, xb);
  if (!d) return std::nullopt;
  const Eigen::Matrix3d rt = b_from_a.rotation.toRotationMatrix().transpose();
  const Eigen::Vector3d pa = d->x() * xa, pb = -rt * b_from_a.translation + d->y() * (rt * xb);
  return Eigen::Vector3d(0.5 * (pa + pb));
}

// Refines b_from_a (and optionally model_b's focal length) of the pair.
PairResult RefinePair(const CameraModel& model_a, const CameraModel& model_b_in,
                      const Rigid3d& initial, const std::vector<Correspondence>& correspondences,
                      const RefineOptions& options) {
  const double length = initial.translation.norm();
  SLSHADOW_THROW_IF(!(length > 0),
                    "calibrate refine: the two devices share a centre (zero baseline)");
  PairResult out;
  out.model_b = model_b_in;
  Rays rays = Unproject(model_a, out.model_b, correspondences);
  SLSHADOW_THROW_IF(rays.cam.size() < 20, "calibrate refine: only ", rays.cam.size(),
                    " usable correspondences (need at least 20): is the scan decoded, and the rig "
                    "the right one?");
  out.before = Stats(Residuals(rays, initial, out.model_b.fx()));

  Eigen::Vector3d rvec = RotationVectorFromQuaternion(initial.rotation);
  Eigen::Vector3d dir = initial.translation / length;
  // With focal refinement, the rays of b depend on its focal length through the distortion too:
  // solve with the first-order ray scaling, update the model, re-undistort, solve again.
  const int outer = options.refine_focal ? 4 : 1;
  for (int it = 0; it < outer; ++it) {
    double scale = 1.0;
    ceres::Problem problem;
    for (size_t i = 0; i < rays.cam.size(); ++i) {
      problem.AddResidualBlock(
          new ceres::AutoDiffCostFunction<EpipolarFunctor, 1, 3, 3, 1>(
              new EpipolarFunctor(rays.cam[i], rays.proj[i], length, out.model_b.fx())),
          new ceres::CauchyLoss(options.loss_scale_px), rvec.data(), dir.data(), &scale);
    }
    problem.SetManifold(dir.data(), new ceres::SphereManifold<3>());
    if (!options.refine_focal) problem.SetParameterBlockConstant(&scale);
    ceres::Solver::Options so;
    so.max_num_iterations = options.max_iterations;
    so.num_threads = ThreadBudget();
    so.logging_type = ceres::SILENT;
    ceres::Solver::Summary summary;
    ceres::Solve(so, &problem, &summary);
    out.converged = summary.termination_type == ceres::CONVERGENCE;
    if (options.refine_focal) {
      out.model_b.params[CameraModel::kFx] *= scale;
      out.model_b.params[CameraModel::kFy] *= scale;
      out.focal_scale *= scale;
      rays = Unproject(model_a, out.model_b, correspondences);
    }
  }
  out.b_from_a = Rigid3d::FromRotationVector(rvec, length * dir.normalized());
  const std::vector<double> after = Residuals(rays, out.b_from_a, out.model_b.fx());
  out.after = Stats(after);
  // Inliers, and cheirality over the inliers (an outlier's depth means nothing).
  int front = 0, inliers = 0;
  for (size_t i = 0; i < rays.cam.size(); ++i) {
    if (!(after[i] <= options.inlier_px)) continue;
    ++inliers;
    const auto d = Depths(out.b_from_a, rays.cam[i], rays.proj[i]);
    front += d && d->x() > 0 && d->y() > 0;
  }
  const double n = static_cast<double>(std::max<size_t>(correspondences.size(), 1));
  out.front_share = inliers > 0 ? front / static_cast<double>(inliers) : 0.0;
  out.inlier_share = inliers / n;  // correspondences that did not unproject count as lost
  // Scale: a known length, else the rig file's baseline.
  char note[300];
  if (options.known_baseline_mm > 0) {
    out.b_from_a.translation = options.known_baseline_mm * dir.normalized();
    out.scale_verified = true;
    std::snprintf(note, sizeof(note),
                  "scale set by the known baseline: %.3f mm (rig file: %.3f mm)",
                  options.known_baseline_mm, length);
    out.scale_note = note;
  } else if (!options.known_distances.empty()) {
    const KnownDistance& k = options.known_distances[0];
    const auto p1 = Triangulate(model_a, out.model_b, out.b_from_a, k.first);
    const auto p2 = Triangulate(model_a, out.model_b, out.b_from_a, k.second);
    SLSHADOW_THROW_IF(!p1 || !p2,
                      "calibrate refine: a point of the known distance does not triangulate");
    const double measured = (*p1 - *p2).norm();
    SLSHADOW_THROW_IF(!(measured > 0),
                      "calibrate refine: the two points of the known distance coincide");
    out.b_from_a.translation *= k.distance_mm / measured;
    out.scale_verified = true;
    std::snprintf(note, sizeof(note),
                  "scale set by the known distance %.3f mm (%.3f mm with the rig file's baseline): "
                  "baseline %.3f -> %.3f mm",
                  k.distance_mm, measured, length, out.b_from_a.translation.norm());
    out.scale_note = note;
  } else {
    std::snprintf(note, sizeof(note),
                  "scale not verified: the baseline is the rig file's %.3f mm (self-calibration "
                  "cannot measure scale; "
                  "give a known baseline or a measured distance between two scene points)",
                  length);
    out.scale_note = note;
  }
  out.rotation_change_rad = out.b_from_a.rotation.angularDistance(initial.rotation);
  out.direction_change_rad =
      std::acos(std::clamp(dir.normalized().dot(initial.translation / length), -1.0, 1.0));
  return out;
}

// The report of a refinement, part by part (the figures first, then the warnings and notes).
std::vector<std::string> MessageParts(const PairResult& r, const std::string& second,
                                      const RefineOptions& options) {
  char msg[600];
  std::snprintf(
      msg, sizeof(msg),
      "epipolar residual median %.3f -> %.3f px, p95 %.3f -> %.3f px (%d correspondences); %s "
      "rotated "
      "%.4f deg, baseline direction turned %.4f deg, baseline %.3f mm%s",
      r.before.median_px, r.after.median_px, r.before.p95_px, r.after.p95_px, r.after.count,
      second.c_str(), r.rotation_change_rad * 180 / M_PI, r.direction_change_rad * 180 / M_PI,
      r.b_from_a.translation.norm(),
      options.refine_focal ? (", focal length x" + std::to_string(r.focal_scale)).c_str() : "");
  std::vector<std::string> parts = {msg};
  if (r.before.median_px > options.warn_median_px) {
    parts.push_back(
        "WARNING: before refinement the calibration did not fit this scan (bumped rig, swapped "
        "devices or wrong file?)");
  }
  if (r.after.median_px > options.warn_median_px) {
    // What the refined parameters cannot absorb stays: a pose cannot stand in for a focal length.
    std::snprintf(msg, sizeof(msg), "%.3f px (above %.3g px)", r.after.median_px,
                  options.warn_median_px);
    parts.push_back(
        options.refine_focal
            ? std::string("WARNING: after refinement of the pose and the focal length the median "
                          "residual is still ") +
                  msg + ": another intrinsic (principal point, distortion) is off; recalibrate " +
                  second
            : std::string("WARNING: after refinement of the pose the median residual is still ") +
                  msg + ": the likely cause is the focal length of " + second +
                  ", which a pose cannot absorb; run again with --refine-focal");
  }
  if (r.rotation_change_rad > 1.0 * M_PI / 180 || r.direction_change_rad > 5.0 * M_PI / 180) {
    parts.push_back(
        "WARNING: the correction is far larger than a bump (swapped camera names or a rig file "
        "of another rig?): check before trusting the refined rig");
  }
  parts.push_back(r.scale_note);
  // Not the figure `slshadow reconstruct` quotes: its calibration check fits a smooth field to the
  // dense epipolar error and judges it against the capture's decode noise (issue 14: say so).
  parts.push_back(
      "(this is the Sampson residual of the sparse correspondences refine fits, px of " + second +
      "; `slshadow reconstruct` quotes another figure: the systematic part of the "
      "dense epipolar error against the capture's decode noise)");
  return parts;
}

// Accepted: the parts in one paragraph. Rejected: "rejected: why" first, then the figures of the
// refused solution, one part a line.
std::string Message(const PairResult& r, const std::string& second, const RefineOptions& options,
                    const std::string& rejection) {
  const std::vector<std::string> parts = MessageParts(r, second, options);
  std::string out =
      rejection.empty() ? "" : rejection + "\nthe refused solution (nothing written):";
  for (size_t i = 0; i < parts.size(); ++i) {
    out += rejection.empty() ? (i ? "; " : "") + parts[i] : "\n  " + parts[i];
  }
  return out;
}

// Why a refined pair is refused, or empty.
std::string Rejection(const PairResult& r, const RefineOptions& options) {
  char msg[400];
  if (r.inlier_share < options.min_inlier_share) {
    std::snprintf(msg, sizeof(msg),
                  "rejected: the refined pose fits only %.0f %% of the correspondences within %.1f "
                  "px (need %.0f %%): "
                  "most correspondences are lost (wrong scan or rig file, or a decoding failure?)",
                  100 * r.inlier_share, options.inlier_px, 100 * options.min_inlier_share);
    return msg;
  }
  if (r.front_share < options.min_front_share) {
    std::snprintf(msg, sizeof(msg),
                  "rejected: only %.0f %% of the fitting correspondences triangulate in front of "
                  "both devices (cheirality; "
                  "need %.0f %%): the solution is the twisted pair or the reversed baseline of the "
                  "true pose, a "
                  "mirror image that fits the epipolar geometry equally well; the rig file is too "
                  "far off (wrong "
                  "file or swapped devices?)",
                  100 * r.front_share, 100 * options.min_front_share);
    return msg;
  }
  return "";
}

void CheckCamera(const Rig& rig, int camera, const char* what) {
  SLSHADOW_THROW_IF(camera < 0 || camera >= static_cast<int>(rig.cameras.size()), what,
                    ": camera index ", camera, " out of range (rig '", rig.name, "' has ",
                    rig.cameras.size(), " cameras)");
}

Rigid3d BFromA(const Rig& rig, int a, int b) {
  return rig.cameras[static_cast<size_t>(b)].cam_from_rig *
         rig.cameras[static_cast<size_t>(a)].cam_from_rig.Inverse();
}

// Sub-pixel position in `b` of projector coordinate (u, v), from b's pixels around `seed`.
std::optional<Eigen::Vector2d> MatchIn(const ProjectorMap& b, int sx, int sy, double u, double v) {
  Eigen::Matrix<double, 25, 3> A;
  Eigen::Matrix<double, 25, 2> B;
  int n = 0;
  for (int y = sy - 2; y <= sy + 2; ++y) {
    if (y < 0 || y >= b.height()) continue;
    for (int x = sx - 2; x <= sx + 2; ++x) {
      if (x < 0 || x >= b.width()) continue;
      if (b.status.at<uint8_t>(y, x) != static_cast<uint8_t>(PixelStatus::kValid)) continue;
      const double pu = b.proj_x.at<float>(y, x), pv = b.proj_y.at<float>(y, x);
      if (!std::isfinite(pu) || !std::isfinite(pv)) continue;
      A.row(n) << pu - u, pv - v, 1.0;
      B.row(n) << x - sx, y - sy;
      ++n;
    }
  }
  if (n < 12) return std::nullopt;
  const Eigen::MatrixXd An = A.topRows(n), Bn = B.topRows(n);
  const Eigen::Matrix<double, 3, 2> M = An.colPivHouseholderQr().solve(Bn);
  const double fit_rms = std::sqrt((An * M - Bn).squaredNorm() / n);
  if (!(fit_rms < 0.5)) return std::nullopt;  // not locally affine: an edge or a depth jump
  const Eigen::Vector2d d = M.row(2).transpose();
  if (d.norm() > 1.5) return std::nullopt;
  return Eigen::Vector2d(sx + d.x(), sy + d.y());
}

}  // namespace

std::vector<Correspondence> SampleCorrespondences(const ProjectorMap& map, int max_samples) {
  std::vector<Correspondence> all;
  for (int y = 0; y < map.height(); ++y) {
    const uint8_t* st = map.status.ptr<uint8_t>(y);
    const float* px = map.proj_x.ptr<float>(y);
    const float* py = map.proj_y.ptr<float>(y);
    for (int x = 0; x < map.width(); ++x) {
      if (st[x] == static_cast<uint8_t>(PixelStatus::kValid) && std::isfinite(px[x]) &&
          std::isfinite(py[x])) {
        all.push_back({Eigen::Vector2d(x, y), Eigen::Vector2d(px[x], py[x])});
      }
    }
  }
  if (static_cast<int>(all.size()) <= max_samples) return all;
  std::vector<Correspondence> out;
  const double step = static_cast<double>(all.size()) / max_samples;
  for (int i = 0; i < max_samples; ++i) out.push_back(all[static_cast<size_t>(i * step)]);
  return out;
}

EpipolarStats EpipolarResiduals(const Rig& rig, int camera,
                                const std::vector<Correspondence>& correspondences,
                                std::vector<double>* residuals_px) {
  SLSHADOW_THROW_IF(!rig.projector, "calibration check: rig '", rig.name, "' has no projector");
  CheckCamera(rig, camera, "calibration check");
  const Rays rays = Unproject(rig.cameras[static_cast<size_t>(camera)].model, rig.projector->model,
                              correspondences);
  const Rigid3d proj_from_cam =
      rig.projector->cam_from_rig * rig.cameras[static_cast<size_t>(camera)].cam_from_rig.Inverse();
  std::vector<double> res = Residuals(rays, proj_from_cam, rig.projector->model.fx());
  if (residuals_px) *residuals_px = res;
  return Stats(std::move(res));
}

// The refined rig (device b moved to b_from_a * a_from_rig, with its refined model) and the
// figures of one pair refinement.
template <typename DeviceB>
RefineResult PairToResult(const PairResult& p, const Rig& rig, DeviceB device_b,
                          const Rigid3d& a_from_rig, const std::string& b_label,
                          const Rigid3d& initial, const RefineOptions& options) {
  RefineResult out;
  out.before = p.before;
  out.after = p.after;
  out.rotation_change_rad = p.rotation_change_rad;
  out.direction_change_rad = p.direction_change_rad;
  out.focal_scale = p.focal_scale;
  out.converged = p.converged;
  out.rig = rig;
  RigDevice& nb = device_b(out.rig);
  nb.cam_from_rig = p.b_from_a * a_from_rig;
  nb.model = p.model_b;
  out.front_share = p.front_share;
  out.inlier_share = p.inlier_share;
  out.baseline_mm = p.b_from_a.translation.norm();
  out.scale_verified = p.scale_verified;
  out.rejection = Rejection(p, options);
  out.rejected = !out.rejection.empty();
  out.message = Message(p, b_label, options, out.rejection);
  (void)initial;
  return out;
}

void RefineOptions::Check() const {
  const char* p = "refine options: ";
  SLSHADOW_THROW_IF(!(loss_scale_px > 0), p, "loss_scale_px: must be > 0 (got ", loss_scale_px,
                    ")");
  SLSHADOW_THROW_IF(max_iterations < 1, p, "max_iterations: must be >= 1 (got ", max_iterations,
                    ")");
  SLSHADOW_THROW_IF(!(known_baseline_mm >= 0) || !std::isfinite(known_baseline_mm), p,
                    "known_baseline_mm: must be >= 0 (got ", known_baseline_mm, ")");
  SLSHADOW_THROW_IF(known_distances.size() > 1, p, "known_distances: at most one (got ",
                    known_distances.size(), ")");
  SLSHADOW_THROW_IF(known_baseline_mm > 0 && !known_distances.empty(), p,
                    "known_baseline_mm, known_distances: give one known length, not both");
  for (const auto& k : known_distances) {
    SLSHADOW_THROW_IF(!(k.distance_mm > 0) || !std::isfinite(k.distance_mm), p,
                      "known_distances: distance_mm must be > 0 (got ", k.distance_mm, ")");
  }
  SLSHADOW_THROW_IF(!(min_front_share >= 0 && min_front_share <= 1), p,
                    "min_front_share: must be in [0, 1] (got ", min_front_share, ")");
  SLSHADOW_THROW_IF(!(min_inlier_share >= 0 && min_inlier_share <= 1), p,
                    "min_inlier_share: must be in [0, 1] (got ", min_inlier_share, ")");
  SLSHADOW_THROW_IF(!(inlier_px > 0), p, "inlier_px: must be > 0 (got ", inlier_px, ")");
}

RefineResult RefineProjectorPose(const Rig& rig, int camera,
                                 const std::vector<Correspondence>& correspondences,
                                 const RefineOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(
      !rig.projector, "calibrate refine: rig '", rig.name,
      "' has no projector: refine a camera pair instead (--stereo CAMERA, cameras: ",
      [&] {
        std::string names;
        for (const auto& c : rig.cameras) names += (names.empty() ? "" : ", ") + c.name;
        return names;
      }(),
      ")");
  CheckCamera(rig, camera, "calibrate refine");
  const auto& cam = rig.cameras[static_cast<size_t>(camera)];
  const Rigid3d initial = rig.projector->cam_from_rig * cam.cam_from_rig.Inverse();
  const PairResult p =
      RefinePair(cam.model, rig.projector->model, initial, correspondences, options);
  return PairToResult(
      p, rig, [](Rig& r) -> RigDevice& { return *r.projector; }, cam.cam_from_rig, "projector",
      initial, options);
}

namespace {
// Stereo matches of `a`'s samples in `b`, or of the one correspondence `only` (a pixel of a with
// its projector coordinate).
std::vector<Correspondence> StereoMatches(const ProjectorMap& a, const ProjectorMap& b,
                                          int max_samples,
                                          const std::optional<Correspondence>& only) {
  SLSHADOW_THROW_IF(a.proj_x.empty() || a.proj_y.empty() || b.proj_x.empty() || b.proj_y.empty(),
                    "stereo correspondences: both projector maps must decode both projector axes");
  // Index b by projector coordinate: a grid of 1 projector px cells, each holding one b pixel.
  double max_u = 0, max_v = 0;
  for (int y = 0; y < b.height(); ++y) {
    for (int x = 0; x < b.width(); ++x) {
      if (b.status.at<uint8_t>(y, x) != static_cast<uint8_t>(PixelStatus::kValid)) continue;
      const float u = b.proj_x.at<float>(y, x), v = b.proj_y.at<float>(y, x);
      if (std::isfinite(u) && std::isfinite(v))
        max_u = std::max<double>(max_u, u), max_v = std::max<double>(max_v, v);
    }
  }
  const int gw = static_cast<int>(max_u) + 2, gh = static_cast<int>(max_v) + 2;
  cv::Mat grid(gh, gw, CV_32SC1, cv::Scalar(-1));
  for (int y = 0; y < b.height(); ++y) {
    for (int x = 0; x < b.width(); ++x) {
      if (b.status.at<uint8_t>(y, x) != static_cast<uint8_t>(PixelStatus::kValid)) continue;
      const float u = b.proj_x.at<float>(y, x), v = b.proj_y.at<float>(y, x);
      if (!std::isfinite(u) || !std::isfinite(v) || u < 0 || v < 0) continue;
      grid.at<int32_t>(static_cast<int>(std::lround(v)), static_cast<int>(std::lround(u))) =
          y * b.width() + x;
    }
  }
  const std::vector<Correspondence> samples =
      only ? std::vector<Correspondence>{*only} : SampleCorrespondences(a, max_samples);
  std::vector<Correspondence> out;
  for (const auto& s : samples) {
    const int gu = static_cast<int>(std::lround(s.projector_px.x())),
              gv = static_cast<int>(std::lround(s.projector_px.y()));
    if (gu < 0 || gv < 0 || gu >= gw || gv >= gh) continue;
    const int idx = grid.at<int32_t>(gv, gu);
    if (idx < 0) continue;
    const auto m =
        MatchIn(b, idx % b.width(), idx / b.width(), s.projector_px.x(), s.projector_px.y());
    if (m) out.push_back({s.camera_px, *m});
  }
  return out;
}
}  // namespace

std::vector<Correspondence> StereoCorrespondences(const ProjectorMap& a, const ProjectorMap& b,
                                                  int max_samples) {
  return StereoMatches(a, b, max_samples, std::nullopt);
}

std::optional<Correspondence> CorrespondenceAt(const ProjectorMap& a, const ProjectorMap* b,
                                               const Eigen::Vector2d& pixel) {
  const int x = static_cast<int>(std::lround(pixel.x())),
            y = static_cast<int>(std::lround(pixel.y()));
  if (x < 0 || y < 0 || x >= a.width() || y >= a.height()) return std::nullopt;
  if (a.status.at<uint8_t>(y, x) != static_cast<uint8_t>(PixelStatus::kValid)) return std::nullopt;
  const float u = a.proj_x.at<float>(y, x), v = a.proj_y.at<float>(y, x);
  if (!std::isfinite(u) || !std::isfinite(v)) return std::nullopt;
  const Correspondence c{Eigen::Vector2d(x, y), Eigen::Vector2d(u, v)};
  if (!b) return c;
  const auto m = StereoMatches(a, *b, 1, c);
  if (m.empty()) return std::nullopt;
  return m[0];
}

EpipolarStats StereoEpipolarResiduals(const Rig& rig, int camera_a, int camera_b,
                                      const std::vector<Correspondence>& correspondences,
                                      std::vector<double>* residuals_px) {
  CheckCamera(rig, camera_a, "calibration check");
  CheckCamera(rig, camera_b, "calibration check");
  const auto& mb = rig.cameras[static_cast<size_t>(camera_b)].model;
  const Rays rays =
      Unproject(rig.cameras[static_cast<size_t>(camera_a)].model, mb, correspondences);
  std::vector<double> res = Residuals(rays, BFromA(rig, camera_a, camera_b), mb.fx());
  if (residuals_px) *residuals_px = res;
  return Stats(std::move(res));
}

RefineResult RefineStereoPose(const Rig& rig, int camera_a, int camera_b,
                              const std::vector<Correspondence>& correspondences,
                              const RefineOptions& options) {
  options.Check();
  CheckCamera(rig, camera_a, "calibrate refine");
  CheckCamera(rig, camera_b, "calibrate refine");
  SLSHADOW_THROW_IF(camera_a == camera_b,
                    "calibrate refine: stereo needs two different cameras (both are ", camera_a,
                    ")");
  const auto& a = rig.cameras[static_cast<size_t>(camera_a)];
  const auto& b = rig.cameras[static_cast<size_t>(camera_b)];
  const Rigid3d initial = BFromA(rig, camera_a, camera_b);
  const PairResult p = RefinePair(a.model, b.model, initial, correspondences, options);
  return PairToResult(
      p, rig, [camera_b](Rig& r) -> RigDevice& { return r.cameras[static_cast<size_t>(camera_b)]; },
      a.cam_from_rig, "camera '" + b.name + "'", initial, options);
}

nlohmann::json RefineRecordToJson(const RefineResult& r, const std::string& imageset,
                                  const std::string& camera, const std::string& stereo) {
  return {{"imageset", imageset},
          {"camera", camera},
          {"stereo", stereo},
          {"focal_scale", r.focal_scale},
          {"before_median_px", r.before.median_px},
          {"before_p95_px", r.before.p95_px},
          {"after_median_px", r.after.median_px},
          {"after_p95_px", r.after.p95_px},
          {"rotation_change_rad", r.rotation_change_rad},
          {"direction_change_rad", r.direction_change_rad},
          {"converged", r.converged},
          {"front_share", r.front_share},
          {"inlier_share", r.inlier_share},
          {"baseline_mm", r.baseline_mm},
          {"scale_verified", r.scale_verified}};
}

}  // namespace slshadow
