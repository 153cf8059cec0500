#include "workflows/twin/diagnose.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

namespace slshadow::twin {
namespace {

// The robust quadratic field recovers a planted smooth field under noise and 10 % gross outliers
// (the calibration signature's estimator).
TEST(Diagnose, SmoothFieldRecoversPlantedQuadratic) {
  const int w = 320, h = 240;
  cv::Mat residual(h, w, CV_32FC1), mask(h, w, CV_8UC1, cv::Scalar(255));
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0, 0.1f);
  std::uniform_real_distribution<float> u(0, 1);
  const auto truth = [&](int x, int y) {
    const double a = (x - w / 2.0) / (w / 2.0), b = (y - h / 2.0) / (h / 2.0);
    return 0.8 + 0.3 * a - 0.2 * b + 0.1 * a * a + 0.05 * a * b;
  };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      residual.at<float>(y, x) =
          static_cast<float>(truth(x, y)) + noise(rng) + (u(rng) < 0.1f ? 3.0f : 0.0f);
    }
  }
  double rms = 0, mean = 0;
  const cv::Mat field = SmoothField(residual, mask, &rms, &mean);
  ASSERT_FALSE(field.empty());
  double worst = 0;
  for (int y = 0; y < h; y += 5) {
    for (int x = 0; x < w; x += 5)
      worst = std::max(worst, std::abs(field.at<float>(y, x) - truth(x, y)));
  }
  EXPECT_LT(worst, 0.03);
  EXPECT_NEAR(mean, 0.8 + 0.1 / 3, 0.03);  // mean of a^2 over [-1, 1] is 1/3
  // Too few samples: no field.
  cv::Mat empty_mask(h, w, CV_8UC1, cv::Scalar(0));
  EXPECT_TRUE(SmoothField(residual, empty_mask).empty());
}

}  // namespace
}  // namespace slshadow::twin
