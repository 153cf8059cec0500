#include "reconstruct/dense_grid.h"

#include <limits>

#include <opencv2/core.hpp>

namespace slshadow {

const char* ToString(RejectReason reason) {
  switch (reason) {
    case RejectReason::kAccepted: return "accepted";
    case RejectReason::kNotDecoded: return "not_decoded";
    case RejectReason::kLowQuality: return "low_quality";
    case RejectReason::kNoRay: return "no_ray";
    case RejectReason::kNoMatch: return "no_match";
    case RejectReason::kAmbiguousMatch: return "ambiguous_match";
    case RejectReason::kParallelRays: return "parallel_rays";
    case RejectReason::kBehindDevice: return "behind_device";
    case RejectReason::kOutOfDepthRange: return "out_of_depth_range";
    case RejectReason::kReprojectionError: return "reprojection_error";
    case RejectReason::kEpipolarError: return "epipolar_error";
    case RejectReason::kDepthDiscontinuity: return "depth_discontinuity";
    case RejectReason::kOutlier: return "outlier";
    case RejectReason::kOutsideImage: return "outside_image";
  }
  return "unknown";
}

void DenseGrid::Allocate(int w, int h) {
  width = w;
  height = h;
  const size_t n = static_cast<size_t>(w) * h;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  point_in_rig.assign(n, Eigen::Vector3d::Constant(std::numeric_limits<double>::quiet_NaN()));
  reason.assign(n, static_cast<uint8_t>(RejectReason::kNotDecoded));
  quality.assign(n, 0.0f);
  source_u.assign(n, nan);
  source_v.assign(n, nan);
  reprojection_error_px.assign(n, nan);
  epipolar_error_px.assign(n, nan);
}

std::array<int64_t, kNumRejectReasons> DenseGrid::CountByReason() const {
  std::array<int64_t, kNumRejectReasons> counts{};
  for (uint8_t r : reason) {
    if (r < kNumRejectReasons) ++counts[r];
  }
  return counts;
}

PointCloud DenseGrid::ToPointCloud(const std::vector<Eigen::Vector3f>* normals) const {
  // Rows are counted, then filled in parallel at their prefix offsets (same order as a serial scan).
  std::vector<size_t> row_start(static_cast<size_t>(height) + 1, 0);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      size_t n = 0;
      for (int u = 0; u < width; ++u) n += Accepted(Index(u, v)) ? 1 : 0;
      row_start[static_cast<size_t>(v) + 1] = n;
    }
  });
  for (int v = 0; v < height; ++v) row_start[static_cast<size_t>(v) + 1] += row_start[static_cast<size_t>(v)];
  const size_t count = row_start.back();
  PointCloud cloud;
  cloud.points.resize(count);
  const bool with_normals = normals && normals->size() == reason.size();
  if (with_normals) cloud.normals.resize(count);
  std::vector<float> q(count), us(count), vs(count), e(count);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      size_t k = row_start[static_cast<size_t>(v)];
      for (int u = 0; u < width; ++u) {
        const size_t i = Index(u, v);
        if (!Accepted(i)) continue;
        cloud.points[k] = point_in_rig[i];
        if (with_normals) cloud.normals[k] = (*normals)[i];
        q[k] = quality[i];
        us[k] = source_u[i];
        vs[k] = source_v[i];
        e[k] = reprojection_error_px[i];
        ++k;
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
