#include "compare/statistics.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iterator>
#include <limits>
#include <numeric>
#include <random>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "compare/coverage.h"
#include "compare/internal/median_spacing.h"
#include "compare/median_spacing.h"
#include "core/error.h"
#include "core/kdtree.h"
#include "tests/compare/test_shapes.h"

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
  const auto inl =
      static_cast<size_t>(std::count_if(a.begin(), a.end(), [](double v) { return v <= 0.25; }));
  EXPECT_EQ(s.inliers, inl);
  EXPECT_EQ(s.outliers, 10000u - inl);
  size_t total = s.histogram.underflow + s.histogram.overflow;
  for (size_t c : s.histogram.counts) total += c;
  EXPECT_EQ(total, s.count);
  EXPECT_EQ(s.histogram.counts.size(), 40u);
  EXPECT_DOUBLE_EQ(s.histogram.lo_mm, -s.histogram.hi_mm);
}

// Field for field, the doubles bit for bit (NaN where NaN).
void ExpectSameStats(const DistanceStats& a, const DistanceStats& b, const std::string& what) {
  const auto bits = [](double x) {
    uint64_t u = 0;
    std::memcpy(&u, &x, sizeof(u));
    return std::isnan(x) ? uint64_t{1} : u;
  };
  EXPECT_EQ(a.is_signed, b.is_signed) << what;
  EXPECT_EQ(a.count, b.count) << what;
  EXPECT_EQ(a.num_invalid, b.num_invalid) << what;
  const std::pair<double, double> pairs[] = {{a.mean_mm, b.mean_mm},
                                             {a.std_mm, b.std_mm},
                                             {a.rms_mm, b.rms_mm},
                                             {a.median_mm, b.median_mm},
                                             {a.p95_mm, b.p95_mm},
                                             {a.max_mm, b.max_mm},
                                             {a.signed_mean_mm, b.signed_mean_mm},
                                             {a.signed_std_mm, b.signed_std_mm},
                                             {a.threshold_mm, b.threshold_mm},
                                             {a.histogram.lo_mm, b.histogram.lo_mm},
                                             {a.histogram.hi_mm, b.histogram.hi_mm}};
  for (size_t k = 0; k < std::size(pairs); ++k) {
    EXPECT_EQ(bits(pairs[k].first), bits(pairs[k].second))
        << what << " field " << k << ": " << pairs[k].first << " " << pairs[k].second;
  }
  EXPECT_EQ(a.inliers, b.inliers) << what;
  EXPECT_EQ(a.outliers, b.outliers) << what;
  EXPECT_EQ(a.histogram.counts, b.histogram.counts) << what;
  EXPECT_EQ(a.histogram.underflow, b.histogram.underflow) << what;
  EXPECT_EQ(a.histogram.overflow, b.histogram.overflow) << what;
}

// Field for field (bit-exact doubles, NaN where NaN) the two ComputeStats calls it replaces.
TEST(ComputeUnsignedAndSignedStats, EqualsTheTwoSeparateCalls) {
  std::mt19937 rng(27);
  std::normal_distribution<double> g(0.1, 0.3);
  std::vector<double> d(20001);
  for (auto& v : d) v = g(rng);
  d[5] = std::numeric_limits<double>::quiet_NaN();
  d[6] = std::numeric_limits<double>::infinity();
  d[7] = 7.0;  // beyond the histogram range
  d[8] = -7.0;
  for (const double range : {0.0, 0.5}) {
    for (const auto& data : {d, std::vector<double>{}, std::vector<double>(3, NAN)}) {
      const UnsignedAndSigned both = ComputeUnsignedAndSignedStats(data, 0.2, 40, range);
      ExpectSameStats(both.unsigned_stats, ComputeStats(data, false, 0.2, 40, range), "unsigned");
      ExpectSameStats(both.signed_stats, ComputeStats(data, true, 0.2, 40, range), "signed");
    }
  }
}

