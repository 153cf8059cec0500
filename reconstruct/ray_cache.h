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
#include <optional>
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

// Newton's method on the distortion of `model` (as CameraModel::UndistortToNormalized, same
// convergence test and fold check) started at `initial` instead of the distorted coordinate:
// from a close start it converges in one or two steps.
std::optional<Eigen::Vector2d> UndistortFrom(const CameraModel& model, const Eigen::Vector2d& pixel,
                                             const Eigen::Vector2d& initial,
                                             int max_iterations = 50);

// Undistortion of any sub-pixel position, started from the bilinear interpolation of `grid`
// (the model's RayGrid) and finished by UndistortFrom: agrees with
// CameraModel::UndistortToNormalized to the Newton tolerance (1e-13) at a fraction of the cost.
// Falls back to the plain iteration outside the grid or next to invalid grid cells.
std::optional<Eigen::Vector2d> UndistortWithGrid(const CameraModel& model, const RayGrid& grid,
                                                 const Eigen::Vector2d& pixel);

// Computes the grid (row-parallel), each pixel's Newton iteration started from its left
// neighbour's solution. Agrees with CameraModel::UndistortToNormalized to 1e-13.
RayGrid ComputeRayGrid(const CameraModel& model);

// The grid of `model` from the process-wide cache, computing it on first use (thread-safe; at most
// kMaxCachedRayGrids models are kept, least recently used first out).
std::shared_ptr<const RayGrid> CachedRayGrid(const CameraModel& model);
constexpr int kMaxCachedRayGrids = 8;
void ClearRayCache();
size_t RayCacheSize();

}  // namespace slshadow
