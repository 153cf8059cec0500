// The two passes of the virtual scanner (DESIGN.md, "The simulator"):
//
//  1. TraceGeometry, once per camera: for every pixel sample, the camera ray's first hit (point,
//     normal, object), the projector coordinate of that point through the projector model with
//     its distortion, whether the projector lights it (facing the projector, inside the
//     projector image, not occluded: one occlusion ray per sample) and the radiometric factor
//     albedo * cos_p * (d_ref / d_p)^2 (sim/scene.h). Rays in packets of 4 x 4 pixels
//     (rtcIntersect16 / rtcOccluded16), TBB over packets.
//  2. PatternRenderer::Render, once per projector image: lookups over that buffer,
//     DN = exposure * full_scale * (ambient * albedo + factor * I(projector coordinate)), then the
//     scene's optional layers. Geometry is never recomputed per pattern.
//
// Units: mm, px. Projector coordinates use OpenCV's pixel convention (integer = pixel centre).
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <mutex>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/projector_map.h"
#include "core/rig.h"
#include "sim/raycaster.h"
#include "sim/scene.h"

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
  std::vector<Eigen::Vector3f> centers;  // width * height; empty when n = 1 (then samples are the centres)
};
// `storage`: rays no longer needed whose buffers are reused (no new allocation when large enough).
CameraRays ComputeCameraRays(const CameraModel& camera, int samples_per_axis, CameraRays storage = {});

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
  cv::Mat depth_mm;       // CV_32FC1: z of the hit in the camera frame; NaN where no surface
  cv::Mat point_in_rig;   // CV_32FC3: hit point in the rig frame, mm; NaN where no surface
  cv::Mat normal_in_rig;  // CV_32FC3: unit surface normal facing the camera; NaN where no surface
  cv::Mat visibility;     // CV_8UC1: 0 no surface, 1 surface not lit by the projector, 2 lit
  cv::Mat object_id;      // CV_32SC1: index into Scene::objects, -1 where no surface
  ProjectorMap projector; // true projector coordinates; status valid where lit, shadow elsewhere;
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
GeometryBuffer TraceGeometry(const RayCaster& caster, const Rig& rig, int camera_index, const CameraRays& rays,
                             TraceMode mode = TraceMode::kPacket16, bool ground_truth = true);

// A batch of projector images (CV_8UC1, one size) and, made on first use by the fused pattern
// pass and then kept, the same bytes interleaved per projector pixel ([pixel][image]) so that
// one lookup reads every image of the batch from the same cache lines. Build it once per scan
// and render it for every camera (PatternRenderer::RenderBatch): the interleaving is then paid
// once, not once per camera. The images are shared with the caller (cv::Mat headers), not
// copied: their pixels must not change while the batch is in use. Thread-safe.
class PatternBatch {
 public:
  explicit PatternBatch(std::vector<cv::Mat> images);
  const std::vector<cv::Mat>& images() const { return images_; }
  int size() const { return static_cast<int>(images_.size()); }
  // size() bytes per projector pixel, then kPadding zero bytes (vector loads may overrun).
  const uint8_t* Interleaved() const;
  static constexpr int kPadding = 32;

 private:
  std::vector<cv::Mat> images_;
  mutable std::once_flag interleaved_once_;
  mutable cv::Mat interleaved_;
};

// The pattern pass for one camera: precomputes what does not depend on the pattern
// (vignetting, camera defocus levels), then renders any number of projector images.
class PatternRenderer {
 public:
  PatternRenderer(const Scene& scene, const Rig& rig, int camera_index, const GeometryBuffer& geometry);

  // Renders the camera image for one projector image (CV_8UC1 at the projector's resolution).
  // Returns CV_8UC1 when radiometry.adc_bits <= 8, else CV_16UC1 (values up to 2^adc_bits - 1).
  // `pattern_index` only seeds the noise layer. Throws slshadow::Error on a wrong image size/type.
  cv::Mat Render(const cv::Mat& projector_image, int pattern_index) const;

  // The noise-free irradiance image before quantisation, in DN as float (CV_32FC1); what Render
  // quantises (after noise). For tests of the radiometric model.
  cv::Mat RenderIrradiance(const cv::Mat& projector_image) const;

  // Several projector images in one sweep over the geometry buffer (which is then read once per
  // batch instead of once per image; the lookup weights are shared too): the same images as
  // Render(images[k], first_pattern_index + k). Batches of up to kMaxBatch images.
  static constexpr int kMaxBatch = 32;
  std::vector<cv::Mat> RenderBatch(const std::vector<cv::Mat>& projector_images, int first_pattern_index) const;
  std::vector<cv::Mat> RenderBatch(const PatternBatch& batch, int first_pattern_index) const;
  std::vector<cv::Mat> RenderIrradianceBatch(const std::vector<cv::Mat>& projector_images) const;

 private:
  const Scene& scene_;
  const GeometryBuffer& geometry_;
  int camera_index_;
  int projector_width_, projector_height_;
  double full_scale_dn_;
  std::vector<float> response_;  // 256 entries: projector value -> intensity in [0, 1]
  cv::Mat vignetting_;           // CV_32FC1 multiplier, empty when off
  // Camera defocus: per-pixel blur level (fractional index into camera_sigmas_), empty when off.
  cv::Mat camera_level_;
  std::vector<double> camera_sigmas_;
  std::vector<double> projector_sigmas_;  // projector defocus levels, empty when off
  bool linear_response_ = true;           // lookups straight on the 8-bit pattern

  cv::Mat Quantize(const cv::Mat& irradiance, int pattern_index) const;
  cv::Mat ApplyCameraDefocus(const cv::Mat& irradiance) const;
};

}  // namespace slshadow
