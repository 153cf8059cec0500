// Generate the projector images of a PatternSpec, and decode camera images of them into a
// ProjectorMap (per camera pixel: projector coordinate, status reason, quality).
//
// Decoding rules (exact formulas in docs/formats.md, "Pattern spec"); all levels are grey levels
// of the input images, thresholds are given on an 8-bit scale and multiplied by full_scale / 255:
//   Gray-code bit:  bit = P > I for the pattern / inverse pair (P, I): a per-pixel threshold
//                   that needs no global level; the bit contrast is |P - I|. A bit without an
//                   inverse (spec.gray_inverse false) uses the reference (white + black) / 2 or
//                   the mean of the phase frames as I.
//   Phase (N-step): S = sum_n I_n sin(a_n), C = sum_n I_n cos(a_n), a_n = spec.PhaseStepAngle(n),
//                   phase = atan2(S, C) in [0, 2 pi), modulation B' = (2 / N) sqrt(S^2 + C^2).
//   Status, first that applies: saturated (Gray code: white or black frame >= saturation_level;
//   phase codecs: any phase frame), shadow (Gray
//   code: white - black < shadow_threshold; phase codecs: 2 B' < shadow_threshold), low contrast
//   (Gray code: smallest bit contrast < contrast_threshold; phase shift: second-smallest bit
//   contrast, since one bit at a code edge is tolerated by the complementary unwrapping; Gray
//   code with gray_edge_midpoint: one unreadable bit at a code edge gives the edge position), code
//   error (code out of range, coordinate outside [-1, S], heterodyne residual > tolerance).
//   Quality: Gray code: smallest bit contrast; phase codecs: smallest modulation B'.
#pragma once

#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/projector_map.h"
#include "patterns/pattern_spec.h"

namespace slshadow {

class ConfigNode;

// The projector images of `spec`, in projection order (spec.Frames()), each CV_8UC1 of
// projector_height x projector_width. Calls spec.Check().
std::vector<cv::Mat> GeneratePatterns(const PatternSpec& spec);

struct DecodeOptions {
  // Minimum lit range (white - black, or fringe peak-to-peak 2 B'), 8-bit grey levels.
  double shadow_threshold = 12;
  // Minimum Gray-code bit contrast |pattern - inverse|, 8-bit grey levels.
  double contrast_threshold = 4;
  // A pixel with a frame at or above this level is saturated; -1: full_scale.
  int saturation_level = -1;
  // The input's full scale, -1: auto (255 for CV_8U, 65535 for CV_16U). Set 4095 for 12-bit
  // data in 16-bit images. Thresholds are multiplied by full_scale / 255.
  int full_scale = -1;
  // Gray code: when exactly one bit of an axis is below contrast_threshold and flipping it gives
  // the adjacent code c' = c +- 1, the pixel sees the edge between two projector pixels: decode it
  // to the edge (c + c') / 2 instead of rejecting it as low contrast.
  bool gray_edge_midpoint = true;
  // Multi-frequency: largest accepted rounding residual of each unwrapping step, in cycles.
  double unwrap_tolerance_cycles = 0.3;
  // Decode rows in parallel (cv::parallel_for_).
  bool parallel = true;

  // Throws slshadow::Error naming the field of the first violated constraint.
  void Check() const;
};

// DecodeOptions as a file (YAML or JSON, docs/formats.md "Decode options"): every field under its
// own name; missing fields keep their defaults, unknown keys are rejected, the result is
// Check()ed. Throws slshadow::Error naming the file, the field and the value.
nlohmann::json DecodeOptionsToJson(const DecodeOptions& options);
DecodeOptions DecodeOptionsFromConfig(const ConfigNode& node);

// Decodes one camera's images of `spec` (spec.NumImages() images in spec order, all CV_8UC1 or
// all CV_16UC1, of one size) into a ProjectorMap of the camera's size. Throws slshadow::Error on
// a bad spec, options, image count, type or size. Undecodable pixels are a status, not an error.
// Rows run in parallel (options.parallel). Speed: docs/benchmarks.md, "Pattern decoding".
ProjectorMap DecodePatterns(const PatternSpec& spec, const std::vector<cv::Mat>& camera_images,
                            const DecodeOptions& options = {});

// Direct and global light (Nayar, Krishnan, Grossberg, Raskar, SIGGRAPH 2006): under a
// high-frequency pattern lighting half the scene, a pixel sees L+ = d + g/2 when its own patch is
// lit and L- = g/2 when it is dark, so d = L+ - L- and g = 2 L-. Per camera pixel, in input grey
// levels (CV_32FC1):
//   kGrayCode: L+ / L- = max / min over the pattern and inverse frames of the `fine_bits` least
//              significant bits of every coded axis (stripes 2, 4, ... projector px wide), and
//              the black frame is subtracted first (ambient light is neither direct nor global).
//   phase codecs: from the finest period of the first coded axis, d = 2 B' and g = 2 (A - B'),
//              A the mean level; no black frame, so g includes ambient light.
// Valid where the global light varies slowly over the pattern period. Throws like DecodePatterns.
struct DirectGlobal {
  cv::Mat direct;  // CV_32FC1
  cv::Mat global;  // CV_32FC1, >= 0
};
DirectGlobal SeparateDirectGlobal(const PatternSpec& spec,
                                  const std::vector<cv::Mat>& camera_images, int fine_bits = 2);

// A fast atan2 in cycles: atan2(y, x) / (2 pi) wrapped to [0, 1); absolute error < 2e-6 cycles.
// Exposed for tests.
float Atan2Cycles(float y, float x);

}  // namespace slshadow
