#include <cmath>
#include <numbers>

#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {
namespace {

// One line of a frame along its coded axis (size S), as 8-bit levels.
std::vector<uint8_t> FrameProfile(const PatternSpec& spec, const FrameInfo& frame) {
  const int size = spec.AxisSize(frame.axis);
  std::vector<uint8_t> line(static_cast<size_t>(size));
  const auto lo = static_cast<uint8_t>(spec.intensity_min);
  const auto hi = static_cast<uint8_t>(spec.intensity_max);
  switch (frame.role) {
    case FrameRole::kWhite:
      std::fill(line.begin(), line.end(), hi);
      break;
    case FrameRole::kBlack:
      std::fill(line.begin(), line.end(), lo);
      break;
    case FrameRole::kGrayBit:
    case FrameRole::kGrayBitInverse: {
      const bool inverse = frame.role == FrameRole::kGrayBitInverse;
      for (int c = 0; c < size; ++c) {
        // kGrayCode codes the pixel index; kPhaseShift the half-period index floor(2 c / P), or
        // the (shifted) period index.
        const uint32_t value = spec.GrayValue(frame.code, c);
        const uint32_t gray = value ^ (value >> 1);
        const bool on = ((gray >> frame.bit) & 1u) != 0;
        line[static_cast<size_t>(c)] = (on != inverse) ? hi : lo;
      }
      break;
    }
    case FrameRole::kPhase: {
      const double period = spec.PeriodsPx().at(static_cast<size_t>(frame.frequency));
      const double a = 0.5 * (spec.intensity_min + spec.intensity_max);
      const double b = 0.5 * (spec.intensity_max - spec.intensity_min);
      const double shift = spec.PhaseStepAngle(frame.step);
      for (int c = 0; c < size; ++c) {
        const double v = a + b * std::cos(2 * std::numbers::pi * c / period - shift);
        line[static_cast<size_t>(c)] = static_cast<uint8_t>(std::floor(v + 0.5));
      }
      break;
    }
  }
  return line;
}

}  // namespace

std::vector<cv::Mat> GeneratePatterns(const PatternSpec& spec) {
  spec.Check();
  const std::vector<FrameInfo> frames = spec.Frames();
  std::vector<cv::Mat> images(frames.size());
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& frame = frames[i];
    const std::vector<uint8_t> line = FrameProfile(spec, frame);
    cv::Mat image(spec.projector_height, spec.projector_width, CV_8UC1);
    const bool columns =
        frame.role == FrameRole::kWhite || frame.role == FrameRole::kBlack || frame.axis == 0;
    for (int r = 0; r < image.rows; ++r) {
      uint8_t* row = image.ptr<uint8_t>(r);
      if (columns) {
        std::copy(line.begin(), line.end(), row);
      } else {
        std::fill(row, row + image.cols, line[static_cast<size_t>(r)]);
      }
    }
    images[i] = image;
  }
  return images;
}

}  // namespace slshadow
