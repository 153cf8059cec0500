// One rank convention for every median and percentile slshadow reports (calibration, reconstruction
// and comparison summaries, reports and maps): the nearest rank. The p-th percentile (0 <= p <=
// 100) of n values is the value of rank ceil(p / 100 * n) in ascending order (1-based, at least 1),
// so it is always one of the values, never an interpolation; the median is the 50th percentile,
// i.e. the lower of the two middle values for an even count (docs/formats.md says so for every
// report). Summarize() gives the summary figures every module quotes of a set of values (mean,
// population standard deviation by two passes, RMS, the median, the 95th percentile and the
// maximum of the magnitudes) with these percentiles.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

namespace slshadow {

// The 0-based index in ascending order of the nearest-rank p-th percentile of n > 0 values.
inline size_t PercentileRank(size_t n, double p) {
  const double rank = std::ceil(p / 100.0 * static_cast<double>(n));
  return static_cast<size_t>(std::clamp(rank, 1.0, static_cast<double>(n))) - 1;
}

// The nearest-rank p-th percentile of `values` (reordered, not sorted: std::nth_element); NaN for
// none. NaNs must be removed first.
template <typename T>
T Percentile(std::vector<T>& values, double p) {
  if (values.empty()) return std::numeric_limits<T>::quiet_NaN();
  const auto k = values.begin() + static_cast<std::ptrdiff_t>(PercentileRank(values.size(), p));
  std::nth_element(values.begin(), k, values.end());
  return *k;
}

// The same of a temporary (or a copy the caller gives up).
template <typename T>
T Percentile(std::vector<T>&& values, double p) {
  return Percentile(values, p);
}

// Percentile(values, 50).
template <typename T>
T Median(std::vector<T>& values) {
  return Percentile(values, 50);
}
template <typename T>
T Median(std::vector<T>&& values) {
  return Percentile(values, 50);
}

// The summary figures of a set of values, over its finite values only.
struct Summary {
  int64_t count = 0;  // finite values
  // Of the finite values: the mean, the population standard deviation (divisor n, from the
  // deviations from the mean: two passes, no cancellation) and the RMS, all summed in double; the
  // median, the 95th percentile and the largest of the values, the 95th percentile and the
  // largest of their magnitudes (nearest rank). All 0 for no finite value.
  double mean = 0, stddev = 0, rms = 0, median = 0, p95 = 0, max = 0, p95_abs = 0, max_abs = 0;
};

// Summary of `values` (non-finite ones left out). Floats: the order statistics by two passes of a
// 16-bit histogram of the values' bits (several times faster than std::nth_element on millions
// of values); doubles: std::nth_element. The same figures for float values either way; a zero
// median is +0.
Summary Summarize(std::vector<float> values);
Summary Summarize(std::vector<double> values);

}  // namespace slshadow
