#include "compare/statistics.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include "compare/kdtree.h"
#include "core/error.h"

namespace slshadow::compare {
namespace {

// Nearest-rank percentile of sorted values.
double Percentile(const std::vector<double>& sorted, double p) {
  if (sorted.empty()) return 0.0;
  const double rank = std::ceil(p / 100.0 * static_cast<double>(sorted.size()));
  const size_t idx = static_cast<size_t>(std::clamp(rank, 1.0, static_cast<double>(sorted.size()))) - 1;
  return sorted[idx];
}

}  // namespace

DistanceStats ComputeStats(const std::vector<double>& distances_mm, bool is_signed,
                           double threshold_mm, int bins) {
  SLSHADOW_THROW_IF(!(threshold_mm >= 0) || !std::isfinite(threshold_mm),
                    "threshold_mm: must be finite and >= 0 (got ", threshold_mm, ")");
  SLSHADOW_THROW_IF(bins < 1, "histogram bins: must be >= 1 (got ", bins, ")");
  DistanceStats s;
  s.is_signed = is_signed;
  s.threshold_mm = threshold_mm;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s.signed_mean_mm = s.signed_std_mm = nan;
  std::vector<double> abs_d;
  abs_d.reserve(distances_mm.size());
  double sum = 0, sum2 = 0, ssum = 0;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) {
      ++s.num_invalid;
      continue;
    }
    const double a = std::abs(d);
    abs_d.push_back(a);
    sum += a;
    sum2 += a * a;
    ssum += d;
    if (a <= threshold_mm) ++s.inliers;
  }
  s.count = abs_d.size();
  s.outliers = s.count - s.inliers;
  if (s.count == 0) {
    s.histogram.counts.assign(static_cast<size_t>(bins), 0);
    s.histogram.hi_mm = std::max(threshold_mm, 1e-3);
    s.histogram.lo_mm = is_signed ? -s.histogram.hi_mm : 0.0;
    return s;
  }
  const double n = static_cast<double>(s.count);
  s.mean_mm = sum / n;
  s.rms_mm = std::sqrt(sum2 / n);
  // Two-pass for the standard deviations (numerically safe).
  double var = 0, svar = 0;
  const double smean = ssum / n;
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    var += (std::abs(d) - s.mean_mm) * (std::abs(d) - s.mean_mm);
    svar += (d - smean) * (d - smean);
  }
  s.std_mm = std::sqrt(var / n);
  if (is_signed) {
    s.signed_mean_mm = smean;
    s.signed_std_mm = std::sqrt(svar / n);
  }
  std::sort(abs_d.begin(), abs_d.end());
  s.median_mm = Percentile(abs_d, 50);
  s.p95_mm = Percentile(abs_d, 95);
  s.max_mm = abs_d.back();
  Histogram& h = s.histogram;
  h.hi_mm = std::max({Percentile(abs_d, 99.9), threshold_mm, 1e-6});
  h.lo_mm = is_signed ? -h.hi_mm : 0.0;
  h.counts.assign(static_cast<size_t>(bins), 0);
  const double w = h.BinWidth();
  for (double d : distances_mm) {
    if (!std::isfinite(d)) continue;
    const double v = is_signed ? d : std::abs(d);
    if (v < h.lo_mm) {
      ++h.underflow;
    } else if (v > h.hi_mm) {
      ++h.overflow;
    } else {
      const auto b = std::min(static_cast<size_t>((v - h.lo_mm) / w), h.counts.size() - 1);
      ++h.counts[b];
    }
  }
  return s;
}

double Coverage(const std::vector<Eigen::Vector3d>& reference_samples, const KdTree& reached,
                double radius_mm) {
  if (reference_samples.empty() || reached.size() == 0) return 0.0;
  const std::vector<uint32_t> order = SpatialOrder(reference_samples);
  const size_t covered = tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, reference_samples.size(), 2048), size_t{0},
      [&](const tbb::blocked_range<size_t>& r, size_t acc) {
        Neighbor nb;
        for (size_t k = r.begin(); k != r.end(); ++k) {
          // Nearest() finds points strictly closer than the bound: nudge it to make it inclusive.
          if (reached.Nearest(reference_samples[order[k]], &nb, std::nextafter(radius_mm, 1e300))) ++acc;
        }
        return acc;
      },
      [](size_t a, size_t b) { return a + b; });
  return static_cast<double>(covered) / static_cast<double>(reference_samples.size());
}

}  // namespace slshadow::compare
