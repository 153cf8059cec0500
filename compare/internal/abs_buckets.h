// Order statistics of magnitudes by buckets, behind ComputeStats's median, p95 and p99 and
// AbsPercentile (compare/statistics.h).
#pragma once

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace slshadow::compare::internal {

// The bucket of |d| is its top 16 bits (sign 0, exponent, 4 bits of mantissa), which order
// magnitudes as their values; non-finite values fall beyond every finite bucket.
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

}  // namespace slshadow::compare::internal
