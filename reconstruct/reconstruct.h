// Dense reconstruction from decoded ProjectorMaps: camera-projector triangulation (one camera
// against the projector, an inverse camera) and stereo (two cameras matched through equal
// projector coordinates), then gates, filters, normals -> PointCloud in the rig frame (mm).
//
// Every reference-grid cell either becomes a point or is rejected with one RejectReason
// (dense_grid.h); the summary counts them, so rejected + accepted = cells, and no NaN/inf point
// is ever emitted. Per point the cloud keeps scalar fields quality (decode quality), u, v (source
// pixel in the reference camera image, px) and reprojection_error_px.
//
// Maps: proj_x / proj_y CV_32F as produced by patterns/, or CV_64F (e.g. exact ground truth);
// status CV_8U PixelStatus, quality CV_32F, all of the camera's size.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/point_cloud.h"
#include "core/projector_map.h"
#include "core/rig.h"
#include "reconstruct/calibration_check.h"
#include "reconstruct/dense_grid.h"
#include "reconstruct/stereo_matcher.h"
#include "reconstruct/triangulation.h"

namespace slshadow {

class ConfigNode;

enum class ReconstructMode { kProjector, kStereo };
std::string ToString(ReconstructMode mode);                          // "projector", "stereo"
ReconstructMode ReconstructModeFromString(const std::string& name);  // throws on unknown names

// Stereo: how the cameras' maps are resampled on the rectified grids and the crossings located.
//  kCubic: bicubic resampling (4x4 Lagrange) and the crossing on the 4-sample cubic: O(h^4)
//    interpolation error, but the 4-point weights amplify the decoding noise.
//  kLinear: bilinear resampling and linear crossings: O(h^2) bias, below the decoding noise on
//    smooth surfaces; the least noise.
//  (Measured errors and noise of both: docs/benchmarks/log/reconstruction.md.)
//  kAuto: cubic when both maps are CV_64F (exact or ground-truth codes), linear for decoded
//    (CV_32F) maps.
enum class StereoInterpolation { kAuto, kLinear, kCubic };
std::string ToString(StereoInterpolation interpolation);  // "auto", "linear", "cubic"
StereoInterpolation StereoInterpolationFromString(
    const std::string& name);  // throws on unknown names

struct ReconstructOptions {
  // Two-view solver (camera-projector with both axes coded, and stereo). With one coded projector
  // axis the exact ray-surface solve is used whatever the method.
  TriangulationMethod method = TriangulationMethod::kMidpoint;
  // Noise of the reference pixel position relative to that of the matched coordinate (sigma ratio,
  // > 0), used by the optimal method only. The reference pixel (camera pixel, rectified left cell)
  // is exact and the decoded / matched coordinate carries the noise, hence small.
  double reference_noise_ratio = 0.01;
  // Depth gate along the reference camera's optical axis (rectified axis in stereo), mm.
  double min_depth_mm = 50;
  double max_depth_mm = 5000;
  // Rays closer to parallel than this are rejected (depth is ill-conditioned there), degrees.
  double min_triangulation_angle_deg = 2.0;
  // Gate on the RMS reprojection error of the point over both views, px. Infinity disables it.
  double max_reprojection_error_px = 1.0;
  // Gate on |epipolar error|, projector px (calibration_check.h: projector mode with both axes
  // coded, distance of the projector coordinate from the camera pixel's epipolar line; stereo with
  // both axes coded, |row_left - row_right| of the matched projector rows). Infinity disables it.
  double max_epipolar_error_px = 1.0;
  // Pixels of decode quality below this are rejected (units of ProjectorMap::quality). 0 keeps all.
  float min_quality = 0.0f;
  // Stereo: rectified maps are not interpolated across, nor matched over, projector-coordinate
  // steps larger than this between neighbouring samples, projector px. 0 ("auto"): 3 x the largest
  // median step between decoded neighbours (per map and direction), at least 4 px
  // (AutoCodeStepGate), so that a camera coarser than the projector or a surface seen obliquely
  // keeps its smooth steps. Not the default: it also lets interpolation reach further into a
  // sphere's limb, where the steps grow smoothly to a jump (docs/studies/stability_grazing_quick:
  // stereo at 65 deg with auto, none past 55 with 4; a 25 mm sphere's PS error 0.12 mm with auto).
  double max_code_step_px = 4.0;
  // Stereo: nor across a code jump below that gate: a step between neighbouring pixels (along a
  // row or a column of the camera image) larger than 0.5 projector px and than this many times
  // each of the steps on either side of it. A smooth surface's step changes gradually (also at a
  // crease or where the surface turns away); a jump is an occlusion edge, or a wall's foot seen at
  // grazing incidence with the table behind it, whose interpolated codes match the other camera
  // between the two surfaces: ghost points up to a few mm in front of both
  // (docs/benchmarks/log/2026-12-07-ghost-points.md). 0 disables the test.
  double max_code_step_ratio = 2.5;
  // Stereo resampling and crossings (StereoInterpolation above).
  StereoInterpolation stereo_interpolation = StereoInterpolation::kAuto;
  // Depth-discontinuity filter (filters.h), in pixel footprints; dilation in pixels.
  bool filter_depth_discontinuities = true;
  double max_depth_jump_footprints = 8.0;
  int discontinuity_dilation_px = 1;
  // Statistical outlier removal (filters.h): RMS distance to the 4 nearest of the 8 grid
  // neighbours, in footprints (a surface tilted by a to the line of sight keeps two neighbours at
  // ~1 footprint and two at ~1 / cos(a)), rejected above max(mean + ratio * std, floor): an
  // off-surface spike has no near neighbour, a steep surface (< ~78 deg) stays.
  bool filter_outliers = true;
  int outlier_window_radius_px = 1;
  int outlier_neighbors = 4;
  double outlier_std_ratio = 4.0;
  double outlier_min_distance_footprints = 4.0;
  // Normals from the organised grid, oriented toward the reference camera.
  bool estimate_normals = true;
  // The summary's residual statistics (reprojection and epipolar error) and the calibration check
  // below. false skips both (the gates still apply, the cloud is the same): a sweep job reads
  // neither, and they cost ~25 ms CPU of a 1920x1200 reconstruction.
  bool report_residuals = true;
  // Calibration check (calibration_check.h): warn when the systematic part of the epipolar error
  // (the RMS of a smooth field fitted to it) exceeds a threshold, projector px. 0 (default): the
  // threshold is calibration_noise_factor x the decode noise of this capture (the scatter about
  // the field), at least calibration_min_warning_px; > 0: this fixed threshold; infinity: the
  // check reports but never warns. The default factor 1 warns when the calibration, not the
  // decoding, dominates a point's error (the margins: docs/benchmarks/log/calibration-check.md).
  double calibration_warning_px = 0;
  double calibration_noise_factor = 1.0;
  // Floor of the automatic threshold, projector px: exact (noise-free) maps leave no noise to
  // judge by; 0.01 px is 0.016 mm of depth on the full-size demo rig at 500 mm.
  double calibration_min_warning_px = 0.01;

