#include "compare/statistics.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <random>

#include <gtest/gtest.h>

#include "compare/kdtree.h"
#include "core/error.h"

namespace slshadow::compare {
namespace {

TEST(ComputeStats, MatchesTheDefinitionsOnRandomData) {
  std::mt19937 rng(21);
  std::normal_distribution<double> g(0.02, 0.1);
  std::vector<double> d(10001);
  for (auto& v : d) v = g(rng);
  d[17] = std::numeric_limits<double>::quiet_NaN();
  const DistanceStats s = ComputeStats(d, /*is_signed=*/true, 0.25, 40);
  std::vector<double> a;
  double ssum = 0;
  for (double v : d)
    if (std::isfinite(v)) {
      a.push_back(std::abs(v));
      ssum += v;
    }
  std::sort(a.begin(), a.end());
  const double n = static_cast<double>(a.size());
  const double mean = std::accumulate(a.begin(), a.end(), 0.0) / n;
  double var = 0, sq = 0;
  for (double v : a) {
    var += (v - mean) * (v - mean);
    sq += v * v;
  }
  EXPECT_EQ(s.count, 10000u);
  EXPECT_EQ(s.num_invalid, 1u);
  EXPECT_NEAR(s.mean_mm, mean, 1e-12);
  EXPECT_NEAR(s.std_mm, std::sqrt(var / n), 1e-12);
  EXPECT_NEAR(s.rms_mm, std::sqrt(sq / n), 1e-12);
  EXPECT_EQ(s.median_mm, a[4999]);  // nearest rank: ceil(0.5 * 10000) - 1
  EXPECT_EQ(s.p95_mm, a[9499]);
  EXPECT_EQ(s.max_mm, a.back());
  EXPECT_NEAR(s.signed_mean_mm, ssum / n, 1e-12);
  const auto inl = static_cast<size_t>(std::count_if(a.begin(), a.end(), [](double v) { return v <= 0.25; }));
  EXPECT_EQ(s.inliers, inl);
  EXPECT_EQ(s.outliers, 10000u - inl);
  size_t total = s.histogram.underflow + s.histogram.overflow;
  for (size_t c : s.histogram.counts) total += c;
  EXPECT_EQ(total, s.count);
  EXPECT_EQ(s.histogram.counts.size(), 40u);
  EXPECT_DOUBLE_EQ(s.histogram.lo_mm, -s.histogram.hi_mm);
}

TEST(ComputeStats, UnsignedHasNoSignedMeanAndHandlesEmpty) {
  const DistanceStats s = ComputeStats({0.1, 0.3, 0.2}, false, 0.25);
  EXPECT_TRUE(std::isnan(s.signed_mean_mm));
  EXPECT_EQ(s.inliers, 2u);
  EXPECT_EQ(s.outliers, 1u);
  EXPECT_EQ(s.median_mm, 0.2);
  EXPECT_EQ(s.histogram.lo_mm, 0.0);
  const DistanceStats e = ComputeStats({}, false, 0.25);
  EXPECT_EQ(e.count, 0u);
  EXPECT_THROW(ComputeStats({1.0}, false, -1.0), Error);
}

TEST(Coverage, FractionOfReferenceSamplesReached) {
  std::vector<Eigen::Vector3d> ref, reached;
  for (int i = 0; i < 100; ++i)
    for (int j = 0; j < 50; ++j) {
      ref.emplace_back(i * 0.1, j * 0.1, 0);
      if (i < 30) reached.emplace_back(i * 0.1 + 0.01, j * 0.1, 0.02);  // covers 30 of 100 columns
    }
  const KdTree tree(reached);
  EXPECT_DOUBLE_EQ(Coverage(ref, tree, 0.05), 0.3);
  EXPECT_DOUBLE_EQ(Coverage(ref, tree, 0.001), 0.0);
}

}  // namespace
}  // namespace slshadow::compare
