#include "compare/statistics.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>

#include "compare/internal/abs_buckets.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::compare {
namespace {

using internal::AbsBucket;
using internal::AbsValuesAtRanks;
using internal::kAbsBuckets;

// ComputeStats's figures of |d| (shared by the signed and unsigned figures), the signed mean and
// std, and the histograms asked for, from three passes over the distances: the sums in order (so
// the same doubles) and a count of the top 16 bits of |d|; the values of the (at most three)
// buckets holding the ranks of the median, p95 and p99, a selection among which gives each (the
// value a full sort puts at that rank); the deviations from the means (ComputeStats's two-pass
// standard deviations) and the histograms, whose range the 99th percentile sets.
struct AbsFigures {
  DistanceStats stats;  // its histogram unset, its signed figures NaN
  double signed_mean = 0, signed_std = 0;
  Histogram signed_histogram, unsigned_histogram;  // of d over [-hi, hi], of |d| over [0, hi]
};

AbsFigures ComputeAbsFigures(const std::vector<double>& distances_mm, double threshold_mm, int bins,
                             double range_mm, bool bin_signed, bool bin_unsigned) {
  SLSHADOW_THROW_IF(!(range_mm >= 0) || !std::isfinite(range_mm),
                    "colour range: must be finite and >= 0 (got ", range_mm, ")");
  SLSHADOW_THROW_IF(!(threshold_mm >= 0) || !std::isfinite(threshold_mm),
                    "threshold_mm: must be finite and >= 0 (got ", threshold_mm, ")");
  SLSHADOW_THROW_IF(bins < 1, "histogram bins: must be >= 1 (got ", bins, ")");
  AbsFigures out;
  DistanceStats& s = out.stats;
  s.threshold_mm = threshold_mm;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.signed_mean_mm = s.signed_std_mm = nan;
  out.signed_mean = out.signed_std = nan;
  std::vector<uint32_t> counts(kAbsBuckets, 0);
  double sum = 0, sum2 = 0, ssum = 0, max = 0;
  for (const double d : distances_mm) {
    if (!std::isfinite(d)) {
      ++s.num_invalid;
      continue;
    }
    const double a = std::abs(d);
    ++s.count;
    sum += a;
    sum2 += a * a;
    ssum += d;
    if (a <= threshold_mm) ++s.inliers;
    ++counts[AbsBucket(a)];
    max = std::max(max, a);
  }
  s.outliers = s.count - s.inliers;
  double hi = range_mm > 0 ? range_mm : std::max(threshold_mm, 1e-3);  // for no values
  if (s.count > 0) {
    const double n = static_cast<double>(s.count);
    s.mean_mm = sum / n;
    s.rms_mm = std::sqrt(sum2 / n);
    s.max_mm = max;
    const size_t ranks[3] = {PercentileRank(s.count, 50), PercentileRank(s.count, 95),
                             PercentileRank(s.count, 99)};
    double at[3];
    AbsValuesAtRanks(distances_mm.data(), distances_mm.data() + distances_mm.size(), counts, ranks,
                     3, at);
    s.median_mm = at[0];
    s.p95_mm = at[1];
    hi = range_mm > 0 ? range_mm : std::max(at[2], 1e-6);
  }
  Histogram &hs = out.signed_histogram, &hu = out.unsigned_histogram;
  hs.hi_mm = hu.hi_mm = hi;
  hs.lo_mm = -hi;
  hu.lo_mm = 0.0;
  if (bin_signed) hs.counts.assign(static_cast<size_t>(bins), 0);
  if (bin_unsigned) hu.counts.assign(static_cast<size_t>(bins), 0);
  if (s.count == 0) return out;
  // The deviations from the means, and the histograms.
  const double n = static_cast<double>(s.count);
  const double ws = hs.BinWidth(), wu = hu.BinWidth();
  const size_t last = static_cast<size_t>(bins) - 1;
  double var = 0, svar = 0;
  const double smean = ssum / n;
  for (const double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    const double a = std::abs(d);
    var += (a - s.mean_mm) * (a - s.mean_mm);
    svar += (d - smean) * (d - smean);
    if (bin_signed) {
      if (d < hs.lo_mm) {
        ++hs.underflow;
      } else if (d > hs.hi_mm) {
        ++hs.overflow;
      } else {
        ++hs.counts[std::min(static_cast<size_t>((d - hs.lo_mm) / ws), last)];
      }
    }
    if (bin_unsigned) {
      if (a > hu.hi_mm) {
        ++hu.overflow;
      } else {
        ++hu.counts[std::min(static_cast<size_t>((a - hu.lo_mm) / wu), last)];
      }
    }
  }
  s.std_mm = std::sqrt(var / n);
  out.signed_mean = smean;
  out.signed_std = std::sqrt(svar / n);
  return out;
}

}  // namespace

