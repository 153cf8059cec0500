// Summary statistics of per-point deviations.
//
// Definitions (docs/formats.md "Comparison report" repeats them):
//  - count: number of finite distances d_i (NaN entries are skipped and counted in num_invalid);
//  - mean, std (population, divisor n), rms, median, p95, max: of |d_i|; median and p95 by the
//    nearest-rank method on the sorted |d_i| (p-th percentile = element ceil(p/100 n) - 1);
//  - signed_mean / signed_std: of d_i when the distances are signed (NaN otherwise);
//  - inliers: |d_i| <= threshold, outliers: the others (outliers = count - inliers);
//  - histogram of d_i (signed) or |d_i| (unsigned) with `bins` equal bins over [lo, hi], where
//    hi = max(p99.9 of |d|, threshold) and lo = -hi (signed) or 0 (unsigned); values outside go
//    to underflow / overflow.
#pragma once

#include <cstddef>
#include <vector>

namespace slshadow::compare {

struct Histogram {
  double lo_mm = 0.0, hi_mm = 0.0;  // range of the bins
  std::vector<size_t> counts;       // equal-width bins over [lo, hi)
  size_t underflow = 0, overflow = 0;
  double BinWidth() const {
    return counts.empty() ? 0.0 : (hi_mm - lo_mm) / static_cast<double>(counts.size());
  }
};

struct DistanceStats {
  bool is_signed = false;
  size_t count = 0;
  size_t num_invalid = 0;
  double mean_mm = 0, std_mm = 0, rms_mm = 0, median_mm = 0, p95_mm = 0, max_mm = 0;
  double signed_mean_mm = 0, signed_std_mm = 0;  // NaN when !is_signed
  double threshold_mm = 0;
  size_t inliers = 0, outliers = 0;
  Histogram histogram;
};

// The histogram's range (also the colour range of the deviation map and of the PLY colours):
// range_mm > 0: [-range, range] (signed) or [0, range]; 0: scaled to the data, at the 99th
// percentile of |d| (1e-6 at least), so small deviations are not one flat colour; the values
// beyond fall in underflow / overflow, the threshold is marked where it falls in range.
// Three passes over the distances: the sums in order and a count of the top 16 bits of |d|, which
// finds the bucket holding each percentile's rank; the values of those buckets, a selection among
// which gives each percentile (the value a full sort gives); the deviations from the means and
// the histogram.
DistanceStats ComputeStats(const std::vector<double>& distances_mm, bool is_signed,
                           double threshold_mm, int bins = 60, double range_mm = 0);
// {ComputeStats(d, false, ...), ComputeStats(d, true, ...)}, equal field for field, from one pass
// over the distances and one set of percentile selections (what the two share: everything of
// |d|; the signed one adds the signed mean and std and bins d instead of |d|).
struct UnsignedAndSigned {
  DistanceStats unsigned_stats, signed_stats;
};
UnsignedAndSigned ComputeUnsignedAndSignedStats(const std::vector<double>& distances_mm,
                                                double threshold_mm, int bins = 60,
                                                double range_mm = 0);

// The nearest-rank p-th percentile (core/statistics.h) of |d| over the finite d of [first, last)
// (NaN for none): Percentile's value, by ComputeStats's buckets of magnitudes, without copying or
// reordering the values.
double AbsPercentile(const double* first, const double* last, double p);

}  // namespace slshadow::compare
