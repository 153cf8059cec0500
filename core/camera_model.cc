#include "core/camera_model.h"

#include <cmath>

#include "core/error.h"

namespace slshadow {

CameraModel::CameraModel(int width_px, int height_px, double fx, double fy, double cx, double cy,
                         double k1, double k2, double p1, double p2, double k3)
    : width(width_px), height(height_px), params{fx, fy, cx, cy, k1, k2, p1, p2, k3} {}

bool CameraModel::HasDistortion() const {
  for (int i = kK1; i <= kK3; ++i) {
    if (params[i] != 0.0) return true;
  }
  return false;
}

void CameraModel::Check(const std::string& what) const {
  static const char* kNames[kNumParams] = {"fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"};
  SLSHADOW_THROW_IF(width <= 0, what, ": width: must be a positive number of pixels (got ", width,
                    ")");
  SLSHADOW_THROW_IF(height <= 0, what, ": height: must be a positive number of pixels (got ",
                    height, ")");
  for (int i = 0; i < kNumParams; ++i) {
    SLSHADOW_THROW_IF(!std::isfinite(params[i]), what, ": ", kNames[i], ": must be finite (got ",
                      params[i], ")");
  }
  SLSHADOW_THROW_IF(params[kFx] <= 0, what, ": fx: focal length must be positive (got ",
                    params[kFx], ")");
  SLSHADOW_THROW_IF(params[kFy] <= 0, what, ": fy: focal length must be positive (got ",
                    params[kFy], ")");
}

std::optional<Eigen::Vector2d> CameraModel::Project(const Eigen::Vector3d& point_in_cam) const {
  if (!(point_in_cam.z() > 0)) return std::nullopt;
  Eigen::Vector2d pixel;
  ImgFromCam(params.data(), point_in_cam.data(), pixel.data());
  return pixel;
}

std::optional<Eigen::Vector2d> CameraModel::UndistortToNormalized(const Eigen::Vector2d& pixel,
                                                                  int max_iterations) const {
  const Eigen::Vector2d target((pixel.x() - cx()) / fx(), (pixel.y() - cy()) / fy());
  if (!HasDistortion()) return target;
  const double k1 = params[kK1], k2 = params[kK2], p1 = params[kP1], p2 = params[kP2],
               k3 = params[kK3];
  Eigen::Vector2d xy = target;
  for (int it = 0; it < max_iterations; ++it) {
    const double x = xy.x(), y = xy.y();
    const double r2 = x * x + y * y;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2);  // d radial / d r2
    Eigen::Vector2d distorted;
    Distort(params.data(), x, y, &distorted.x(), &distorted.y());
    const Eigen::Vector2d residual = distorted - target;
    // Jacobian [a b; b d] of the distortion (symmetric for this model).
    const double a = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x;
    const double b = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y;
    const double d = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x;
    const double det = a * d - b * b;
    if (!(det > 0)) return std::nullopt;  // past the fold of the distortion
    if (residual.squaredNorm() < 1e-26) return xy;
    xy -=
        Eigen::Vector2d(d * residual.x() - b * residual.y(), a * residual.y() - b * residual.x()) /
        det;
    if (!xy.allFinite()) return std::nullopt;
  }
  return std::nullopt;
}

std::optional<Eigen::Vector3d> CameraModel::Unproject(const Eigen::Vector2d& pixel) const {
  const auto xy = UndistortToNormalized(pixel);
  if (!xy) return std::nullopt;
  return Eigen::Vector3d(xy->x(), xy->y(), 1.0).normalized();
}

double CameraModel::HorizontalFovRad() const {
  const auto left = UndistortToNormalized({-0.5, cy()});
  const auto right = UndistortToNormalized({width - 0.5, cy()});
  if (!left || !right) return std::nan("");
  return std::atan(-left->x()) + std::atan(right->x());
}

double CameraModel::VerticalFovRad() const {
  const auto top = UndistortToNormalized({cx(), -0.5});
  const auto bottom = UndistortToNormalized({cx(), height - 0.5});
  if (!top || !bottom) return std::nan("");
  return std::atan(-top->y()) + std::atan(bottom->y());
}

}  // namespace slshadow