  // Throws slshadow::Error naming the first violated constraint.
  void Check() const;
  // Every field under its own name; enums by name, infinite gates as "inf".
  nlohmann::json ToJson() const;
};

// The automatic code-step gate of stereo (ReconstructOptions::max_code_step_px = 0), projector px:
// 3 x the largest median step between decoded neighbours, over the two maps and the two directions
// (to the right, below; a pair's step the larger over the coded axes; every 2nd row and column),
// at least 4. 4 when a map has no such pair.
double AutoCodeStepGate(const ProjectorMap& left, const ProjectorMap& right);

// ReconstructOptions from a file (YAML or JSON, docs/formats.md "Reconstruct options"): the
// fields of ToJson(); missing fields keep their defaults, unknown keys are rejected, the result
// is Check()ed. Throws slshadow::Error naming the file, the field and the value.
ReconstructOptions ReconstructOptionsFromConfig(const ConfigNode& node);

// Statistics of a per-correspondence residual, px.
struct ResidualStats {
  int64_t count = 0;
  double median = 0;
  double p95 = 0;
  double max = 0;
  double rms = 0;
  nlohmann::json ToJson() const;
};
// The statistics of `values` (non-finite entries ignored): Summarize()'s count, median, 95th
// percentile, maximum and RMS of the values (core/statistics.h). Pass a temporary (std::move) to
// spare the copy.
ResidualStats ComputeResidualStats(std::vector<float> values);

struct ReconstructSummary {
  ReconstructMode mode = ReconstructMode::kProjector;
  TriangulationMethod method = TriangulationMethod::kMidpoint;
  // Noise of the reference pixel position relative to that of the matched coordinate (sigma ratio,
  // > 0), used by the optimal method only. The reference pixel (camera pixel, rectified left cell)
  // is exact and the decoded / matched coordinate carries the noise, hence small.
  double reference_noise_ratio = 0.01;
  std::string camera;                   // reference camera
  std::string other_device;             // "projector" or the right camera
  int grid_width = 0, grid_height = 0;  // reference grid (camera image, or rectified left image)
  int64_t cells = 0;
  int64_t points = 0;                                 // accepted
  std::array<int64_t, kNumRejectReasons> rejected{};  // by RejectReason (index 0: accepted)
  // Stereo: the code-step gate used, projector px (ReconstructOptions::max_code_step_px, or the
  // automatic one); 0 in projector mode.
  double code_step_gate_px = 0;
  // Decoder statuses of the reference camera's pixels (stereo: of both cameras), by PixelStatus.
  std::array<int64_t, kNumPixelStatus> decode_status{};
  int64_t normal_fallbacks = 0;
  // Residuals of all triangulated correspondences, before the reprojection/epipolar gates and
  // the filters. reprojection_error_px: RMS over both views (projector mode: camera and projector
  // px; stereo: left and right camera px, ~0 by construction with the midpoint, so no evidence of
  // calibration). epipolar_error_px: |epipolar error|, projector px (calibration_check.h); empty
  // (count 0) with one coded axis.
  ResidualStats reprojection_error_px;
  ResidualStats epipolar_error_px;
  // The calibration check of the epipolar error (calibration_check.h), always reported.
  CalibrationCheck calibration_check;
  // Calibration-check warnings (its Message() when it warns); empty when the residuals fit the
  // calibration or the check is not available.
  std::vector<std::string> warnings;
  // Wall-clock seconds per stage.
  double rays_s = 0, match_s = 0, triangulate_s = 0, filter_s = 0, normals_s = 0, total_s = 0;
  // Process CPU seconds (user + system, all threads) per stage: CPU / wall ~ 2 on 2 idle cores.
  double rays_cpu_s = 0, match_cpu_s = 0, triangulate_cpu_s = 0, filter_cpu_s = 0,
         normals_cpu_s = 0, total_cpu_s = 0;

