#include "reconstruct/ray_cache.h"

#include <cmath>
#include <cstring>
#include <list>
#include <limits>
#include <mutex>
#include <utility>

#include <opencv2/core.hpp>

namespace slshadow {

RayGrid ComputeRayGrid(const CameraModel& model) {
  RayGrid grid;
  grid.width = model.width;
  grid.height = model.height;
  grid.xy.resize(static_cast<size_t>(model.width) * model.height);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  cv::parallel_for_(cv::Range(0, model.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      Eigen::Vector2d* out = grid.xy.data() + static_cast<size_t>(v) * model.width;
      for (int u = 0; u < model.width; ++u) {
        const auto xy = model.UndistortToNormalized(Eigen::Vector2d(u, v));
        out[u] = xy ? *xy : Eigen::Vector2d(nan, nan);
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
