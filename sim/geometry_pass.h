// The geometry pass of the virtual scanner (sim/renderer.h describes both passes): camera rays
// per pixel sample, and per camera the first hit, projector coordinate, projector visibility and
// radiometric factor of each sample, plus the ground-truth maps. Implemented in geometry_pass.cc.
//
// Units: mm, px. Projector coordinates use OpenCV's pixel convention (integer = pixel centre).
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/camera_model.h"
#include "core/projector_map.h"
#include "core/rig.h"
#include "sim/raycaster.h"

namespace slshadow {

// Viewing rays of one camera, in the camera frame (unit length), per pixel sample: sample s of
// pixel (x, y) has index (y * width + x) * n^2 + s, s = b * n + a, at pixel position
// (x + (a + 0.5) / n - 0.5, y + (b + 0.5) / n - 0.5) (n = samples_per_axis; n = 1: the pixel
// centre). NaN where the pixel cannot be unprojected (distortion folds over). Computing them
// costs one Newton undistortion per sample: compute once per camera and reuse across scans.
struct CameraRays {
  int width = 0;
  int height = 0;
  int samples_per_axis = 1;
  std::vector<Eigen::Vector3f> samples;  // width * height * n^2
  std::vector<Eigen::Vector3f>
      centers;  // width * height; empty when n = 1 (then samples are the centres)
};
// `storage`: rays no longer needed whose buffers are reused (no new allocation when large enough).
CameraRays ComputeCameraRays(const CameraModel& camera, int samples_per_axis,
                             CameraRays storage = {});

// Per-sample floats of a geometry pass (index as CameraRays) in a continuous CV_32FC1 Mat from
// the simulator's pool of large blocks (sim/pooled_mats.cc: recycled across passes and scans, so
// later scans do not fault their pages in again). A copy shares the storage, like cv::Mat. With
// one sample per pixel, proj_x / proj_y / factor share their storage with the ground-truth maps
// projector.proj_x / proj_y / quality (the same values, written once).
class SampleBuffer {
 public:
  SampleBuffer() = default;
  explicit SampleBuffer(cv::Mat m) : mat_(std::move(m)) {}
  float* data() { return reinterpret_cast<float*>(mat_.data); }
  const float* data() const { return reinterpret_cast<const float*>(mat_.data); }
  size_t size() const { return mat_.total(); }
  bool empty() const { return mat_.empty(); }
  float& operator[](size_t i) { return data()[i]; }
  const float& operator[](size_t i) const { return data()[i]; }
  const float* begin() const { return data(); }
  const float* end() const { return data() + size(); }
  const cv::Mat& mat() const { return mat_; }

 private:
  cv::Mat mat_;
};

// What the geometry pass yields for one camera.
struct GeometryBuffer {
  int width = 0;
  int height = 0;
  int samples_per_axis = 1;
  // Per sample (index as CameraRays):
  SampleBuffer proj_x;         // projector column, px; NaN when not lit
  SampleBuffer proj_y;         // projector row, px; NaN when not lit
  SampleBuffer factor;         // albedo * cos_p * (d_ref/d_p)^2 when lit, else 0
  SampleBuffer albedo;         // albedo at the hit, 0 where the ray misses
  SampleBuffer proj_sigma_px;  // projector defocus sigma (px); empty unless that layer is on

  // Ground truth per pixel, from the pixel-centre ray:
  cv::Mat depth_mm;        // CV_32FC1: z of the hit in the camera frame; NaN where no surface
  cv::Mat point_in_rig;    // CV_32FC3: hit point in the rig frame, mm; NaN where no surface
  cv::Mat normal_in_rig;   // CV_32FC3: unit surface normal facing the camera; NaN where no surface
  cv::Mat visibility;      // CV_8UC1: 0 no surface, 1 surface not lit by the projector, 2 lit
  cv::Mat object_id;       // CV_32SC1: index into Scene::objects, -1 where no surface
  ProjectorMap projector;  // true projector coordinates; status valid where lit, shadow elsewhere;
                           // quality = the radiometric factor

  // Counts and time of the pass (for benchmarks).
  int64_t primary_rays = 0;
  int64_t shadow_rays = 0;
  double seconds = 0;
};

// The geometry pass of camera `camera_index` of `rig` (which needs a projector). `rays` must be
// ComputeCameraRays of that camera with the scene's supersampling. Reference distance: the
// scene's radiometry.reference_distance_mm, or the rig's working distance when 0.
// ground_truth = false: only what the pattern pass needs (the per-sample buffers); the
// ground-truth maps (depth_mm ... projector) stay empty, which saves about a quarter of the pass
// and 30 bytes per pixel. The camera-defocus layer needs depth, so with it on they are made anyway.
GeometryBuffer TraceGeometry(const RayCaster& caster, const Rig& rig, int camera_index,
                             const CameraRays& rays, TraceMode mode = TraceMode::kPacket16,
                             bool ground_truth = true);

}  // namespace slshadow
