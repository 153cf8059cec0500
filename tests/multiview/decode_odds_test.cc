// The decoder's odds at its thresholds (workflows/multiview/internal/decode_odds.h) against a brute
// force: the decoder's integer tests (patterns/codec.h: white - black >= 12, per axis every Gray
// bit's |pattern - inverse| >= 4 or all but one whose flip gives the adjacent code) drawn with
// Gaussian noise per frame difference, fixed seed.
#include "workflows/multiview/internal/decode_odds.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

namespace slshadow::multiview::internal {
namespace {

constexpr double kThreshold = 12, kContrast = 4;

TEST(DecodeOddsTest, InactiveWithoutNoiseOrBits) {
  const DecodeOdds odds(kThreshold, 0, {}, kContrast, {});
  EXPECT_FALSE(odds.Active());
  EXPECT_EQ(odds.Decode(3), 1.0);  // inactive: the caller's own rule decides
}

// Noise alone: the shadow test on an integer read of level + noise.
TEST(DecodeOddsTest, TheShadowTestMatchesIntegerReadsOfNoisyLevels) {
  const double sigma = 1.05;
  const DecodeOdds odds(kThreshold, sigma, {}, kContrast, {});
  ASSERT_TRUE(odds.Active());
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0, sigma);
  for (double level : {9.0, 10.5, 11.2, 11.8, 12.0, 12.7, 14.0, 17.0}) {
    int pass = 0;
    const int n = 200000;
    for (int k = 0; k < n; ++k) pass += std::lround(level + noise(rng)) >= kThreshold;
    EXPECT_NEAR(odds.Decode(level), static_cast<double>(pass) / n, 0.005) << level;
  }
  // Far from the threshold: certain either way.
  EXPECT_LT(odds.Decode(5), 1e-9);
  EXPECT_GT(odds.Decode(30), 1 - 1e-9);
}

// The contrast test of one pixel: a code edge at the finest bit of x (its ratio 0.05, its flip
// gives the adjacent code), the other bits at their ratios, the unmodulated part per bit.
TEST(DecodeOddsTest, TheContrastTestMatchesTheDecodersRuleOnNoisyBits) {
  const double sigma = 1.0;
  PixelBitContrast px;
  px.ratio[0] = {0.05f, 0.5f, 0.7f, 0.8f, 0.9f, 0.95f};
  px.ratio[1] = {0.45f, 0.3f, 0.75f, 0.85f, 0.9f, 0.95f};
  // Code x = 0b000001 (Gray 000001): flipping bit 0 gives 0, bit 1 gives 2 (adjacent); bit 2
  // gives 6. Code y = 0b000011: bit 0 gives 2, bit 2 gives 4 (adjacent), bit 1 gives 0.
  px.adjacent_bits = {0b000011u, 0b000101u};
  const std::array<std::vector<double>, 2> global = {std::vector<double>{5, 4, 3, 3, 2, 2},
                                                     std::vector<double>{5, 4, 3, 3, 2, 2}};
  const DecodeOdds odds(kThreshold, sigma, global, kContrast, {px});
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0, sigma);
  for (double level : {12.0, 14.0, 17.0, 22.0, 30.0}) {
    int pass = 0;
    const int n = 100000;
    for (int k = 0; k < n; ++k) {
      bool ok = true;
      for (size_t a = 0; a < 2; ++a) {
        int low = 0, low_bit = -1;
        for (size_t b = 0; b < px.ratio[a].size(); ++b) {
          const double c = px.ratio[a][b] * std::max(0.0, level - global[a][b]) + noise(rng);
          if (std::lround(std::abs(c)) < kContrast) ++low, low_bit = static_cast<int>(b);
        }
        ok = ok && (low == 0 || (low == 1 && ((px.adjacent_bits[a] >> low_bit) & 1u)));
      }
      pass += ok;
    }
    EXPECT_NEAR(odds.ContrastPass(level), static_cast<double>(pass) / n, 0.01) << level;
  }
}

TEST(DecodeOddsTest, FixedUniformIsUniformAndFixed) {
  EXPECT_EQ(FixedUniform(42), FixedUniform(42));
  double sum = 0;
  int below = 0;
  for (uint64_t i = 0; i < 100000; ++i) {
    const double u = FixedUniform(i);
    ASSERT_GE(u, 0);
    ASSERT_LT(u, 1);
    sum += u;
    below += u < 0.25;
  }
  EXPECT_NEAR(sum / 100000, 0.5, 0.005);
  EXPECT_NEAR(below / 100000.0, 0.25, 0.005);
}

}  // namespace
}  // namespace slshadow::multiview::internal
