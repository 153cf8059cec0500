#include "reconstruct/dense_grid.h"

#include <algorithm>
#include <limits>
#include <mutex>

#include <opencv2/core.hpp>

namespace slshadow {

std::string ToString(RejectReason reason) {
  switch (reason) {
    case RejectReason::kAccepted:
      return "accepted";
    case RejectReason::kNotDecoded:
      return "not_decoded";
    case RejectReason::kLowQuality:
      return "low_quality";
    case RejectReason::kNoRay:
      return "no_ray";
    case RejectReason::kNoMatch:
      return "no_match";
    case RejectReason::kAmbiguousMatch:
      return "ambiguous_match";
    case RejectReason::kParallelRays:
      return "parallel_rays";
    case RejectReason::kBehindDevice:
      return "behind_device";
    case RejectReason::kOutOfDepthRange:
      return "out_of_depth_range";
    case RejectReason::kReprojectionError:
      return "reprojection_error";
    case RejectReason::kEpipolarError:
      return "epipolar_error";
    case RejectReason::kDepthDiscontinuity:
      return "depth_discontinuity";
    case RejectReason::kOutlier:
      return "outlier";
    case RejectReason::kOutsideImage:
      return "outside_image";
  }
  return "unknown";
}

namespace {

struct GridBuffers {
  std::vector<Eigen::Vector3d> point_in_rig;
  std::vector<uint8_t> reason;
  std::vector<float> quality, source_u, source_v, reprojection_error_px, epipolar_error_px;
};

struct GridPool {
  std::mutex mutex;
  std::vector<GridBuffers> free;
};

GridPool& Pool() {
  static GridPool* pool = new GridPool;  // never destroyed: grids may die after static destruction
  return *pool;
}

// Grids below this many cells are not worth pooling.
constexpr size_t kMinPooledCells = size_t{1} << 16;

}  // namespace

DenseGrid::~DenseGrid() {
  if (point_in_rig.capacity() < kMinPooledCells) return;
  GridPool& pool = Pool();
  std::lock_guard<std::mutex> lock(pool.mutex);
  if (pool.free.size() >= static_cast<size_t>(kPooledGrids)) return;
  pool.free.push_back({std::move(point_in_rig), std::move(reason), std::move(quality),
                       std::move(source_u), std::move(source_v), std::move(reprojection_error_px),
                       std::move(epipolar_error_px)});
}

void DenseGrid::ReleasePool() {
  GridPool& pool = Pool();
  std::lock_guard<std::mutex> lock(pool.mutex);
  pool.free.clear();
  pool.free.shrink_to_fit();
}

void DenseGrid::Allocate(int w, int h) {
  width = w;
  height = h;
  const size_t n = static_cast<size_t>(w) * h;
  if (n >= kMinPooledCells && point_in_rig.capacity() < n) {
    GridPool& pool = Pool();
    std::lock_guard<std::mutex> lock(pool.mutex);
    // The pooled set with the largest capacity (a too small one grows below as a fresh one would).
    auto best = pool.free.end();
    for (auto it = pool.free.begin(); it != pool.free.end(); ++it) {
      if (best == pool.free.end() || it->point_in_rig.capacity() > best->point_in_rig.capacity())
        best = it;
    }
    if (best != pool.free.end()) {
      point_in_rig = std::move(best->point_in_rig);
      reason = std::move(best->reason);
      quality = std::move(best->quality);
      source_u = std::move(best->source_u);
      source_v = std::move(best->source_v);
      reprojection_error_px = std::move(best->reprojection_error_px);
      epipolar_error_px = std::move(best->epipolar_error_px);
      pool.free.erase(best);
    }
  }
  // resize() of the point vector leaves new elements uninitialised (Eigen's default constructor):
  // every field is filled below, row-parallel, so fresh pages are first touched by both threads.
  point_in_rig.resize(n);
  reason.resize(n);
  quality.resize(n);
  source_u.resize(n);
  source_v.resize(n);
  reprojection_error_px.resize(n);
  epipolar_error_px.resize(n);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const Eigen::Vector3d nan3 = Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN());
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    const size_t a = static_cast<size_t>(rows.start) * w, b = static_cast<size_t>(rows.end) * w;
    std::fill(point_in_rig.begin() + static_cast<std::ptrdiff_t>(a),
              point_in_rig.begin() + static_cast<std::ptrdiff_t>(b), nan3);
    std::fill(reason.begin() + static_cast<std::ptrdiff_t>(a),
              reason.begin() + static_cast<std::ptrdiff_t>(b),
              static_cast<uint8_t>(RejectReason::kNotDecoded));
    std::fill(quality.begin() + static_cast<std::ptrdiff_t>(a),
              quality.begin() + static_cast<std::ptrdiff_t>(b), 0.0f);
    for (auto* f : {&source_u, &source_v, &reprojection_error_px, &epipolar_error_px}) {
      std::fill(f->begin() + static_cast<std::ptrdiff_t>(a),
                f->begin() + static_cast<std::ptrdiff_t>(b), nan);
    }
  });
}

