#include "reconstruct/dense_grid.h"

#include <limits>

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
  PointCloud cloud;
  const size_t n = reason.size();
  size_t count = 0;
  for (size_t i = 0; i < n; ++i) count += Accepted(i) ? 1 : 0;
  cloud.points.reserve(count);
  const bool with_normals = normals && normals->size() == n;
  if (with_normals) cloud.normals.reserve(count);
  std::vector<float> q, u, v, e;
  q.reserve(count);
  u.reserve(count);
  v.reserve(count);
  e.reserve(count);
  for (size_t i = 0; i < n; ++i) {
    if (!Accepted(i)) continue;
    cloud.points.push_back(point_in_rig[i]);
    if (with_normals) cloud.normals.push_back((*normals)[i]);
    q.push_back(quality[i]);
    u.push_back(source_u[i]);
    v.push_back(source_v[i]);
    e.push_back(reprojection_error_px[i]);
  }
  cloud.SetScalar("quality", std::move(q));
  cloud.SetScalar("u", std::move(u));
  cloud.SetScalar("v", std::move(v));
  cloud.SetScalar("reprojection_error_px", std::move(e));
  return cloud;
}

}  // namespace slshadow
