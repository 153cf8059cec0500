// The decoder's odds on a real capture (coverage_prediction.h, pixel_noise_dn): per mean lit range
// L of the surface, the probability that a camera pixel there decodes (Gray code, patterns/codec.h)
// with the pixel noise on each frame: the shadow test (white - black, an integer, at least
// shadow_threshold, L plus the noise) and, independently (other frames), the contrast test (per
// axis every Gray bit's |pattern - inverse| at least contrast_threshold, or all but one whose flip
// gives the adjacent code; a bit's contrast is its measured ratio x (lit range - that bit's global
// part) plus the noise). Internal to workflows/multiview.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include "core/rigid3.h"
#include "workflows/multiview/coverage_prediction.h"

namespace slshadow::multiview::internal {

class DecodeOdds {
 public:
  DecodeOdds() = default;
  // `noise`: the lit range's pixel noise (sigma, grey levels), also taken as |pattern - inverse|'s;
  // `global`: per axis and bit, the lit range's part its fringes do not modulate (grey levels;
  // empty: none); `bit_contrast`: the pixels' bits (empty: the contrast test always passes).
  // Inactive (Active() false) when noise is 0 and bit_contrast empty.
  DecodeOdds(double shadow_threshold, double noise,
             const std::array<std::vector<double>, 2>& global, double contrast_threshold,
             const std::vector<PixelBitContrast>& bit_contrast);
  bool Active() const { return !table_.empty(); }
  // The probability that a pixel of mean lit range `level` decodes.
  double Decode(double level) const;
  // The probability that a pixel of mean lit range `level` passes the contrast test.
  double ContrastPass(double level) const;
  double Noise() const { return noise_; }

 private:
  double noise_ = 0, contrast_cut_ = 0;
  std::array<std::vector<double>, 2> global_;
  std::vector<PixelBitContrast> bit_contrast_;
  double step_ = 0.05;
  std::vector<double> table_;  // Decode at level k * step_
};

// A uniform number in [0, 1) fixed by `index` (splitmix64; the prediction's deterministic draws).
double FixedUniform(uint64_t index);
// A seed fixed by a view's pose (its rotation and translation, bit for bit), so that the draws of
// two views are independent.
uint64_t PoseSeed(const Rigid3d& pose);

}  // namespace slshadow::multiview::internal
