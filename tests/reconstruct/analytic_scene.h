// Analytic ground truth for reconstruction tests (no simulator): surfaces that are intersected
// exactly, and the exact ProjectorMap a camera of a rig sees of them (the projector coordinate of
// the surface point on each camera pixel's ray, CV_64F). Shadowing by the surface itself is
// handled by casting the projector ray to the point.
#pragma once

#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <random>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/projector_map.h"
#include "core/rig.h"

namespace slshadow::testing {

// Ray parameter t >= 0 of the first hit of origin + t * dir (dir unit), or nullopt.
using Surface =
    std::function<std::optional<double>(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir)>;

inline std::optional<double> HitPlane(const Eigen::Vector3d& n, double d, const Eigen::Vector3d& o,
                                      const Eigen::Vector3d& dir) {
  const double den = n.dot(dir);
  if (std::abs(den) < 1e-15) return std::nullopt;
  const double t = (d - n.dot(o)) / den;
  if (!(t > 1e-9)) return std::nullopt;
  return t;
}

// Plane n . x = d (rig frame).
inline Surface Plane(const Eigen::Vector3d& normal, double d) {
  const Eigen::Vector3d n = normal.normalized();
  return [n, d](const Eigen::Vector3d& o, const Eigen::Vector3d& dir) {
    return HitPlane(n, d, o, dir);
  };
}

inline Surface Sphere(const Eigen::Vector3d& center, double radius) {
  return [center, radius](const Eigen::Vector3d& o,
                          const Eigen::Vector3d& dir) -> std::optional<double> {
    const Eigen::Vector3d oc = o - center;
    const double b = oc.dot(dir);
    const double c = oc.squaredNorm() - radius * radius;
    const double disc = b * b - c;
    if (disc < 0) return std::nullopt;
    const double s = std::sqrt(disc);
    const double t0 = -b - s, t1 = -b + s;
    if (t0 > 1e-9) return t0;
    if (t1 > 1e-9) return t1;
    return std::nullopt;
  };
}

// A step: z = near_z for x < edge_x, z = far_z for x >= edge_x (rig frame), with the vertical
// face x = edge_x between them.
inline Surface Step(double edge_x, double near_z, double far_z) {
  return [=](const Eigen::Vector3d& o, const Eigen::Vector3d& dir) -> std::optional<double> {
    std::optional<double> best;
    auto consider = [&](std::optional<double> t, auto inside) {
      if (t && inside(o + *t * dir) && (!best || *t < *best)) best = t;
    };
    const Eigen::Vector3d z(0, 0, 1), x(1, 0, 0);
    consider(HitPlane(z, near_z, o, dir), [&](const Eigen::Vector3d& p) { return p.x() < edge_x; });
    consider(HitPlane(z, far_z, o, dir), [&](const Eigen::Vector3d& p) { return p.x() >= edge_x; });
    const double zlo = std::min(near_z, far_z), zhi = std::max(near_z, far_z);
    consider(HitPlane(x, edge_x, o, dir),
             [&](const Eigen::Vector3d& p) { return p.z() >= zlo && p.z() <= zhi; });
    return best;
  };
}

// Ground truth per camera pixel.
struct AnalyticView {
  ProjectorMap map;                   // CV_64F coordinates
  cv::Mat point_x, point_y, point_z;  // CV_64F true surface point (rig frame), NaN where none
  Eigen::Vector3d Point(int u, int v) const {
    return {point_x.at<double>(v, u), point_y.at<double>(v, u), point_z.at<double>(v, u)};
  }
};

// The exact ProjectorMap of `camera` looking at `surface` lit by the rig's projector. A pixel is
// valid when its ray hits the surface, the point projects inside the projector image and the
// projector sees it (no earlier hit along the projector's ray).
inline AnalyticView RenderAnalytic(const Rig& rig, const RigDevice& camera, const Surface& surface,
                                   bool code_x = true, bool code_y = true) {
  const RigDevice& proj = *rig.projector;
  AnalyticView view;
  const int w = camera.model.width, h = camera.model.height;
  view.map.Allocate(w, h, code_x, code_y);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  view.map.proj_x = cv::Mat(h, w, CV_64FC1, cv::Scalar(nan));
  view.map.proj_y = cv::Mat(h, w, CV_64FC1, cv::Scalar(nan));
  view.point_x = cv::Mat(h, w, CV_64FC1, cv::Scalar(nan));
  view.point_y = view.point_x.clone();
  view.point_z = view.point_x.clone();
  const Eigen::Matrix3d rig_from_cam = camera.cam_from_rig.rotation.toRotationMatrix().transpose();
  const Eigen::Vector3d center = camera.CenterInRig();
  const Eigen::Vector3d proj_center = proj.CenterInRig();
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < w; ++u) {
        const auto xy = camera.model.UndistortToNormalized(Eigen::Vector2d(u, v));
        if (!xy) continue;
        const Eigen::Vector3d dir =
            (rig_from_cam * Eigen::Vector3d(xy->x(), xy->y(), 1.0)).normalized();
        const auto t = surface(center, dir);
        if (!t) continue;
        const Eigen::Vector3d p = center + *t * dir;
        const auto pp = proj.model.Project(proj.cam_from_rig * p);
        if (!pp || !proj.model.IsInImage(*pp)) continue;
        const Eigen::Vector3d to_p = p - proj_center;
        const auto tp = surface(proj_center, to_p.normalized());
        if (!tp || *tp < to_p.norm() - 1e-6) continue;  // shadowed
        view.point_x.at<double>(v, u) = p.x();
        view.point_y.at<double>(v, u) = p.y();
        view.point_z.at<double>(v, u) = p.z();
        if (code_x) view.map.proj_x.at<double>(v, u) = pp->x();
        if (code_y) view.map.proj_y.at<double>(v, u) = pp->y();
        view.map.status.at<uint8_t>(v, u) = static_cast<uint8_t>(PixelStatus::kValid);
        view.map.quality.at<float>(v, u) = 100.0f;
      }
    }
  });
  return view;
}

