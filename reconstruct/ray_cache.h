// Per-pixel viewing rays of a camera model, computed once and shared.
//
// Undistorting a pixel is a Newton iteration (CameraModel::UndistortToNormalized); a dense
// reconstruction needs it for every pixel of every camera, and the answer depends only on the
// model. RayGrid holds the undistorted normalised coordinates (x, y) (ray (x, y, 1) in the camera
// frame) of every pixel centre in double precision, NaN where undistortion fails. The cache is
// keyed by the model's size and parameter bits, so a changed calibration never reuses stale rays.
#pragma once

#include <cmath>
#include <cstddef>
#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/camera_model.h"

namespace slshadow {

struct RayGrid {
  int width = 0;
  int height = 0;
  std::vector<Eigen::Vector2d> xy;  // row-major, width * height; NaN where undistortion failed

  const Eigen::Vector2d& at(int u, int v) const { return xy[static_cast<size_t>(v) * width + u]; }
  bool Valid(int u, int v) const { return std::isfinite(at(u, v).x()); }
};

// Computes the grid (row-parallel). Exactly CameraModel::UndistortToNormalized per pixel.
RayGrid ComputeRayGrid(const CameraModel& model);

// The grid of `model` from the process-wide cache, computing it on first use (thread-safe; at most
// kMaxCachedRayGrids models are kept, least recently used first out).
std::shared_ptr<const RayGrid> CachedRayGrid(const CameraModel& model);
constexpr int kMaxCachedRayGrids = 8;
void ClearRayCache();
size_t RayCacheSize();

}  // namespace slshadow
