// Summary statistics of per-point deviations, and the coverage of a reference surface.
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
#include <cstdint>
#include <cstring>
#include <vector>

#include <Eigen/Core>

namespace slshadow::compare {

class KdTree;

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

// Coverage of the reference surface: the fraction of `reference_samples` (points that sample
// the reference surface uniformly by area, or the reference cloud's own points) that have a
// point of `reached` (the compared points within the threshold of the reference) within
// `radius_mm`. In [0, 1]; 0 when there are no samples.
double Coverage(const std::vector<Eigen::Vector3d>& reference_samples, const KdTree& reached,
                double radius_mm);
// The same value from the reached points themselves, through a uniform grid of cell ~radius
// (no tree to build: cheaper on millions of reached points).
double Coverage(const std::vector<Eigen::Vector3d>& reference_samples,
                const std::vector<Eigen::Vector3d>& reached, double radius_mm);
// Coverage(*sample_sets[k], reached, radius_mm) for every k, bit for bit, from one grid over the
// reached points (built once instead of once per sample set).
std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& reached, double radius_mm);
// The same with the reached points given as flags over `points` (non-zero: reached), without
// copying them out.
std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& points,
                              const std::vector<uint8_t>& reached, double radius_mm);

// MedianSpacing(KdTree(points), max_samples) without the tree, the same double. A cloud whose
// array order follows space (a scan's cloud, in grid order): each sample's distance to its array
// neighbours bounds its nearest, hashed cells sized from those bounds list the samples searching
// them, and one pass over the points compares each with the samples searching its cell. Any
// other cloud (or one with a non-finite sample, or many isolated ones): a uniform grid from the
// bounding box answers the samples whose nearest other point lies within its cell, a tree only
// the others (compare/internal/median_spacing.h).
double MedianSpacing(const std::vector<Eigen::Vector3d>& points, size_t max_samples = 20000);

// Order statistics of magnitudes by buckets (ComputeStats's median, p95 and p99; the sweep's
// per-band p95): the bucket of |d| is its top 16 bits (sign 0, exponent, 4 bits of mantissa),
// which order magnitudes as their values; non-finite values fall beyond every finite bucket.
inline constexpr size_t kAbsBuckets = size_t{1} << 16;
inline uint32_t AbsBucket(double magnitude) {
  uint64_t bits = 0;
  std::memcpy(&bits, &magnitude, sizeof(bits));
  return static_cast<uint32_t>(bits >> 48);
}

// out[r] = the value of 0-based rank ranks[r] among the |d| of the finite d of [first, last),
// ascending (ranks ascending, each below that count), given counts[b] = how many of those |d|
// fall in bucket b (AbsBucket; kAbsBuckets entries): what a full sort puts there, selected among
// the values of the ranks' buckets only.
void AbsValuesAtRanks(const double* first, const double* last, const std::vector<uint32_t>& counts,
                      const size_t* ranks, int num_ranks, double* out);

}  // namespace slshadow::compare
