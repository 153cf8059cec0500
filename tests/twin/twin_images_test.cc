// The shadow report's per-camera image comparisons (workflows/twin/internal/twin_images.h) against
// brute force on synthetic images: frame statistics over the mask (the 8-bit integer path and the
// general one give the same figures), and projector-coordinate agreement and validity counts.
#include "workflows/twin/internal/twin_images.h"

#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

namespace slshadow::twin::internal {
namespace {

PatternSpec SmallSpec() {
  PatternSpec spec;
  spec.kind = PatternKind::kGrayCode;
  spec.projector_width = 64;
  spec.projector_height = 32;
  spec.Check();
  return spec;
}

GeometryBuffer Buffer(int w, int h) {
  GeometryBuffer g;
  g.width = w;
  g.height = h;
  g.visibility = cv::Mat(h, w, CV_8UC1, cv::Scalar(2));
  g.object_id = cv::Mat(h, w, CV_32SC1, cv::Scalar(0));
  return g;
}

TEST(TwinImages, FrameStatisticsOverTheMaskOnBothPaths) {
  const PatternSpec spec = SmallSpec();
  const std::vector<FrameInfo> frames = spec.Frames();
  const int w = 37, h = 23, nf = spec.NumImages();
  GeometryBuffer g = Buffer(w, h);
  g.visibility.at<uint8_t>(3, 4) = 1;  // not lit
  g.object_id.at<int32_t>(5, 6) = -1;  // background
  const cv::Mat mask = LitPartMask(g);
  EXPECT_EQ(cv::countNonZero(mask), w * h - 2);
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> level(0, 255);
  std::vector<cv::Mat> real8, twin8, real16, twin16;
  for (int k = 0; k < nf; ++k) {
    cv::Mat a(h, w, CV_8UC1), b(h, w, CV_8UC1);
    for (int i = 0; i < w * h; ++i) a.data[i] = static_cast<uint8_t>(level(rng));
    for (int i = 0; i < w * h; ++i) {
      // Most pixels within a few levels, some far off.
      const int d = i % 7 == 0 ? level(rng) - 128 : level(rng) % 11 - 5;
      b.data[i] = static_cast<uint8_t>(std::clamp(a.data[i] + d, 0, 255));
    }
    real8.push_back(a), twin8.push_back(b);
    cv::Mat a16, b16;
    a.convertTo(a16, CV_16UC1);
    b.convertTo(b16, CV_16UC1);
    real16.push_back(a16), twin16.push_back(b16);
  }
  const double fs = 255;
  const FrameAgreement bytes = CompareFrames(spec, frames, real8, twin8, mask, g, fs);
  const FrameAgreement words = CompareFrames(spec, frames, real16, twin16, mask, g, fs);
  ASSERT_EQ(bytes.per.size(), static_cast<size_t>(nf));
  int64_t in_all = 0;
  double worst = 1;
  for (int k = 0; k < nf; ++k) {
    double sum = 0, ss = 0;
    int64_t n = 0, in = 0;
    for (int y = 0; y < h; ++y) {
      for (int x = 0; x < w; ++x) {
        if (!mask.at<uint8_t>(y, x)) continue;
        const double d = real8[static_cast<size_t>(k)].at<uint8_t>(y, x) -
                         twin8[static_cast<size_t>(k)].at<uint8_t>(y, x);
        sum += d, ss += d * d, ++n;
        in += std::abs(d) <= 0.05 * fs;
      }
    }
    const nlohmann::json& e = bytes.per[static_cast<size_t>(k)];
    EXPECT_EQ(e.at("name").get<std::string>(), frames[static_cast<size_t>(k)].Name());
    EXPECT_DOUBLE_EQ(e.at("mean_dn").get<double>(), sum / static_cast<double>(n)) << k;
    EXPECT_DOUBLE_EQ(e.at("rms_dn").get<double>(), std::sqrt(ss / static_cast<double>(n))) << k;
    const double within = static_cast<double>(in) / static_cast<double>(n);
    EXPECT_EQ(e.at("within_5pct").get<double>(), within) << k;
    EXPECT_EQ(e.dump(), words.per[static_cast<size_t>(k)].dump()) << k;
    in_all += in;
    worst = std::min(worst, within);
  }
  EXPECT_EQ(bytes.in_all, in_all);
  EXPECT_EQ(words.in_all, in_all);
  EXPECT_EQ(bytes.worst, worst);
}

TEST(TwinImages, ProjectorCoordinatesAgainstTruth) {
  const PatternSpec spec = SmallSpec();  // codes both axes
  const int w = 16, h = 8;
  const GeometryBuffer g = Buffer(w, h);
  const cv::Mat mask = LitPartMask(g);
  ProjectorMap truth, real, twin;
  for (ProjectorMap* m : {&truth, &real, &twin}) {
    m->status = cv::Mat(h, w, CV_8UC1, cv::Scalar(0));  // 0: valid
    m->proj_x = cv::Mat(h, w, CV_32FC1);
    m->proj_y = cv::Mat(h, w, CV_32FC1);
    m->quality = cv::Mat(h, w, CV_32FC1, cv::Scalar(1));
  }
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      truth.proj_x.at<float>(y, x) = 4.0f * x, truth.proj_y.at<float>(y, x) = 4.0f * y;
      real.proj_x.at<float>(y, x) = 4.0f * x + 0.5f, real.proj_y.at<float>(y, x) = 4.0f * y;
      twin.proj_x.at<float>(y, x) = 4.0f * x, twin.proj_y.at<float>(y, x) = 4.0f * y - 0.25f;
    }
  }
  real.status.at<uint8_t>(0, 0) = 1;  // decoded by the twin only
  real.proj_x.at<float>(0, 0) = real.proj_y.at<float>(0, 0) = NAN;
  real.proj_x.at<float>(1, 1) = 4.0f + 100;  // a wrong code: beyond the 20 px gate
  cv::Mat residual, validity;
  const nlohmann::json j =
      CompareProjectorCoordinates(spec, real, twin, truth, mask, w * h, g, &residual, &validity);
  EXPECT_EQ(j.at("valid_both").get<int64_t>(), w * h - 1);
  EXPECT_EQ(j.at("valid_twin_only").get<int64_t>(), 1);
  EXPECT_EQ(j.at("valid_real_only").get<int64_t>(), 0);
  // Real vs truth: x off by 0.5 and y by 0 on the w h - 2 compared pixels (one not decoded, one
  // gated x), both axes pooled.
  const nlohmann::json& rt = j.at("real_vs_truth");
  EXPECT_EQ(rt.at("count").get<int64_t>(), 2 * (w * h - 2) + 1);
  EXPECT_EQ(rt.at("max_abs_px").get<double>(), 0.5);
  EXPECT_EQ(j.at("twin_vs_truth").at("p95_abs_px").get<double>(), 0.25);
  EXPECT_EQ(j.at("twin_vs_truth").at("median_px").get<double>(), -0.25);  // y all -0.25, x 0
  EXPECT_TRUE(std::isnan(residual.at<float>(0, 0)));
  EXPECT_EQ(residual.at<float>(2, 3), 0.5f);
  EXPECT_EQ(validity.at<cv::Vec3b>(0, 0), cv::Vec3b(255, 120, 60));  // twin only
}

}  // namespace
}  // namespace slshadow::twin::internal