  std::string BriefReport() const;
  std::string FullReport() const;
  nlohmann::json ToJson() const;
};

struct Reconstruction {
  PointCloud cloud;  // rig frame, mm
  DenseGrid grid;    // the organised result with per-cell reasons
  ReconstructSummary summary;
  // Stereo with one coded axis: the signed projector error per grid cell (a projector in the rig)
  // or the fitted projector error (none), projector px (calibration_check.h; NaN where none);
  // empty otherwise.
  std::vector<float> projector_error_px;
};

// Camera `camera` of the rig against its projector. Throws slshadow::Error when the rig has no
// projector, the camera is unknown, the map's size differs from the camera's or no axis is coded.
// max_cloud_points > 0: the cloud holds at most that many points, every s-th accepted cell
// (DenseGrid::ToPointCloud); the grid and the summary are those of the whole reconstruction.
Reconstruction ReconstructWithProjector(const Rig& rig, const std::string& camera,
                                        const ProjectorMap& map,
                                        const ReconstructOptions& options = {},
                                        size_t max_cloud_points = 0);

// Stereo mode's triangulation of one correspondence, what ReconstructStereo runs on every matched
// cell: the left rectified pixel (u, v) and the right rectified column ur on the same rectified
// row (stereo_matcher.h), triangulated with options.method between the two rectified cameras,
// then gated by the triangulation angle, the side of all four (rectified and original) cameras
// and the depth range (rectified left axis).
class StereoTriangulator {
 public:
  StereoTriangulator(const RigDevice& left, const RigDevice& right, const StereoRectification& rect,
                     const ReconstructOptions& options);
  // kAccepted with the point (rig frame, mm) and its reprojection error (RMS over both views, px,
  // against left_source_px, the left cell's position in the left image, and the right match's
  // position in the right image; with the midpoint, which is the closed-form intersection of the
  // two coplanar rectified rays, the right term is zero by construction and not evaluated);
  // otherwise kParallelRays, kBehindDevice or kOutOfDepthRange.
  RejectReason Triangulate(double u, double v, double ur, const Eigen::Vector2d& left_source_px,
                           Eigen::Vector3d* point_in_rig, double* reprojection_error_px) const;

 private:
  StereoRectification rect_;
  TriangulationView view0_, view1_, left_view_, right_view_;
  TwoViewTriangulator tri_;
  Eigen::Matrix3d right_from_rect_, rig_from_rect_;
  std::array<double, CameraModel::kNumParams> left_params_, right_params_;
  TriangulationMethod method_;
  double sin_min_, min_depth_mm_, max_depth_mm_;
};

// Cameras `left` and `right` matched by equal projector column along rectified epipolar lines.
// The grid is the rectified left image (stereo_matcher.h). Throws when a camera is unknown, the
// maps do not code projector columns or do not match their cameras' sizes.
// max_cloud_points as for ReconstructWithProjector.
Reconstruction ReconstructStereo(const Rig& rig, const std::string& left, const std::string& right,
                                 const ProjectorMap& left_map, const ProjectorMap& right_map,
                                 const ReconstructOptions& options = {},
                                 size_t max_cloud_points = 0);

// Frees what reconstructions keep for the next one: the calling thread's reused buffers (rectified
// maps, matches, residuals, normals, filter scratch), the ray cache and the grid pool (several
// hundred MB after a stereo reconstruction of 1920x1200 cameras). The next reconstruction
// allocates them again; results do not change.
void ReleaseReconstructionBuffers();

}  // namespace slshadow
