// The sensor-noise generator (sim/sensor_noise.h): standard normals, independent of each other
// and of the neighbouring pixels, the same for a key whatever the block they are asked in, and
// the ADC without noise.
#include "sim/sensor_noise.h"

#include <algorithm>
#include <cmath>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

namespace slshadow {
namespace {

constexpr int kN = 1 << 21;  // ~2 M pairs: sampling error of a moment ~1e-3

struct Moments {
  double mean = 0, var = 0, skew = 0, kurt = 0;
};

Moments MomentsOf(const std::vector<float>& v) {
  Moments m;
  for (float x : v) m.mean += x;
  m.mean /= static_cast<double>(v.size());
  for (float x : v) {
    const double d = x - m.mean;
    m.var += d * d, m.skew += d * d * d, m.kurt += d * d * d * d;
  }
  const double n = static_cast<double>(v.size());
  m.var /= n;
  m.skew /= n * std::pow(m.var, 1.5);
  m.kurt /= n * m.var * m.var;
  return m;
}

double Correlation(const float* a, const float* b, size_t n) {
  double sa = 0, sb = 0, sab = 0, saa = 0, sbb = 0;
  for (size_t i = 0; i < n; ++i)
    sa += a[i], sb += b[i], sab += a[i] * b[i], saa += a[i] * a[i], sbb += b[i] * b[i];
  const double m = static_cast<double>(n);
  return (sab / m - sa / m * sb / m) /
         std::sqrt((saa / m - sa * sa / m / m) * (sbb / m - sb * sb / m / m));
}

TEST(SensorNoise, NormalsAreStandardIndependentAndNormal) {
  std::vector<float> n(kN);
  SensorNoiseNormals(7, 1, 12, 0, kN, n.data());
  const Moments m = MomentsOf(n);
  EXPECT_NEAR(m.mean, 0, 0.003);
  EXPECT_NEAR(m.var, 1, 0.004);
  EXPECT_NEAR(m.skew, 0, 0.008);
  EXPECT_NEAR(m.kurt, 3, 0.02);
  // The normal CDF at a few points (binomial sampling error < 3e-4).
  for (const double z : {-2.5, -1.0, 0.0, 0.5, 2.0}) {
    int64_t below = 0;
    for (float x : n) below += x < z;
    EXPECT_NEAR(static_cast<double>(below) / kN, 0.5 * std::erfc(-z / std::sqrt(2.0)), 0.0012)
        << "at " << z;
  }
  int64_t beyond4 = 0;
  for (float x : n) beyond4 += std::abs(x) > 4;
  EXPECT_GT(beyond4, 120) << "tails reach beyond 4 sigma (expected ~266)";
  EXPECT_LT(beyond4, 420);
  EXPECT_NEAR(Correlation(n.data(), n.data() + 1, kN - 1), 0, 0.003) << "neighbouring pixels";
  EXPECT_NEAR(Correlation(n.data(), n.data() + 1920, kN - 1920), 0, 0.003) << "the pixel below";
  // Pixels 16 b + l and 16 b + 8 + l share a hash: the two normals of one Box-Muller pair.
  std::vector<float> c, s8, c2, s2;
  for (int b = 0; b < kN / 16; ++b) {
    for (int l = 0; l < 8; ++l) {
      const float x = n[static_cast<size_t>(16 * b + l)],
                  y = n[static_cast<size_t>(16 * b + 8 + l)];
      c.push_back(x), s8.push_back(y), c2.push_back(x * x), s2.push_back(y * y);
    }
  }
  EXPECT_NEAR(Correlation(c.data(), s8.data(), c.size()), 0, 0.004) << "a Box-Muller pair";
  EXPECT_NEAR(Correlation(c2.data(), s2.data(), c.size()), 0, 0.004)
      << "independent, not only uncorrelated";
  // The 16 pixels of a block: each lane's normals are standard (no lane or half is biased).
  for (int j = 0; j < 16; ++j) {
    double sum = 0, sum_sq = 0;
    for (int b = 0; b < kN / 16; ++b) {
      const double x = n[static_cast<size_t>(16 * b + j)];
      sum += x, sum_sq += x * x;
    }
    const double count = kN / 16.0;
    EXPECT_NEAR(sum / count, 0, 0.012) << "position " << j << " of a block";
    EXPECT_NEAR(sum_sq / count, 1, 0.017) << "position " << j << " of a block";
  }
}

TEST(SensorNoise, StreamsDifferAndBlocksAgree) {
  std::vector<float> a(4096), b(4096);
  SensorNoiseNormals(7, 0, 3, 1000, 4096, a.data());
  // Any offset and length: the same values per pixel index (partial blocks of 16 included).
  for (const int first : {1000, 1003, 1517}) {
    const int count = 4096 - (first - 1000) - 5;
    std::vector<float> c(static_cast<size_t>(count));
    SensorNoiseNormals(7, 0, 3, static_cast<uint64_t>(first), count, c.data());
    for (int i = 0; i < count; ++i)
      ASSERT_EQ(c[static_cast<size_t>(i)], a[static_cast<size_t>(first - 1000 + i)]);
  }
  for (const auto& [seed, camera, pattern] :
       {std::tuple{8, 0, 3}, std::tuple{7, 1, 3}, std::tuple{7, 0, 4}}) {
    SensorNoiseNormals(static_cast<uint64_t>(seed), camera, pattern, 1000, 4096, b.data());
    EXPECT_NEAR(Correlation(a.data(), b.data(), 4096), 0, 0.07)
        << seed << " " << camera << " " << pattern;
  }
}

TEST(SensorNoise, ImageFollowsEmvaModelAndRowsDoNotDependOnThreads) {
  Scene scene;
  scene.radiometry.adc_bits = 12;
  scene.layers.noise_enabled = true;
  scene.layers.full_well_e = 8000;
  scene.layers.read_noise_e = 12;
  scene.layers.seed = 3;
  // Widths not a multiple of 8: row tails.
  cv::Mat irradiance(301, 1003, CV_32FC1);
  for (int y = 0; y < irradiance.rows; ++y) {
    for (int x = 0; x < irradiance.cols; ++x)
      irradiance.at<float>(y, x) = 100.0f + 3.0f * static_cast<float>(x);
  }
  cv::Mat out;
  QuantizeIrradiance(irradiance, scene, 0, 5, &out);
  ASSERT_EQ(out.type(), CV_16UC1);
  const double k = 4095.0 / 8000;
  double sum = 0, sum_sq = 0;
  int n = 0;
  for (int y = 0; y < out.rows; ++y) {
    for (int x = 0; x < out.cols; ++x) {
      const double mu = irradiance.at<float>(y, x);
      if (mu > 3500) continue;
      const double z =
          (out.at<uint16_t>(y, x) - mu) / std::sqrt(k * k * (mu / k + 144.0) + 1.0 / 12);
      sum += z, sum_sq += z * z, ++n;
    }
  }
  const double mean = sum / n, sd = std::sqrt(sum_sq / n - mean * mean);
  EXPECT_NEAR(mean, 0, 0.01);
  EXPECT_NEAR(sd, 1, 0.01);
  // Pixel (x, y) takes the normal of index y * width + x, whatever thread renders its row.
  std::vector<float> normals(static_cast<size_t>(out.cols));
  int off_by_more = 0;
  for (int y = 0; y < out.rows; ++y) {
    SensorNoiseNormals(3, 0, 5, static_cast<uint64_t>(y) * static_cast<uint64_t>(out.cols),
                       out.cols, normals.data());
    for (int x = 0; x < out.cols; ++x) {
      const double mu_e = irradiance.at<float>(y, x) / k;
      const double e =
          std::min(mu_e + std::sqrt(mu_e + 144.0) * normals[static_cast<size_t>(x)], 8000.0);
      const double dn = std::clamp(std::round(e * k), 0.0, 4095.0);
      off_by_more +=
          std::abs(dn - out.at<uint16_t>(y, x)) > 1;  // float vs double rounding: at most 1 DN
    }
  }
  EXPECT_EQ(off_by_more, 0);
  cv::Mat again;
  QuantizeIrradiance(irradiance, scene, 0, 5, &again);
  EXPECT_EQ(cv::norm(out, again, cv::NORM_INF), 0);
}

// Rows of whole block pairs take the sixteen-lane path, rows of one block the eight-lane one:
// the same pixel indices give the same bits either way.
TEST(SensorNoise, BlockPairsAgreeWithSingleBlocks) {
  Scene scene;
  scene.layers.noise_enabled = true;
  scene.layers.seed = 11;
  cv::Mat wide(320, 1000, CV_32FC1);
  cv::randu(wide, cv::Scalar(-5), cv::Scalar(300));
  const cv::Mat narrow = wide.reshape(1, 20000);  // 16 pixels a row: one block
  cv::Mat a, b;
  QuantizeIrradiance(wide, scene, 1, 2, &a);
  QuantizeIrradiance(narrow, scene, 1, 2, &b);
  ASSERT_EQ(a.type(), CV_8UC1);
  EXPECT_EQ(cv::norm(a.reshape(1, 20000), b, cv::NORM_INF), 0);
}

TEST(SensorNoise, NoNoiseIsRoundingAndClipping) {
  Scene scene;
  scene.radiometry.adc_bits = 8;
  cv::Mat irradiance = (cv::Mat_<float>(1, 9) << -3.0f, std::nanf(""), 0.0f, 0.49f, 0.5f, 1.5f,
                        254.4f, 254.5f, 1e9f);
  cv::Mat out;
  QuantizeIrradiance(irradiance, scene, 0, 0, &out);
  ASSERT_EQ(out.type(), CV_8UC1);
  const uint8_t expected[9] = {0, 0, 0, 0, 1, 2, 254, 255, 255};
  for (int x = 0; x < 9; ++x) EXPECT_EQ(out.at<uint8_t>(0, x), expected[x]) << "at " << x;
}

}  // namespace
}  // namespace slshadow
