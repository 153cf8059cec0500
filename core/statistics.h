// One rank convention for every median and percentile slshadow reports (calibration, reconstruction
// and comparison summaries, reports and maps): the nearest rank. The p-th percentile (0 <= p <=
// 100) of n values is the value of rank ceil(p / 100 * n) in ascending order (1-based, at least 1),
// so it is always one of the values, never an interpolation; the median is the 50th percentile,
// i.e. the lower of the two middle values for an even count (docs/formats.md says so for every
// report).
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
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

// Percentile(values, 50).
template <typename T>
T Median(std::vector<T>& values) {
  return Percentile(values, 50);
}

}  // namespace slshadow
