// The shadow report's statistics (workflows/twin/internal/twin_stats.h) against a brute force:
// sorted copies and the nearest-rank convention of core/statistics.h, float and double alike.
#include "workflows/twin/internal/twin_stats.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <gtest/gtest.h>

namespace slshadow::twin::internal {
namespace {

// The 1-based nearest rank ceil(p n / 100), as an index into the sorted values.
size_t NearestRankIndex(size_t n, int p) { return std::max<size_t>(1, (p * n + 99) / 100) - 1; }

TEST(SampleStats, NearestRankFiguresOfTheFiniteValues) {
  std::mt19937 rng(5);
  std::normal_distribution<float> normal(0.3f, 2.0f);
  // Even and odd counts, counts whose 95 % is a whole number (20, 2000), ties (rounded values).
  for (const size_t n :
       {size_t{1}, size_t{2}, size_t{20}, size_t{21}, size_t{2000}, size_t{4097}}) {
    for (const bool ties : {false, true}) {
      std::vector<float> v(n);
      for (float& x : v) x = ties ? std::round(normal(rng)) : normal(rng);
      std::vector<float> with_bad = v;
      with_bad.push_back(std::numeric_limits<float>::quiet_NaN());
      with_bad.push_back(std::numeric_limits<float>::infinity());
      with_bad.insert(with_bad.begin(), -std::numeric_limits<float>::infinity());

      std::vector<float> sorted = v, mags(v.size());
      std::sort(sorted.begin(), sorted.end());
      std::transform(v.begin(), v.end(), mags.begin(), [](float x) { return std::abs(x); });
      std::sort(mags.begin(), mags.end());
      double sum = 0, ss = 0;
      for (const float x : v) sum += x, ss += static_cast<double>(x) * x;

      const SampleStats f = ComputeSampleStats(with_bad);
      const SampleStats d =
          ComputeSampleStats(std::vector<double>(with_bad.begin(), with_bad.end()));
      for (const SampleStats* s : {&f, &d}) {
        EXPECT_EQ(s->count, static_cast<int64_t>(n));
        EXPECT_EQ(s->median, sorted[NearestRankIndex(n, 50)]) << n << " ties " << ties;
        EXPECT_EQ(s->p95_abs, mags[NearestRankIndex(n, 95)]) << n << " ties " << ties;
        EXPECT_EQ(s->max_abs, mags.back());
        EXPECT_DOUBLE_EQ(s->mean, sum / static_cast<double>(n));
        EXPECT_DOUBLE_EQ(s->rms, std::sqrt(ss / static_cast<double>(n)));
      }
      EXPECT_EQ(f.ToJson("px").dump(), d.ToJson("px").dump());  // a zero median is +0 in both
    }
  }
  // The lower middle value for an even count; rank 19 of 20 for the 95th percentile.
  std::vector<float> twenty(20);
  for (int i = 0; i < 20; ++i) twenty[static_cast<size_t>(i)] = static_cast<float>(i + 1);
  const SampleStats s = ComputeSampleStats(twenty);
  EXPECT_EQ(s.median, 10.0);
  EXPECT_EQ(s.p95_abs, 19.0);
  // Nothing finite: zeros.
  const SampleStats none = ComputeSampleStats(std::vector<float>{NAN, INFINITY});
  EXPECT_EQ(none.count, 0);
  EXPECT_EQ(none.median, 0.0);
  const nlohmann::json j = s.ToJson("mm");
  EXPECT_EQ(j.at("p95_abs_mm").get<double>(), 19.0);
  EXPECT_EQ(j.size(), 7u);
}

}  // namespace
}  // namespace slshadow::twin::internal
