#include <algorithm>
#include <cmath>
#include <numbers>

#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {

DirectGlobal SeparateDirectGlobal(const PatternSpec& spec,
                                  const std::vector<cv::Mat>& camera_images, int fine_bits) {
  spec.Check();
  SLSHADOW_THROW_IF(static_cast<int>(camera_images.size()) != spec.NumImages(),
                    "direct/global separation: the ", ToString(spec.kind), " spec has ",
                    spec.NumImages(), " images per camera (got ", camera_images.size(), ")");
  SLSHADOW_THROW_IF(fine_bits < 1, "direct/global separation: fine_bits must be >= 1 (got ",
                    fine_bits, ")");
  std::vector<cv::Mat> images(camera_images.size());
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& im = camera_images[i];
    SLSHADOW_THROW_IF(im.type() != CV_8UC1 && im.type() != CV_16UC1,
                      "direct/global separation: image ", i, " must be CV_8UC1 or CV_16UC1");
    SLSHADOW_THROW_IF(im.size() != camera_images[0].size(), "direct/global separation: image ", i,
                      " differs in size from image 0");
    im.convertTo(images[i], CV_32F);
  }
  const std::vector<FrameInfo> frames = spec.Frames();
  DirectGlobal out;
  if (spec.kind == PatternKind::kGrayCode) {
    cv::Mat lit, dark;
    for (size_t i = 0; i < frames.size(); ++i) {
      const FrameInfo& f = frames[i];
      if ((f.role != FrameRole::kGrayBit && f.role != FrameRole::kGrayBitInverse) ||
          f.bit >= fine_bits)
        continue;
      if (lit.empty()) {
        lit = images[i].clone();
        dark = images[i].clone();
      } else {
        cv::max(lit, images[i], lit);
        cv::min(dark, images[i], dark);
      }
    }
    const cv::Mat& black = images[static_cast<size_t>(spec.BlackFrameIndex())];
    out.direct = lit - dark;
    out.global = cv::max(2 * (dark - black), 0.0);
    return out;
  }
  // Phase codecs: the N steps of the finest period of the first coded axis.
  const int axis = spec.code_x ? 0 : 1;
  cv::Mat sum_s = cv::Mat::zeros(images[0].size(), CV_32F), sum_c = sum_s.clone(),
          sum = sum_s.clone();
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& f = frames[i];
    if (f.role != FrameRole::kPhase || f.axis != axis || f.frequency != 0) continue;
    const double d = spec.PhaseStepAngle(f.step);
    sum_s += images[i] * std::sin(d);
    sum_c += images[i] * std::cos(d);
    sum += images[i];
  }
  cv::Mat magnitude;
  cv::magnitude(sum_s, sum_c, magnitude);
  const cv::Mat modulation = magnitude * (2.0 / spec.phase_steps);
  const cv::Mat mean = sum / spec.phase_steps;
  out.direct = 2 * modulation;
  out.global = cv::max(2 * (mean - modulation), 0.0);
  return out;
}

}  // namespace slshadow
