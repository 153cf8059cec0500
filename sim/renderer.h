// The two passes of the virtual scanner (DESIGN.md, "The simulator"); this header holds the
// second, the first is sim/geometry_pass.h:
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

#include "core/rig.h"
#include "sim/geometry_pass.h"
#include "sim/scene.h"

namespace slshadow {

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
  PatternRenderer(const Scene& scene, const Rig& rig, int camera_index,
                  const GeometryBuffer& geometry);

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
  std::vector<cv::Mat> RenderBatch(const std::vector<cv::Mat>& projector_images,
                                   int first_pattern_index) const;
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
