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

}  // namespace
}  // namespace slshadow