std::array<int64_t, kNumRejectReasons> DenseGrid::CountByReason() const {
  std::array<int64_t, kNumRejectReasons> counts{};
  for (uint8_t r : reason) {
    if (r < kNumRejectReasons) ++counts[r];
  }
  return counts;
}

PointCloud DenseGrid::ToPointCloud(const std::vector<Eigen::Vector3f>* normals,
                                   size_t max_points) const {
  // Rows are counted, then filled in parallel at their prefix offsets (same order as a serial
  // scan).
  std::vector<size_t> row_start(static_cast<size_t>(height) + 1, 0);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      size_t n = 0;
      for (int u = 0; u < width; ++u) n += Accepted(Index(u, v)) ? 1 : 0;
      row_start[static_cast<size_t>(v) + 1] = n;
    }
  });
  for (int v = 0; v < height; ++v)
    row_start[static_cast<size_t>(v) + 1] += row_start[static_cast<size_t>(v)];
  const size_t accepted = row_start.back();
  // Every stride-th accepted cell (its ordinal a multiple of stride) at position ordinal / stride.
  const size_t stride =
      max_points > 0 && accepted > max_points ? (accepted + max_points - 1) / max_points : 1;
  const size_t count = (accepted + stride - 1) / stride;
  PointCloud cloud;
  cloud.points.resize(count);
  const bool with_normals = normals && normals->size() == reason.size();
  if (with_normals) cloud.normals.resize(count);
  // The scalar fields are zero-filled by their constructors: in parallel, one field per task.
  std::array<std::vector<float>, 4> fields;
  cv::parallel_for_(cv::Range(0, 4), [&](const cv::Range& r) {
    for (int k = r.start; k < r.end; ++k) fields[static_cast<size_t>(k)].resize(count);
  });
  std::vector<float>& q = fields[0];
  std::vector<float>& us = fields[1];
  std::vector<float>& vs = fields[2];
  std::vector<float>& e = fields[3];
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      size_t ordinal = row_start[static_cast<size_t>(v)];
      for (int u = 0; u < width; ++u) {
        const size_t i = Index(u, v);
        if (!Accepted(i)) continue;
        if (ordinal++ % stride != 0) continue;
        const size_t k = (ordinal - 1) / stride;
        cloud.points[k] = point_in_rig[i];
        if (with_normals) cloud.normals[k] = (*normals)[i];
        q[k] = quality[i];
        us[k] = source_u[i];
        vs[k] = source_v[i];
        e[k] = reprojection_error_px[i];
      }
    }
  });
  cloud.SetScalar("quality", std::move(q));
  cloud.SetScalar("u", std::move(us));
  cloud.SetScalar("v", std::move(vs));
  cloud.SetScalar("reprojection_error_px", std::move(e));
  return cloud;
}

}  // namespace slshadow