DistanceStats ComputeStats(const std::vector<double>& distances_mm, bool is_signed,
                           double threshold_mm, int bins, double range_mm) {
  AbsFigures f =
      ComputeAbsFigures(distances_mm, threshold_mm, bins, range_mm, is_signed, !is_signed);
  DistanceStats s = std::move(f.stats);
  s.is_signed = is_signed;
  s.histogram = std::move(is_signed ? f.signed_histogram : f.unsigned_histogram);
  if (is_signed && s.count > 0) {
    s.signed_mean_mm = f.signed_mean;
    s.signed_std_mm = f.signed_std;
  }
  return s;
}

UnsignedAndSigned ComputeUnsignedAndSignedStats(const std::vector<double>& distances_mm,
                                                double threshold_mm, int bins, double range_mm) {
  AbsFigures f = ComputeAbsFigures(distances_mm, threshold_mm, bins, range_mm, true, true);
  UnsignedAndSigned out;
  out.unsigned_stats = f.stats;
  out.unsigned_stats.histogram = std::move(f.unsigned_histogram);
  DistanceStats& s = out.signed_stats;
  s = std::move(f.stats);
  s.is_signed = true;
  s.histogram = std::move(f.signed_histogram);
  if (s.count > 0) {
    s.signed_mean_mm = f.signed_mean;
    s.signed_std_mm = f.signed_std;
  }
  return out;
}
double AbsPercentile(const double* first, const double* last, double p) {
  std::vector<uint32_t> counts(kAbsBuckets, 0);
  size_t count = 0;
  for (const double* d = first; d != last; ++d) {
    if (!std::isfinite(*d)) continue;
    ++counts[AbsBucket(std::abs(*d))];
    ++count;
  }
  if (count == 0) return std::numeric_limits<double>::quiet_NaN();
  const size_t rank = PercentileRank(count, p);
  double value = 0;
  AbsValuesAtRanks(first, last, counts, &rank, 1, &value);
  return value;
}

namespace internal {

void AbsValuesAtRanks(const double* first, const double* last, const std::vector<uint32_t>& counts,
                      const size_t* ranks, int num_ranks, double* out) {
  SLSHADOW_CHECK(counts.size() == kAbsBuckets);
  // The bucket of each rank (ranks ascend), and the rank within its bucket.
  std::vector<uint32_t> bucket(static_cast<size_t>(num_ranks));
  std::vector<size_t> within(static_cast<size_t>(num_ranks));
  size_t below = 0;
  uint32_t b = 0;
  for (size_t r = 0; r < bucket.size(); ++r) {
    while (below + counts[b] <= ranks[r]) below += counts[b++];
    bucket[r] = b;
    within[r] = ranks[r] - below;
  }
  // The values of each distinct bucket, in the first rank's list that has it.
  std::vector<std::vector<double>> values(bucket.size());
  for (size_t r = 0; r < bucket.size(); ++r) {
    if (r == 0 || bucket[r] != bucket[r - 1]) values[r].reserve(counts[bucket[r]]);
  }
  for (const double* d = first; d != last; ++d) {
    const double a = std::abs(*d);
    const uint32_t k = AbsBucket(a);  // non-finite: beyond every finite bucket
    for (size_t r = 0; r < bucket.size(); ++r) {
      if (k == bucket[r]) {
        values[r].push_back(a);
        break;
      }
    }
  }
  for (size_t r = 0; r < bucket.size(); ++r) {
    size_t v = r;
    while (v > 0 && bucket[v - 1] == bucket[r]) --v;  // the bucket's values are in values[v]
    std::vector<double>& x = values[v];
    const auto k = x.begin() + static_cast<std::ptrdiff_t>(within[r]);
    std::nth_element(x.begin(), k, x.end());
    out[r] = *k;
  }
}

}  // namespace internal
}  // namespace slshadow::compare
