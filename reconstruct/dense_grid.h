// DenseGrid: a reconstruction organised on a reference image grid (the camera in projector mode,
// the rectified left camera in stereo mode), before it becomes a PointCloud. Every grid cell is a
// candidate point with the reason it was rejected, so counts per reason are exact and no NaN/inf
// point can reach the cloud.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/point_cloud.h"

namespace slshadow {

// Why a grid cell gave no point. Stored as uint8_t in DenseGrid::reason.
enum class RejectReason : uint8_t {
  kAccepted = 0,
  kNotDecoded = 1,         // the decoder marked the pixel invalid (ProjectorMap::status)
  kLowQuality = 2,         // decode quality below ReconstructOptions::min_quality
  kNoRay = 3,              // undistortion (camera or projector) or ray-axis solve did not converge
  kNoMatch = 4,            // stereo: no equal projector coordinate on the epipolar line
  kAmbiguousMatch = 5,     // stereo: more than one match within the disparity range
  kParallelRays = 6,       // triangulation angle below the minimum (near-parallel rays)
  kBehindDevice = 7,       // the point is not in front of both devices
  kOutOfDepthRange = 8,    // depth outside [min_depth_mm, max_depth_mm]
  kReprojectionError = 9,  // reprojection error above the gate
  kEpipolarError = 10,     // |epipolar error| above the gate (both modes; calibration_check.h)
  kDepthDiscontinuity = 11,  // at or next to a depth jump
  kOutlier = 12,             // statistical outlier removal
  kOutsideImage = 13,        // stereo: the rectified cell falls outside the camera image
};
constexpr int kNumRejectReasons = 14;
std::string ToString(RejectReason reason);  // "accepted", "not_decoded", ...

struct DenseGrid {
  int width = 0;
  int height = 0;
  Eigen::Vector3d viewpoint_in_rig = Eigen::Vector3d::Zero();  // reference device centre
  double focal_px = 1;  // reference focal length: a pixel's footprint at range r is r / focal_px
  // Per cell, row-major. point_in_rig is meaningful (finite) only where reason == kAccepted.
  std::vector<Eigen::Vector3d> point_in_rig;
  std::vector<uint8_t> reason;
  std::vector<float> quality;                // decode quality of the source pixel
  std::vector<float> source_u, source_v;     // source pixel in the reference camera image, px
  std::vector<float> reprojection_error_px;  // RMS over the two views
  // Signed epipolar error, projector px (calibration_check.h); NaN when not defined for the mode.
  std::vector<float> epipolar_error_px;

  // Grids of a whole image are large (~45 B per cell, ~100 MB at 1920x1200) and fresh memory of
  // that size costs page faults on every reconstruction, so a destroyed grid hands its buffers to a
  // process-wide pool (at most kPooledGrids grids' worth) that Allocate takes them from.
  static constexpr int kPooledGrids = 2;
  DenseGrid() = default;
  DenseGrid(const DenseGrid&) = default;
  DenseGrid(DenseGrid&&) noexcept = default;
  DenseGrid& operator=(const DenseGrid&) = default;
  DenseGrid& operator=(DenseGrid&&) noexcept = default;
  ~DenseGrid();
  static void ReleasePool();  // frees the pooled buffers

  void Allocate(int width, int height);  // every cell kNotDecoded (row-parallel fill)
  size_t Index(int u, int v) const { return static_cast<size_t>(v) * width + u; }
  bool Accepted(size_t i) const {
    return reason[i] == static_cast<uint8_t>(RejectReason::kAccepted);
  }
  std::array<int64_t, kNumRejectReasons> CountByReason() const;
  // The accepted cells as a cloud with scalar fields quality, u, v, reprojection_error_px (and
  // normals when `normals` has one entry per cell). max_points > 0: at most that many, every
  // s-th accepted cell in row-major order from the first (s = ceil(accepted / max_points)), what
  // PointCloud::Select of every s-th point of the whole cloud gives, without materialising it.
  PointCloud ToPointCloud(const std::vector<Eigen::Vector3f>* normals = nullptr,
                          size_t max_points = 0) const;
};

}  // namespace slshadow