// The oracle of ComputeStats: its definitions (compare/statistics.h) with the percentiles from a
// full sort, the sums in the order of the distances (as ComputeStats adds them, so the same
// doubles), the standard deviations by two passes.
DistanceStats SortedStats(const std::vector<double>& d, bool is_signed, double threshold, int bins,
                          double range) {
  DistanceStats s;
  s.is_signed = is_signed;
  s.threshold_mm = threshold;
  s.signed_mean_mm = s.signed_std_mm = std::numeric_limits<double>::quiet_NaN();
  std::vector<double> a;
  double sum = 0, sum2 = 0, ssum = 0;
  for (const double v : d) {
    if (!std::isfinite(v)) {
      ++s.num_invalid;
      continue;
    }
    a.push_back(std::abs(v));
    sum += std::abs(v);
    sum2 += std::abs(v) * std::abs(v);
    ssum += v;
    s.inliers += std::abs(v) <= threshold;
  }
  s.count = a.size();
  s.outliers = s.count - s.inliers;
  Histogram& h = s.histogram;
  h.counts.assign(static_cast<size_t>(bins), 0);
  if (a.empty()) {
    h.hi_mm = range > 0 ? range : std::max(threshold, 1e-3);
    h.lo_mm = is_signed ? -h.hi_mm : 0.0;
    return s;
  }
  const double n = static_cast<double>(a.size());
  s.mean_mm = sum / n;
  s.rms_mm = std::sqrt(sum2 / n);
  double var = 0, svar = 0;
  for (const double v : d) {
    if (!std::isfinite(v)) continue;
    var += (std::abs(v) - s.mean_mm) * (std::abs(v) - s.mean_mm);
    svar += (v - ssum / n) * (v - ssum / n);
  }
  s.std_mm = std::sqrt(var / n);
  if (is_signed) {
    s.signed_mean_mm = ssum / n;
    s.signed_std_mm = std::sqrt(svar / n);
  }
  std::sort(a.begin(), a.end());
  const auto rank = [&](double p) {  // nearest rank: element ceil(p/100 n) - 1
    return a[static_cast<size_t>(std::clamp(std::ceil(p / 100.0 * n), 1.0, n)) - 1];
  };
  s.median_mm = rank(50);
  s.p95_mm = rank(95);
  s.max_mm = a.back();
  h.hi_mm = range > 0 ? range : std::max(rank(99), 1e-6);
  h.lo_mm = is_signed ? -h.hi_mm : 0.0;
  const double w = (h.hi_mm - h.lo_mm) / bins;
  for (const double v : d) {
    if (!std::isfinite(v)) continue;
    const double x = is_signed ? v : std::abs(v);
    if (x < h.lo_mm) {
      ++h.underflow;
    } else if (x > h.hi_mm) {
      ++h.overflow;
    } else {
      ++h.counts[std::min(static_cast<size_t>((x - h.lo_mm) / w), h.counts.size() - 1)];
    }
  }
  return s;
}

