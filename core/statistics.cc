#include "core/statistics.h"

#include <cstring>
#include <type_traits>

namespace slshadow {
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

// The value of rank k (0-based) of the finite floats `v` ordered by key_of, given hist[b] = how
// many keys have the high 16 bits b: the value std::nth_element would place at k, from the values
// of that one bucket only (a few thousand of millions for residuals).
template <typename KeyOf>
float SelectKth(const std::vector<float>& v, const std::vector<uint32_t>& hist, size_t k,
                KeyOf key_of) {
  uint32_t bucket = 0;
  size_t below = 0;
  while (below + hist[bucket] <= k) below += hist[bucket++];
  std::vector<uint32_t> keys;
  keys.reserve(hist[bucket]);
  for (float x : v) {
    const uint32_t key = key_of(x);
    if ((key >> 16) == bucket) keys.push_back(key);
  }
  const auto at = keys.begin() + static_cast<std::ptrdiff_t>(k - below);
  std::nth_element(keys.begin(), at, keys.end());
  return KeyFloat(*at);
}

template <typename T>
Summary SummarizeFinite(std::vector<T> v) {
  Summary s;
  v.erase(std::remove_if(v.begin(), v.end(), [](T x) { return !std::isfinite(x); }), v.end());
  s.count = static_cast<int64_t>(v.size());
  if (v.empty()) return s;
  const size_t median_rank = PercentileRank(v.size(), 50.0);
  const size_t p95_rank = PercentileRank(v.size(), 95.0);
  const double n = static_cast<double>(v.size());
  double sum = 0, ss = 0;
  if constexpr (std::is_same_v<T, float>) {
    // One pass for the sums, the largest magnitude and the histogram of the high 16 bits of the
    // values' keys; the magnitudes' histogram only when a value has its sign bit set (otherwise
    // the magnitudes are the values: residuals, distances); a pass per order statistic over its
    // bucket's values only.
    const auto value_key = [](float x) { return FloatKey(x); };
    const auto abs_key = [](float x) { return FloatKey(std::abs(x)); };
    std::vector<uint32_t> value_hist(65536, 0);
    float largest = 0, top = -std::numeric_limits<float>::infinity();
    bool any_sign = false;
    for (const float x : v) {
      const double d = x;
      sum += d, ss += d * d;
      largest = std::max(largest, std::abs(x));
      top = std::max(top, x);
      any_sign |= std::signbit(x);
      ++value_hist[value_key(x) >> 16];
    }
    s.max_abs = largest;
    s.max = top;
    s.median = SelectKth(v, value_hist, median_rank, value_key);
    s.p95 = SelectKth(v, value_hist, p95_rank, value_key);
    if (any_sign) {
      std::vector<uint32_t> abs_hist(65536, 0);
      for (const float x : v) ++abs_hist[abs_key(x) >> 16];
      s.p95_abs = SelectKth(v, abs_hist, p95_rank, abs_key);
    } else {
      s.p95_abs = s.p95;
    }
  }
  if constexpr (!std::is_same_v<T, float>) {
    for (double x : v) sum += x, ss += x * x;
  }
  s.mean = sum / n;
  s.rms = std::sqrt(ss / n);
  // The squared deviations in four interleaved partial sums (independent additions: a quarter of
  // the latency of one running sum, and no less accurate).
  double dev[4] = {0, 0, 0, 0};
  const size_t size = v.size();
  size_t i = 0;
  for (; i + 4 <= size; i += 4) {
    for (size_t j = 0; j < 4; ++j) {
      const double d = static_cast<double>(v[i + j]) - s.mean;
      dev[j] += d * d;
    }
  }
  for (; i < size; ++i) {
    const double d = static_cast<double>(v[i]) - s.mean;
    dev[0] += d * d;
  }
  s.stddev = std::sqrt(((dev[0] + dev[1]) + (dev[2] + dev[3])) / n);
  if constexpr (!std::is_same_v<T, float>) {
    s.median = Percentile(v, 50.0);
    s.p95 = Percentile(v, 95.0);
    s.max = *std::max_element(v.begin(), v.end());
    for (T& x : v) x = std::abs(x);
    s.p95_abs = Percentile(v, 95.0);
    s.max_abs = *std::max_element(v.begin(), v.end());
  }
  s.median += 0.0;  // a zero median as +0 (the float keys order -0 below +0; JSON would say -0.0)
  return s;
}

}  // namespace

Summary Summarize(std::vector<float> values) { return SummarizeFinite(std::move(values)); }
Summary Summarize(std::vector<double> values) { return SummarizeFinite(std::move(values)); }

}  // namespace slshadow
