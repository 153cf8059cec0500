#include "calib/refine.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <ceres/sphere_manifold.h>

#include "core/error.h"

namespace slshadow {
namespace {

// Sampson distance of x_p^T [t]x R x_c = 0, scaled by f (projector px).
struct EpipolarFunctor {
  EpipolarFunctor(const Eigen::Vector3d& c, const Eigen::Vector3d& p, double length, double f)
      : xc(c), xp(p), baseline(length), focal(f) {}
  template <typename T>
  bool operator()(const T* rvec, const T* direction, T* residual) const {
    const T c[3] = {T(xc.x()), T(xc.y()), T(xc.z())};
    T rc[3];
    ceres::AngleAxisRotatePoint(rvec, c, rc);
    const T t[3] = {T(baseline) * direction[0], T(baseline) * direction[1], T(baseline) * direction[2]};
    // E x_c = t x (R x_c); E^T x_p = -(R^T (t x x_p))... computed via the rows of E.
    const T ex[3] = {t[1] * rc[2] - t[2] * rc[1], t[2] * rc[0] - t[0] * rc[2], t[0] * rc[1] - t[1] * rc[0]};
    const T e = T(xp.x()) * ex[0] + T(xp.y()) * ex[1] + T(xp.z()) * ex[2];
    // E^T x_p = R^T (x_p x t)  (since x_p . (t x v) = (x_p x t) . v).
    const T p[3] = {T(xp.x()), T(xp.y()), T(xp.z())};
    const T pxt[3] = {p[1] * t[2] - p[2] * t[1], p[2] * t[0] - p[0] * t[2], p[0] * t[1] - p[1] * t[0]};
    const T minus_r[3] = {-rvec[0], -rvec[1], -rvec[2]};
    T etx[3];
    ceres::AngleAxisRotatePoint(minus_r, pxt, etx);
    const T denom = ex[0] * ex[0] + ex[1] * ex[1] + etx[0] * etx[0] + etx[1] * etx[1];
    residual[0] = T(focal) * e / sqrt(denom + T(1e-30));
    return true;
  }
  Eigen::Vector3d xc, xp;
  double baseline, focal;
};

struct Rays {
  std::vector<Eigen::Vector3d> cam, proj;
};

Rays Unproject(const Rig& rig, int camera, const std::vector<Correspondence>& corr) {
  Rays r;
  const auto& cam = rig.cameras[static_cast<size_t>(camera)].model;
  const auto& proj = rig.projector->model;
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
  double sq = 0;
  for (double v : abs_res) sq += v * v;
  s.rms_px = std::sqrt(sq / static_cast<double>(abs_res.size()));
  std::sort(abs_res.begin(), abs_res.end());
  s.median_px = abs_res[abs_res.size() / 2];
  s.p95_px = abs_res[std::min(abs_res.size() - 1, static_cast<size_t>(0.95 * static_cast<double>(abs_res.size())))];
  return s;
}

Rigid3d ProjFromCam(const Rig& rig, int camera) {
  return rig.projector->cam_from_rig * rig.cameras[static_cast<size_t>(camera)].cam_from_rig.Inverse();
}

std::vector<double> Residuals(const Rays& rays, const Rigid3d& proj_from_cam, double focal) {
  const Eigen::AngleAxisd aa(proj_from_cam.rotation);
  const Eigen::Vector3d r = aa.angle() * aa.axis();
  const double length = proj_from_cam.translation.norm();
  const Eigen::Vector3d dir = proj_from_cam.translation / std::max(length, 1e-300);
  std::vector<double> out;
  for (size_t i = 0; i < rays.cam.size(); ++i) {
    double res = 0;
    EpipolarFunctor(rays.cam[i], rays.proj[i], length, focal)(r.data(), dir.data(), &res);
    out.push_back(std::abs(res));
  }
  return out;
}

}  // namespace

std::vector<Correspondence> SampleCorrespondences(const ProjectorMap& map, int max_samples) {
  std::vector<Correspondence> all;
  for (int y = 0; y < map.height(); ++y) {
    const uint8_t* st = map.status.ptr<uint8_t>(y);
    const float* px = map.proj_x.ptr<float>(y);
    const float* py = map.proj_y.ptr<float>(y);
    for (int x = 0; x < map.width(); ++x) {
      if (st[x] == static_cast<uint8_t>(PixelStatus::kValid) && std::isfinite(px[x]) && std::isfinite(py[x])) {
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

EpipolarStats EpipolarResiduals(const Rig& rig, int camera, const std::vector<Correspondence>& correspondences,
                                std::vector<double>* residuals_px) {
  SLSHADOW_THROW_IF(!rig.projector, "calibration check: rig '", rig.name, "' has no projector");
  SLSHADOW_THROW_IF(camera < 0 || camera >= static_cast<int>(rig.cameras.size()), "calibration check: camera index ",
                    camera, " out of range");
  const Rays rays = Unproject(rig, camera, correspondences);
  std::vector<double> res = Residuals(rays, ProjFromCam(rig, camera), rig.projector->model.fx());
  if (residuals_px) *residuals_px = res;
  return Stats(std::move(res));
}

RefineResult RefineProjectorPose(const Rig& rig, int camera, const std::vector<Correspondence>& correspondences,
                                 const RefineOptions& options) {
  SLSHADOW_THROW_IF(!rig.projector, "calibrate refine: rig '", rig.name, "' has no projector");
  SLSHADOW_THROW_IF(camera < 0 || camera >= static_cast<int>(rig.cameras.size()), "calibrate refine: camera index ",
                    camera, " out of range");
  const Rays rays = Unproject(rig, camera, correspondences);
  SLSHADOW_THROW_IF(rays.cam.size() < 20, "calibrate refine: only ", rays.cam.size(),
                    " usable correspondences (need at least 20): is the scan decoded, and the rig the right one?");
  const Rigid3d initial = ProjFromCam(rig, camera);
  const double length = initial.translation.norm();
  SLSHADOW_THROW_IF(!(length > 0), "calibrate refine: camera and projector share a centre (zero baseline)");
  const double focal = rig.projector->model.fx();
  RefineResult out;
  out.before = Stats(Residuals(rays, initial, focal));

  const Eigen::AngleAxisd aa(initial.rotation);
  Eigen::Vector3d rvec = aa.angle() * aa.axis();
  Eigen::Vector3d dir = initial.translation / length;
  ceres::Problem problem;
  for (size_t i = 0; i < rays.cam.size(); ++i) {
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<EpipolarFunctor, 1, 3, 3>(
                                 new EpipolarFunctor(rays.cam[i], rays.proj[i], length, focal)),
                             new ceres::CauchyLoss(options.loss_scale_px), rvec.data(), dir.data());
  }
  problem.SetManifold(dir.data(), new ceres::SphereManifold<3>());
  ceres::Solver::Options so;
  so.max_num_iterations = options.max_iterations;
  so.num_threads = 2;
  so.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(so, &problem, &summary);
  out.converged = summary.termination_type == ceres::CONVERGENCE;

  const double angle = rvec.norm();
  const Eigen::Quaterniond q =
      angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, rvec / angle)) : Eigen::Quaterniond::Identity();
  const Rigid3d refined(q, length * dir.normalized());
  out.after = Stats(Residuals(rays, refined, focal));
  out.rotation_change_rad = refined.rotation.angularDistance(initial.rotation);
  out.direction_change_rad = std::acos(std::clamp(dir.normalized().dot(initial.translation / length), -1.0, 1.0));
  out.rig = rig;
  out.rig.projector->cam_from_rig = refined * rig.cameras[static_cast<size_t>(camera)].cam_from_rig;
  char msg[400];
  std::snprintf(msg, sizeof(msg),
                "epipolar residual median %.3f -> %.3f px, p95 %.3f -> %.3f px (%d correspondences); projector rotated "
                "%.4f deg, baseline direction turned %.4f deg, baseline kept at %.3f mm%s",
                out.before.median_px, out.after.median_px, out.before.p95_px, out.after.p95_px, out.after.count,
                out.rotation_change_rad * 180 / M_PI, out.direction_change_rad * 180 / M_PI, length,
                out.before.median_px > options.warn_median_px
                    ? "; WARNING: before refinement the calibration did not fit this scan (bumped rig, swapped devices or wrong file?)"
                    : "");
  out.message = msg;
  return out;
}

}  // namespace slshadow
