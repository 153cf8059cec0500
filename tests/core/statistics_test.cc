#include "core/statistics.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

namespace slshadow {
namespace {

// Against the definition on sorted values: rank ceil(p n / 100), 1-based, at least 1.
TEST(Statistics, NearestRankPercentileMatchesTheDefinitionOnSortedValues) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-5, 5);
  for (size_t n : {1u, 2u, 3u, 4u, 10u, 19u, 20u, 21u, 100u, 1001u}) {
    std::vector<double> v(n);
    for (auto& x : v) x = u(rng);
    std::vector<double> sorted = v;
    std::sort(sorted.begin(), sorted.end());
    for (double p : {0.0, 1.0, 25.0, 50.0, 90.0, 95.0, 99.0, 99.9, 100.0}) {
      const double want = sorted[static_cast<size_t>(std::max(1.0, std::ceil(p / 100 * n))) - 1];
      std::vector<double> work = v;
      EXPECT_EQ(Percentile(work, p), want) << "n " << n << " p " << p;
    }
  }
}

TEST(Statistics, MedianIsTheLowerMiddleValueAndEdgeCases) {
  std::vector<double> even = {4, 1, 3, 2};
  EXPECT_EQ(Median(even), 2.0);
  std::vector<float> odd = {5, 1, 3};
  EXPECT_EQ(Median(odd), 3.0f);
  std::vector<double> one = {7};
  EXPECT_EQ(Percentile(one, 95), 7.0);
  std::vector<double> none;
  EXPECT_TRUE(std::isnan(Median(none)));
  EXPECT_EQ(PercentileRank(20, 95), 18u);  // the 19th of 20
  EXPECT_EQ(PercentileRank(20, 50), 9u);   // the 10th of 20
  EXPECT_EQ(PercentileRank(1, 0), 0u);
  std::vector<double> ties = {1, 1, 1, 2};
  EXPECT_EQ(Percentile(ties, 75), 1.0);
  EXPECT_EQ(Percentile(ties, 76), 2.0);
}

// Summarize against a sorted copy and long-double sums, floats and doubles, both signs, zeros of
// both signs, ties and non-finite values: the same figures from either type.
TEST(Statistics, SummarizeMatchesTheDefinitions) {
  std::mt19937 rng(11);
  std::uniform_int_distribution<int> level(-40, 200);
  for (size_t n : {1u, 2u, 3u, 7u, 1000u, 100001u}) {
    std::vector<float> f(n);
    for (float& x : f) x = static_cast<float>(level(rng)) * 0.0625f;
    if (n > 3) f[1] = -0.0f, f[2] = std::nanf(""), f[3] = INFINITY;
    std::vector<double> finite, magnitude;
    for (float x : f) {
      if (std::isfinite(x)) finite.push_back(x), magnitude.push_back(std::abs(x));
    }
    std::sort(finite.begin(), finite.end());
    std::sort(magnitude.begin(), magnitude.end());
    long double sum = 0, ss = 0;
    for (double x : finite) sum += x, ss += static_cast<long double>(x) * x;
    const long double mean = sum / finite.size();
    long double dev = 0;
    for (double x : finite) dev += (x - mean) * (x - mean);
    const size_t m = finite.size();
    const Summary a = Summarize(f);
    const Summary b = Summarize(std::vector<double>(f.begin(), f.end()));
    for (const Summary& s : {a, b}) {
      EXPECT_EQ(s.count, static_cast<int64_t>(m)) << n;
      EXPECT_EQ(s.median, finite[PercentileRank(m, 50)]) << n;
      EXPECT_EQ(s.p95, finite[PercentileRank(m, 95)]) << n;
      EXPECT_EQ(s.max, finite.back()) << n;
      EXPECT_EQ(s.p95_abs, magnitude[PercentileRank(m, 95)]) << n;
      EXPECT_EQ(s.max_abs, magnitude.back()) << n;
      EXPECT_NEAR(s.mean, static_cast<double>(mean), 1e-9) << n;
      EXPECT_NEAR(s.rms, std::sqrt(static_cast<double>(ss / m)), 1e-9) << n;
      EXPECT_NEAR(s.stddev, std::sqrt(static_cast<double>(dev / m)), 1e-9) << n;
      if (s.median == 0) {
        EXPECT_FALSE(std::signbit(s.median)) << n;  // a zero median is +0
      }
    }
  }
  EXPECT_EQ(Summarize(std::vector<float>{NAN, INFINITY}).count, 0);
  EXPECT_EQ(Summarize(std::vector<double>{}).stddev, 0.0);
}

// The standard deviation from the deviations, not from ss/n - mean^2: values 1e8 + {0, 1, 2}
// (whose squares lose the unit digit in double) keep their spread sqrt(2/3).
TEST(Statistics, SummarizeStandardDeviationHasNoCancellation) {
  const Summary s = Summarize(std::vector<double>{1e8, 1e8 + 1, 1e8 + 2});
  EXPECT_NEAR(s.stddev, std::sqrt(2.0 / 3.0), 1e-12);
  EXPECT_EQ(s.mean, 1e8 + 1);
}

}  // namespace
}  // namespace slshadow