// The same map with CV_32F coordinates (what patterns/ produces).
inline ProjectorMap ToFloatMap(const ProjectorMap& map) {
  ProjectorMap out = map;
  map.proj_x.convertTo(out.proj_x, CV_32F);
  map.proj_y.convertTo(out.proj_y, CV_32F);
  out.status = map.status.clone();
  out.quality = map.quality.clone();
  return out;
}

// A copy with N(0, sigma^2) projector px added to every valid coordinate (fixed seed).
inline ProjectorMap AddNoise(const ProjectorMap& map, double sigma_px, unsigned seed) {
  ProjectorMap out = map;
  out.proj_x = map.proj_x.clone();
  out.proj_y = map.proj_y.clone();
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma_px);
  for (int v = 0; v < map.height(); ++v) {
    for (int u = 0; u < map.width(); ++u) {
      if (map.status.at<uint8_t>(v, u) != 0) continue;
      if (map.has_x) out.proj_x.at<double>(v, u) += noise(rng);
      if (map.has_y) out.proj_y.at<double>(v, u) += noise(rng);
    }
  }
  return out;
}

// A downscaled copy of a camera (factor 1/s: fewer pixels, same field of view) for fast tests.
inline CameraModel Downscaled(const CameraModel& m, int s) {
  CameraModel out = m;
  out.width = m.width / s;
  out.height = m.height / s;
  out.params[CameraModel::kFx] /= s;
  out.params[CameraModel::kFy] /= s;
  out.params[CameraModel::kCx] = (m.params[CameraModel::kCx] + 0.5) / s - 0.5;
  out.params[CameraModel::kCy] = (m.params[CameraModel::kCy] + 0.5) / s - 0.5;
  return out;
}

}  // namespace slshadow::testing
