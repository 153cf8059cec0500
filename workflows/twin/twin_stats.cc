#include "workflows/twin/internal/twin_stats.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <type_traits>

#include "core/statistics.h"

namespace slshadow::twin::internal {
namespace {

// Floats as order-preserving unsigned keys, and back.
uint32_t FloatKey(float x) {
  uint32_t u;
  std::memcpy(&u, &x, sizeof(u));
  return (u & 0x80000000u) ? ~u : (u | 0x80000000u);
}
float KeyFloat(uint32_t key) {
  const uint32_t u = (key & 0x80000000u) ? (key & 0x7FFFFFFFu) : ~key;
  float x;
  std::memcpy(&x, &u, sizeof(x));
  return x;
}

// The k-th smallest (0-based) of the keys key_of(x) of finite floats, as a float: the value
// std::nth_element would place at k, by two passes of a 16-bit histogram (high, then low half).
template <typename KeyOf>
float SelectKth(const std::vector<float>& v, size_t k, KeyOf key_of) {
  std::vector<uint32_t> hist(65536, 0);
  for (float x : v) ++hist[key_of(x) >> 16];
  uint32_t high = 0;
  size_t below = 0;
  while (below + hist[high] <= k) below += hist[high++];
  std::fill(hist.begin(), hist.end(), 0u);
  for (float x : v) {
    const uint32_t key = key_of(x);
    if ((key >> 16) == high) ++hist[key & 0xFFFFu];
  }
  uint32_t low = 0;
  while (below + hist[low] <= k) below += hist[low++];
  return KeyFloat((high << 16) | low);
}

template <typename T>
SampleStats Compute(std::vector<T> v) {
  SampleStats s;
  v.erase(std::remove_if(v.begin(), v.end(), [](T x) { return !std::isfinite(x); }), v.end());
  s.count = static_cast<int64_t>(v.size());
  if (v.empty()) return s;
  double sum = 0, ss = 0;
  for (double x : v) sum += x, ss += x * x;
  const double n = static_cast<double>(v.size());
  s.mean = sum / n;
  s.rms = std::sqrt(ss / n);
  s.stddev = std::sqrt(std::max(0.0, ss / n - s.mean * s.mean));
  const size_t median_rank = PercentileRank(v.size(), 50.0);
  const size_t p95_rank = PercentileRank(v.size(), 95.0);
  if constexpr (std::is_same_v<T, float>) {
    s.median = SelectKth(v, median_rank, [](float x) { return FloatKey(x); });
    // |x|: the key of a non-negative float orders as its bits.
    s.p95_abs = SelectKth(v, p95_rank, [](float x) { return FloatKey(std::abs(x)); });
    float largest = 0;
    for (float x : v) largest = std::max(largest, std::abs(x));
    s.max_abs = largest;
  } else {
    s.median = Percentile(v, 50.0);
    for (T& x : v) x = std::abs(x);
    s.p95_abs = Percentile(v, 95.0);
    s.max_abs = *std::max_element(v.begin(), v.end());
  }
  s.median += 0.0;  // a zero median as +0 (the float keys order -0 below +0; JSON would say -0.0)
  return s;
}

}  // namespace

nlohmann::json SampleStats::ToJson(const std::string& unit) const {
  return {{"count", count},
          {"mean_" + unit, mean},
          {"std_" + unit, stddev},
          {"rms_" + unit, rms},
          {"median_" + unit, median},
          {"p95_abs_" + unit, p95_abs},
          {"max_abs_" + unit, max_abs}};
}

SampleStats ComputeSampleStats(std::vector<float> values) { return Compute(std::move(values)); }
SampleStats ComputeSampleStats(std::vector<double> values) { return Compute(std::move(values)); }

}  // namespace slshadow::twin::internal
