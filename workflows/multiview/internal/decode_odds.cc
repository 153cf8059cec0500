#include "workflows/multiview/internal/decode_odds.h"

#include <algorithm>
#include <cmath>
#include <cstring>

namespace slshadow::multiview::internal {

namespace {

double NormalCdf(double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); }

}  // namespace

DecodeOdds::DecodeOdds(double shadow_threshold, double noise,
                       const std::array<std::vector<double>, 2>& global, double contrast_threshold,
                       const std::vector<PixelBitContrast>& bit_contrast) {
  if (!(noise > 0) && bit_contrast.empty()) return;
  noise_ = noise;
  global_ = global;
  bit_contrast_ = bit_contrast;
  // |pattern - inverse| is an integer, read >= the threshold when x rho + noise reaches
  // threshold - 1/2.
  const double c_cut = std::max(0.0, std::ceil(contrast_threshold) - 0.5);
  contrast_cut_ = c_cut;
  // The contrast test on a coarser grid (its cost: every bit of every measured pixel), linear in
  // between; it only grows with the level, so 1 once it reaches it.
  constexpr double kCoarse = 0.25;
  std::vector<double> coarse;
  const auto contrast_pass = [&](double x) {
    const auto j = static_cast<size_t>(x / kCoarse);
    while (coarse.size() <= j + 1) {
      const bool done = !coarse.empty() && coarse.back() >= 1 - 1e-9;
      coarse.push_back(done ? 1.0 : ContrastPass(static_cast<double>(coarse.size()) * kCoarse));
    }
    const double f = x / kCoarse - static_cast<double>(j);
    return coarse[j] * (1 - f) + coarse[j + 1] * f;
  };
  double global_max = 0;
  for (const auto& axis : global) {
    for (double g : axis) global_max = std::max(global_max, g);
  }
  const double max_level = 2 * shadow_threshold + global_max + 20 * std::max(noise, 1.0) +
                           (bit_contrast.empty() ? 0 : 40.0);
  const auto n = static_cast<size_t>(std::ceil(std::min(max_level, 4096.0) / step_)) + 1;
  const int k0 = static_cast<int>(std::ceil(shadow_threshold));
  table_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const double level = static_cast<double>(i) * step_;
    // The shadow test reads white - black, the contrast test pattern - inverse: other frames, so
    // independent draws of the noise about the pixel's level. White - black is an integer: at least
    // k0 when level + noise reaches k0 - 1/2.
    const double shadow_pass = noise > 0 ? NormalCdf((level - (k0 - 0.5)) / noise)
                                         : (level >= shadow_threshold ? 1.0 : 0.0);
    table_[i] = shadow_pass > 0 ? std::clamp(shadow_pass * contrast_pass(level), 0.0, 1.0) : 0.0;
  }
}

double DecodeOdds::ContrastPass(double lit_range) const {
  if (bit_contrast_.empty()) return 1.0;
  // A bit read at or above the threshold: |ratio x direct + noise| >= the cut.
  const auto pass = [&](double ratio, double global) {
    const double c = ratio * std::max(0.0, lit_range - global);
    if (!(noise_ > 0)) return c >= contrast_cut_ ? 1.0 : 0.0;
    return NormalCdf((c - contrast_cut_) / noise_) + NormalCdf((-c - contrast_cut_) / noise_);
  };
  double sum = 0;
  for (const PixelBitContrast& px : bit_contrast_) {
    double pixel = 1;
    for (size_t a = 0; a < 2; ++a) {
      const std::vector<float>& ratio = px.ratio[a];
      if (ratio.empty()) continue;
      // Every bit passes, or exactly one whose flip gives the adjacent code fails: with the
      // products of the bits' odds below and above each bit.
      const size_t nb = ratio.size();
      thread_local std::vector<double> p, below;
      p.resize(nb);
      below.resize(nb + 1);
      below[0] = 1;
      for (size_t b = 0; b < nb; ++b) {
        p[b] = pass(ratio[b], b < global_[a].size() ? global_[a][b] : 0.0);
        below[b + 1] = below[b] * p[b];
      }
      double one = 0, above = 1;
      for (size_t b = nb; b-- > 0;) {
        if ((px.adjacent_bits[a] >> b) & 1u) one += (1 - p[b]) * below[b] * above;
        above *= p[b];
      }
      pixel *= below[nb] + one;
    }
    sum += pixel;
  }
  return sum / static_cast<double>(bit_contrast_.size());
}

double DecodeOdds::Decode(double level) const {
  if (table_.empty()) return 1.0;
  const double x = std::max(0.0, level) / step_;
  const auto i = static_cast<size_t>(x);
  if (i + 1 >= table_.size()) return table_.back();
  const double f = x - static_cast<double>(i);
  return table_[i] * (1 - f) + table_[i + 1] * f;
}

namespace {

uint64_t SplitMix64(uint64_t index) {
  uint64_t z = index + 0x9e3779b97f4a7c15ull;
  z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ull;
  z = (z ^ (z >> 27)) * 0x94d049bb133111ebull;
  return z ^ (z >> 31);
}

}  // namespace

double FixedUniform(uint64_t index) {
  return static_cast<double>(SplitMix64(index) >> 11) * 0x1.0p-53;
}

uint64_t PoseSeed(const Rigid3d& pose) {
  const double values[7] = {pose.rotation.w(),   pose.rotation.x(),    pose.rotation.y(),
                            pose.rotation.z(),   pose.translation.x(), pose.translation.y(),
                            pose.translation.z()};
  uint64_t seed = 0;
  for (double v : values) {
    uint64_t bits = 0;
    std::memcpy(&bits, &v, sizeof(bits));
    seed = SplitMix64(seed ^ bits);
  }
  return seed;
}

}  // namespace slshadow::multiview::internal
