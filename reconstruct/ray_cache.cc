#include "reconstruct/ray_cache.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <list>
#include <mutex>
#include <utility>

#include <opencv2/core.hpp>

namespace slshadow {

std::optional<Eigen::Vector2d> UndistortFrom(const CameraModel& model, const Eigen::Vector2d& pixel,
                                             const Eigen::Vector2d& initial, int max_iterations) {
  const Eigen::Vector2d target((pixel.x() - model.cx()) / model.fx(),
                               (pixel.y() - model.cy()) / model.fy());
  if (!model.HasDistortion()) return target;
  const double* p = model.params.data();
  const double k1 = p[CameraModel::kK1], k2 = p[CameraModel::kK2], p1 = p[CameraModel::kP1],
               p2 = p[CameraModel::kP2], k3 = p[CameraModel::kK3];
  Eigen::Vector2d xy = initial;
  for (int it = 0; it < max_iterations; ++it) {
    const double x = xy.x(), y = xy.y();
    const double x2 = x * x, y2 = y * y, r2 = x2 + y2;
    const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2);
    const double rx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x2) - target.x();
    const double ry = y * radial + p1 * (r2 + 2 * y2) + 2 * p2 * x * y - target.y();
    const double a = radial + 2 * x2 * dradial + 2 * p1 * y + 6 * p2 * x;
    const double b = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y;
    const double d = radial + 2 * y2 * dradial + 6 * p1 * y + 2 * p2 * x;
    const double det = a * d - b * b;
    if (!(det > 0)) return std::nullopt;  // past the fold of the distortion
    if (rx * rx + ry * ry < 1e-26) return xy;
    xy.x() -= (d * rx - b * ry) / det;
    xy.y() -= (a * ry - b * rx) / det;
    if (!xy.allFinite()) return std::nullopt;
  }
  return std::nullopt;
}

std::optional<Eigen::Vector2d> UndistortWithGrid(const CameraModel& model, const RayGrid& grid,
                                                 const Eigen::Vector2d& pixel) {
  const double x = pixel.x(), y = pixel.y();
  if (x >= 0 && y >= 0 && x < grid.width - 1 && y < grid.height - 1) {
    const int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    const double ax = x - x0, ay = y - y0;
    const Eigen::Vector2d& a = grid.at(x0, y0);
    const Eigen::Vector2d& b = grid.at(x0 + 1, y0);
    const Eigen::Vector2d& c = grid.at(x0, y0 + 1);
    const Eigen::Vector2d& d = grid.at(x0 + 1, y0 + 1);
    const Eigen::Vector2d start = (1 - ay) * ((1 - ax) * a + ax * b) + ay * ((1 - ax) * c + ax * d);
    if (start.allFinite()) return UndistortFrom(model, pixel, start);
  }
  return model.UndistortToNormalized(pixel);
}

RayGrid ComputeRayGrid(const CameraModel& model) {
  RayGrid grid;
  grid.width = model.width;
  grid.height = model.height;
  grid.xy.resize(static_cast<size_t>(model.width) * model.height);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  cv::parallel_for_(cv::Range(0, model.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      Eigen::Vector2d* out = grid.xy.data() + static_cast<size_t>(v) * model.width;
      std::optional<Eigen::Vector2d> previous;
      for (int u = 0; u < model.width; ++u) {
        const Eigen::Vector2d pixel(u, v);
        auto xy =
            previous ? UndistortFrom(model, pixel, *previous) : model.UndistortToNormalized(pixel);
        if (!xy && previous) xy = model.UndistortToNormalized(pixel);  // the cold start decides
        out[u] = xy ? *xy : Eigen::Vector2d(nan, nan);
        previous = xy;
      }
    }
  });
  return grid;
}

namespace {

struct Key {
  int width, height;
  std::array<double, CameraModel::kNumParams> params;
  bool operator==(const Key& o) const {
    return width == o.width && height == o.height &&
           std::memcmp(params.data(), o.params.data(), sizeof(double) * params.size()) == 0;
  }
};

struct Cache {
  std::mutex mutex;
  std::list<std::pair<Key, std::shared_ptr<const RayGrid>>> entries;  // most recent first
};

Cache& GlobalCache() {
  static Cache cache;
  return cache;
}

}  // namespace

std::shared_ptr<const RayGrid> CachedRayGrid(const CameraModel& model) {
  const Key key{model.width, model.height, model.params};
  Cache& cache = GlobalCache();
  {
    std::lock_guard<std::mutex> lock(cache.mutex);
    for (auto it = cache.entries.begin(); it != cache.entries.end(); ++it) {
      if (it->first == key) {
        cache.entries.splice(cache.entries.begin(), cache.entries, it);
        return cache.entries.front().second;
      }
    }
  }
  // Computed outside the lock; two threads asking for the same new model both compute it once.
  auto grid = std::make_shared<const RayGrid>(ComputeRayGrid(model));
  std::lock_guard<std::mutex> lock(cache.mutex);
  for (auto& entry : cache.entries) {
    if (entry.first == key) return entry.second;
  }
  cache.entries.emplace_front(key, grid);
  while (cache.entries.size() > static_cast<size_t>(kMaxCachedRayGrids)) cache.entries.pop_back();
  return grid;
}

void ClearRayCache() {
  Cache& cache = GlobalCache();
  std::lock_guard<std::mutex> lock(cache.mutex);
  cache.entries.clear();
}

size_t RayCacheSize() {
  Cache& cache = GlobalCache();
  std::lock_guard<std::mutex> lock(cache.mutex);
  return cache.entries.size();
}

}  // namespace slshadow