// ComputeStats (and ComputeUnsignedAndSignedStats) against the sorting oracle: noisy deviations
// of several scales and sizes, with many ties, zeros of both signs, NaN and infinities; values
// spanning the whole double range (denormals to the largest), values all in one radix bucket,
// all equal, one value, none, only NaN.
TEST(ComputeStats, EqualsTheSortingOracle) {
  std::mt19937 rng(5);
  std::normal_distribution<double> normal(0, 1);
  std::vector<std::vector<double>> sets;
  for (const size_t n : {size_t{1}, size_t{2}, size_t{19}, size_t{1000}, size_t{300001}}) {
    std::vector<double> d(n);
    for (double& v : d) v = 0.03 * normal(rng) * (normal(rng) > 2 ? 40 : 1);
    sets.push_back(d);
    for (size_t i = 0; i < n; i += 3) d[i] = std::round(d[i] * 100) / 100;  // many ties
    if (n > 2) {
      d[1] = -0.0;
      d[2] = 0.0;
    }
    sets.push_back(d);
    if (n > 2) {
      d[0] = std::numeric_limits<double>::quiet_NaN();
      d[n - 1] = -std::numeric_limits<double>::infinity();
      d[n / 2] = std::numeric_limits<double>::infinity();
    }
    sets.push_back(d);
  }
  std::vector<double> wide;
  for (int i = 0; i < 20000; ++i) {
    wide.push_back((i % 2 ? -1 : 1) * std::ldexp(1.0 + std::abs(normal(rng)), i % 2046 - 1074));
  }
  wide.push_back(std::numeric_limits<double>::max());
  wide.push_back(-std::numeric_limits<double>::denorm_min());
  sets.push_back(wide);
  std::vector<double> one_bucket;  // the same top 16 bits: the selection does all the work
  for (int i = 0; i < 30000; ++i) one_bucket.push_back(1.0 + 1e-9 * (i * 7919 % 30000));
  sets.push_back(one_bucket);
  sets.push_back(std::vector<double>(5000, 0.25));
  sets.push_back(std::vector<double>(5000, -0.0));
  sets.push_back({0.7});
  sets.push_back({});
  sets.push_back({std::numeric_limits<double>::quiet_NaN()});
  for (size_t k = 0; k < sets.size(); ++k) {
    for (const double threshold : {0.0, 0.05, 0.5}) {
      for (const double range : {0.0, 0.3}) {
        for (const int bins : {1, 60}) {
          const std::string what = "set " + std::to_string(k) + " threshold " +
                                   std::to_string(threshold) + " range " + std::to_string(range) +
                                   " bins " + std::to_string(bins);
          const DistanceStats u = SortedStats(sets[k], false, threshold, bins, range);
          const DistanceStats s = SortedStats(sets[k], true, threshold, bins, range);
          ExpectSameStats(ComputeStats(sets[k], false, threshold, bins, range), u, what);
          ExpectSameStats(ComputeStats(sets[k], true, threshold, bins, range), s, what);
          const UnsignedAndSigned both =
              ComputeUnsignedAndSignedStats(sets[k], threshold, bins, range);
          ExpectSameStats(both.unsigned_stats, u, what + " (both)");
          ExpectSameStats(both.signed_stats, s, what + " (both)");
        }
      }
    }
  }
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

TEST(ComputeStats, PercentilesEqualTheSortedNearestRanks) {
  std::mt19937 rng(22);
  std::exponential_distribution<double> e(10.0);
  for (const size_t n : {1u, 2u, 3u, 999u, 1000u, 4097u}) {
    std::vector<double> d(n);
    for (auto& v : d) v = e(rng);
    const DistanceStats s = ComputeStats(d, false, 0.1);
    std::vector<double> sorted = d;
    std::sort(sorted.begin(), sorted.end());
    const auto rank = [&](double p) {
      return sorted[static_cast<size_t>(std::clamp(std::ceil(p / 100.0 * static_cast<double>(n)),
                                                   1.0, static_cast<double>(n))) -
                    1];
    };
    EXPECT_EQ(s.median_mm, rank(50)) << n;
    EXPECT_EQ(s.p95_mm, rank(95)) << n;
    EXPECT_EQ(s.max_mm, sorted.back()) << n;
    EXPECT_EQ(s.histogram.hi_mm, std::max(rank(99), 1e-6))
        << n;  // scaled to the data, not to the threshold
    const DistanceStats fixed = ComputeStats(d, false, 0.1, 60, 0.25);
    EXPECT_EQ(fixed.histogram.hi_mm, 0.25) << n;
    size_t binned = fixed.histogram.overflow;
    for (size_t c : fixed.histogram.counts) binned += c;
    EXPECT_EQ(binned, n);  // every value in a bin or beyond the fixed range
  }
  EXPECT_THROW(ComputeStats({1.0}, false, 0.1, 60, -1.0), Error);
}

// The grid overload against the tree overload (itself checked above) and a brute-force count,
// on a noisy surface with a hole, duplicates, and radii from below the spacing to wide.
TEST(Coverage, GridEqualsTreeAndBruteForce) {
  std::mt19937 rng(23);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::normal_distribution<double> g(0.0, 0.02);
  std::vector<Eigen::Vector3d> ref, reached;
  for (int i = 0; i < 3000; ++i) ref.emplace_back(u(rng), u(rng), std::sin(u(rng)));
  for (int i = 0; i < 20000; ++i) {
    const Eigen::Vector3d p(u(rng), u(rng), g(rng));
    if ((p.head<2>() - Eigen::Vector2d(5, 5)).norm() > 2) reached.push_back(p);
  }
  reached.push_back(reached.front());
  const KdTree tree(reached);
  for (const double r : {0.0, 0.01, 0.05, 0.3, 1.5, 40.0}) {
    size_t brute = 0;
    const double b = std::nextafter(r, 1e300) * std::nextafter(r, 1e300);
    for (const auto& q : ref) {
      bool hit = false;
      for (const auto& p : reached) hit = hit || (q - p).squaredNorm() < b;
      brute += hit;
    }
    const double expected = static_cast<double>(brute) / static_cast<double>(ref.size());
    EXPECT_EQ(Coverage(ref, reached, r), expected) << r;
    EXPECT_EQ(Coverage(ref, tree, r), expected) << r;
  }
  EXPECT_EQ(Coverage(ref, std::vector<Eigen::Vector3d>{}, 1.0), 0.0);
}

// Several sample sets from one grid: each the value Coverage gives it alone.
TEST(Coverage, SeveralSampleSetsEqualEachAlone) {
  std::mt19937 rng(25);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::vector<Eigen::Vector3d> a, b, reached;
  const std::vector<Eigen::Vector3d> empty;
  for (int i = 0; i < 2000; ++i) a.emplace_back(u(rng), u(rng), 0.05 * u(rng));
  for (int i = 0; i < 500; ++i) b.emplace_back(u(rng), 0.5 * u(rng), 0.0);
  for (int i = 0; i < 8000; ++i) {
    const Eigen::Vector3d p(u(rng), u(rng), 0.02 * u(rng));
    if (p.x() > 3) reached.push_back(p);
  }
  for (const double r : {0.0, 0.02, 0.1, 0.7, 40.0}) {
    const std::vector<double> all = Coverages({&a, &empty, &b}, reached, r);
    ASSERT_EQ(all.size(), 3u);
    EXPECT_EQ(all[0], Coverage(a, reached, r)) << r;
    EXPECT_EQ(all[1], 0.0);
    EXPECT_EQ(all[2], Coverage(b, reached, r)) << r;
    if (r >= 0.7) {
      EXPECT_GT(all[0], 0.5) << r;  // the test is not vacuous: 70 % of `a` lies by the inliers
    }
  }
  EXPECT_EQ(Coverages({&a, &b}, empty, 1.0), (std::vector<double>{0.0, 0.0}));
  EXPECT_TRUE(Coverages({}, reached, 1.0).empty());
}

// Reached points given as flags over a cloud: the same values as the flagged points copied out
// (the tree for bit-exactness, the grid overload on the copy), and nothing flagged covers nothing.
TEST(Coverage, FlaggedPointsEqualTheCopiedSubset) {
  std::mt19937 rng(26);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  std::vector<Eigen::Vector3d> a, cloud, subset;
  for (int i = 0; i < 2000; ++i) a.emplace_back(u(rng), u(rng), 0.05 * u(rng));
  std::vector<uint8_t> flags;
  for (int i = 0; i < 9000; ++i) {
    cloud.emplace_back(u(rng), u(rng), 0.02 * u(rng));
    // Flagged: right of x = 3; the unflagged ones (left, and a far block) must not count.
    flags.push_back(cloud.back().x() > 3 ? 1 : 0);
    if (flags.back()) subset.push_back(cloud.back());
  }
  for (int i = 0; i < 500; ++i) {
    cloud.emplace_back(u(rng) - 20, u(rng), 0.0);
    flags.push_back(0);
  }
  const KdTree tree(subset);
  for (const double r : {0.0, 0.02, 0.1, 0.7, 40.0}) {
    const std::vector<double> flagged = Coverages({&a}, cloud, flags, r);
    ASSERT_EQ(flagged.size(), 1u);
    EXPECT_EQ(flagged[0], Coverage(a, tree, r)) << r;
    EXPECT_EQ(flagged[0], Coverages({&a}, subset, r)[0]) << r;
  }
  EXPECT_GT(Coverages({&a}, cloud, flags, 0.7)[0], 0.5);
  EXPECT_LT(Coverages({&a}, cloud, flags, 0.7)[0], 0.9);  // the left 30 % of `a` is not reached
  EXPECT_EQ(Coverages({&a}, cloud, std::vector<uint8_t>(cloud.size(), 0), 5.0)[0], 0.0);
  EXPECT_THROW(Coverages({&a}, cloud, std::vector<uint8_t>(3, 1), 1.0), Error);
}

TEST(MedianSpacing, GridEqualsTree) {
  std::mt19937 rng(24);
  std::uniform_real_distribution<double> u(0.0, 10.0);
  // A dense surface, a sparse volume (many samples fall back to the tree), a line with
  // duplicates, a flat plane, and a single point.
  std::vector<std::vector<Eigen::Vector3d>> clouds(6);
  for (int i = 0; i < 50000; ++i) clouds[0].emplace_back(u(rng), u(rng), 0.1 * std::sin(u(rng)));
  for (int i = 0; i < 200; ++i) clouds[1].emplace_back(u(rng), u(rng), u(rng));
  for (int i = 0; i < 1000; ++i) clouds[2].emplace_back(0.5 * (i / 2), 0, 0);
  for (int i = 0; i < 3000; ++i) clouds[3].emplace_back(u(rng), u(rng), 1.0);
  clouds[4].emplace_back(1, 2, 3);
  // A dense surface with far outliers every 50th point (samples the one-cell grid around the
  // samples cannot settle).
  for (int i = 0; i < 20000; ++i) {
    clouds[5].emplace_back(u(rng), u(rng), i % 50 == 0 ? 5 + u(rng) : 0.01 * u(rng));
  }
  // A jittered 3D lattice (spacing 1 mm, 12^3 points): every sample's nearest point lies beyond
  // the grid's cell (sized for a surface), within 8 cells: all are settled by the wider grid.
  clouds.emplace_back();
  for (int i = 0; i < 12 * 12 * 12; ++i) {
    clouds.back().emplace_back(i % 12 + 0.1 * u(rng), (i / 12) % 12 + 0.1 * u(rng),
                               i / 144 + 0.1 * u(rng));
  }
  for (const auto& c : clouds) {
    const KdTree tree(c);
    for (const size_t samples : {size_t{20000}, size_t{100}}) {
      EXPECT_EQ(MedianSpacing(c, samples), MedianSpacing(tree, samples))
          << c.size() << " " << samples;
    }
  }
}

// The brute-force median spacing: every stride-th point's nearest other finite point, the
// squared distance as (p - q).squaredNorm(); all samples must be finite.
double BruteForceSpacing(const std::vector<Eigen::Vector3d>& pts, size_t max_samples) {
  if (pts.size() < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, pts.size() / std::max<size_t>(1, max_samples));
  std::vector<double> d;
  for (size_t i = 0; i < pts.size(); i += stride) {
    double best = std::numeric_limits<double>::infinity();
    for (size_t j = 0; j < pts.size(); ++j) {
      if (j != i && pts[j].allFinite()) best = std::min(best, (pts[i] - pts[j]).squaredNorm());
    }
    d.push_back(std::sqrt(best));
  }
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

// Whether MedianSpacing answers `pts` by its scan-order grid (else by MedianSpacingByCells).
bool ScanOrder(const std::vector<Eigen::Vector3d>& pts, size_t max_samples) {
  const size_t stride = std::max<size_t>(1, pts.size() / std::max<size_t>(1, max_samples));
  std::vector<double> d((pts.size() + stride - 1) / stride);
  return internal::ScanOrderSpacings(pts, stride, &d);
}

// MedianSpacing, double for double, against the method it had before the scan-order grid
// (MedianSpacingByCells, itself checked against the tree above) and against a brute force or the
// tree: on clouds in scan order as a reconstruction's (where the scan-order grid answers), the
// same shuffled, with NaN and infinite points (unsampled: skipped; sampled: the general method),
// duplicates, samples far from their array neighbours but near other points, isolated samples
// far from everything (up to 16: compared with every point, beyond the general method's grids:
// its tree's distance, the same double; more, or with a non-finite point in the cloud: the general
// method), all points equal, far from the origin, and fewer than 2 points.
TEST(MedianSpacing, ScanOrderGridEqualsTheGeneralMethodAndTheOracles) {
  struct Case {
    std::string name;
    std::vector<Eigen::Vector3d> points;
    bool scan_order;  // expected to be answered by the scan-order grid (max_samples 2000)
    bool finite;      // the brute force (and the tree) are oracles
  };
  std::vector<Case> cases;
  const std::vector<Eigen::Vector3d> scan = testing::ScanOrderCloud(320, 200, 0.15, 31);
  ASSERT_GT(scan.size(), 50000u);
  cases.push_back({"scan", scan, true, true});
  std::mt19937 rng(32);
  {
    std::vector<Eigen::Vector3d> c = scan;
    std::shuffle(c.begin(), c.end(), rng);
    cases.push_back({"shuffled", c, false, true});
  }
  const size_t stride = scan.size() / 2000;  // the samples at max_samples 2000
  {
    std::vector<Eigen::Vector3d> c = scan;
    const double nan = std::numeric_limits<double>::quiet_NaN();
    const double inf = std::numeric_limits<double>::infinity();
    for (size_t k = 0; k < 40; ++k) {  // beside samples: never a sample
      c[(k * 997 % 1900 + 1) * stride + 1] = k % 3 == 0   ? Eigen::Vector3d(nan, 0, 0)
                                             : k % 3 == 1 ? Eigen::Vector3d(0, inf, 0)
                                                          : Eigen::Vector3d(1, 2, -inf);
    }
    cases.push_back({"non-finite unsampled", c, true, false});
    c[7 * stride].z() = nan;
    cases.push_back({"non-finite sample", c, false, false});
  }
  {
    std::vector<Eigen::Vector3d> c = scan;
    for (size_t i = 0; i + 1 < c.size(); i += 7) c[i + 1] = c[i];           // array neighbours
    for (size_t i = 0; i + 5000 < c.size(); i += 1013) c[i] = c[i + 5000];  // far in the array
    cases.push_back({"duplicates", c, true, true});
  }
  for (const size_t swaps : {size_t{10}, size_t{30}}) {
    // Samples swapped with points elsewhere: far from their array neighbours, near others.
    std::vector<Eigen::Vector3d> c = scan;
    for (size_t k = 0; k < swaps; ++k) {
      std::swap(c[(k * 61 + 5) * stride], c[(k * 61 + 905) % 1990 * stride + stride / 2]);
    }
    cases.push_back({"far samples " + std::to_string(swaps), c, true, true});
  }
  {
    std::vector<Eigen::Vector3d> c = scan;
    for (size_t k = 1; k <= 5; ++k) c[k * 300 * stride].z() += 40.0 + static_cast<double>(k);
    cases.push_back({"isolated", c, true, true});
    c[3 * stride + 2].y() = std::numeric_limits<double>::quiet_NaN();  // the general method's tree
    cases.push_back({"isolated and non-finite", c, false, false});
    c = scan;
    for (size_t k = 1; k <= 20; ++k) c[k * 90 * stride].z() += 40.0 + 5.0 * static_cast<double>(k);
    cases.push_back({"isolated 20", c, false, true});
  }
  {
    std::vector<Eigen::Vector3d> c = scan;
    for (auto& p : c) p += Eigen::Vector3d(1e6, -2e5, 1e5);  // cells beyond the hash's range
    cases.push_back({"far from the origin", c, false, true});
  }
  {
    std::vector<Eigen::Vector3d> line, plane;
    for (int i = 0; i < 3000; ++i) line.emplace_back(0.5 * i, 0, 0);
    for (int i = 0; i < 4000; ++i) plane.emplace_back(0.2 * (i % 80), 0.2 * (i / 80), 1.0);
    cases.push_back({"line", line, true, true});
    cases.push_back({"plane", plane, true, true});
  }
  cases.push_back(
      {"equal", std::vector<Eigen::Vector3d>(500, Eigen::Vector3d(1, 2, 3)), false, true});
  cases.push_back({"two", {{0, 0, 0}, {1, 2, 3}}, true, true});
  cases.push_back({"one", {{1, 2, 3}}, false, true});
  cases.push_back({"none", {}, false, true});
  for (const Case& c : cases) {
    for (const size_t samples : {size_t{2000}, size_t{20000}, size_t{7}, size_t{0}}) {
      const std::string what = c.name + " samples " + std::to_string(samples);
      const double got = MedianSpacing(c.points, samples);
      EXPECT_EQ(got, internal::MedianSpacingByCells(c.points, samples)) << what;
      if (c.finite) {
        if (samples <= 2000) {
          EXPECT_EQ(got, BruteForceSpacing(c.points, samples)) << what;
        } else {
          const KdTree tree(c.points);
          EXPECT_EQ(got, MedianSpacing(tree, samples)) << what;
        }
      }
      if (samples == 2000) {
        EXPECT_EQ(ScanOrder(c.points, samples), c.scan_order) << what;
      }
    }
  }
  EXPECT_NEAR(MedianSpacing(scan), 0.15, 0.03);  // the pixel pitch at the table
  EXPECT_EQ(MedianSpacing(cases.back().points), 0.0);
}

// A reconstruction-sized cloud (1920 x 1200 pixels, ~2.1 M points): the scan-order grid answers
// it, and gives the tree's value.
TEST(MedianSpacing, ScanOrderGridOnAReconstructionSizedCloud) {
  const std::vector<Eigen::Vector3d> scan = testing::ScanOrderCloud(1920, 1200, 0.12, 33);
  ASSERT_GT(scan.size(), 2000000u);
  EXPECT_TRUE(ScanOrder(scan, 20000));
  const KdTree tree(scan);
  EXPECT_EQ(MedianSpacing(scan), MedianSpacing(tree));
}

TEST(MedianSpacing, OfATreeOverAGrid) {
  std::vector<Eigen::Vector3d> grid;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 30; ++j) grid.emplace_back(0.5 * i, 0.5 * j, 0.0);
  const KdTree tree(grid);
  EXPECT_DOUBLE_EQ(MedianSpacing(tree), 0.5);
}

}  // namespace
}  // namespace slshadow::compare
