#include <gtest/gtest.h>

#include <cmath>
#include <numbers>

#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {
namespace {

// Decodes the Gray code of column c from the generated projector images themselves.
TEST(GeneratePatterns, GrayCodeColumnsAndRowsDecodeToTheirIndex) {
  PatternSpec s;
  s.kind = PatternKind::kGrayCode;
  s.projector_width = 100;
  s.projector_height = 37;
  s.intensity_min = 20;
  s.intensity_max = 200;
  const auto images = GeneratePatterns(s);
  const auto frames = s.Frames();
  ASSERT_EQ(images.size(), frames.size());
  for (const cv::Mat& im : images) {
    EXPECT_EQ(im.type(), CV_8UC1);
    EXPECT_EQ(im.cols, 100);
    EXPECT_EQ(im.rows, 37);
  }
  EXPECT_EQ(cv::countNonZero(images[0] != 200), 0);  // white
  EXPECT_EQ(cv::countNonZero(images[1] != 20), 0);   // black
  for (int r = 0; r < 37; ++r) {
    for (int c = 0; c < 100; ++c) {
      uint32_t gx = 0, gy = 0;
      for (size_t i = 2; i < frames.size(); ++i) {
        const uint8_t v = images[i].at<uint8_t>(r, c);
        const uint8_t inv =
            images[i + (frames[i].role == FrameRole::kGrayBit ? 1 : -1)].at<uint8_t>(r, c);
        ASSERT_EQ(v + inv, 220);  // pattern and inverse are complementary
        if (frames[i].role != FrameRole::kGrayBit) continue;
        const uint32_t bit = v == 200 ? 1u : 0u;
        (frames[i].axis == 0 ? gx : gy) |= bit << frames[i].bit;
      }
      uint32_t bx = gx, by = gy;  // Gray to binary
      for (uint32_t shift = 1; shift < 32; shift <<= 1) {
        bx ^= bx >> shift;
        by ^= by >> shift;
      }
      ASSERT_EQ(bx, static_cast<uint32_t>(c));
      ASSERT_EQ(by, static_cast<uint32_t>(r));
    }
  }
}

TEST(GeneratePatterns, PhaseFramesFollowTheFormula) {
  PatternSpec s;
  s.kind = PatternKind::kPhaseShift;
  s.projector_width = 64;
  s.projector_height = 40;
  s.phase_steps = 3;
  s.period_px = 12.5;
  const auto images = GeneratePatterns(s);
  const auto frames = s.Frames();
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role != FrameRole::kPhase) continue;
    for (int r = 0; r < 40; r += 7) {
      for (int c = 0; c < 64; ++c) {
        const double x = frames[i].axis == 0 ? c : r;
        const double v =
            127.5 + 127.5 * std::cos(2 * std::numbers::pi * (x / 12.5 - frames[i].step / 3.0));
        ASSERT_EQ(images[i].at<uint8_t>(r, c), static_cast<int>(std::floor(v + 0.5)))
            << frames[i].Name();
      }
    }
  }
  // Gray frames of the phase shift code the half-period index floor(2 x / P).
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role != FrameRole::kGrayBit || frames[i].axis != 0) continue;
    for (int c = 0; c < 64; ++c) {
      const auto h = static_cast<uint32_t>(std::floor(2.0 * c / 12.5));
      const bool on = (((h ^ (h >> 1)) >> frames[i].bit) & 1u) != 0;
      ASSERT_EQ(images[i].at<uint8_t>(5, c), on ? 255 : 0);
      ASSERT_EQ(images[i + 1].at<uint8_t>(5, c), on ? 0 : 255);
    }
  }
}

TEST(GeneratePatterns, RejectsABadSpec) {
  PatternSpec s;
  s.projector_width = 0;
  EXPECT_THROW(GeneratePatterns(s), Error);
}

}  // namespace
}  // namespace slshadow
