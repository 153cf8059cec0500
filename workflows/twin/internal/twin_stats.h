// The statistics the shadow report quotes for its image and cloud comparisons (docs/formats.md,
// "Shadow report": `count`, `mean_*`, `std_*`, `rms_*`, `median_*`, `p95_abs_*`, `max_abs_*`).
// Percentiles by the project's nearest-rank convention (core/statistics.h).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow::twin::internal {

struct SampleStats {
  int64_t count = 0;  // finite values
  // Of the finite values: mean, population standard deviation and RMS (sums in double); the
  // nearest-rank median of the values and 95th percentile of their magnitudes; the largest
  // magnitude. All 0 for no finite value.
  double mean = 0, stddev = 0, rms = 0, median = 0, p95_abs = 0, max_abs = 0;

  // {"count", "mean_<unit>", "std_<unit>", "rms_<unit>", "median_<unit>", "p95_abs_<unit>",
  // "max_abs_<unit>"}.
  nlohmann::json ToJson(const std::string& unit) const;
};

// The statistics of `values` (non-finite ones left out): core's Summarize (core/statistics.h),
// under the report's field names.
SampleStats ComputeSampleStats(std::vector<float> values);
SampleStats ComputeSampleStats(std::vector<double> values);

}  // namespace slshadow::twin::internal
