#include "workflows/twin/internal/twin_stats.h"

#include <utility>

#include "core/statistics.h"

namespace slshadow::twin::internal {
namespace {

SampleStats FromSummary(const Summary& s) {
  SampleStats out;
  out.count = s.count;
  out.mean = s.mean;
  out.stddev = s.stddev;
  out.rms = s.rms;
  out.median = s.median;
  out.p95_abs = s.p95_abs;
  out.max_abs = s.max_abs;
  return out;
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

SampleStats ComputeSampleStats(std::vector<float> values) {
  return FromSummary(Summarize(std::move(values)));
}
SampleStats ComputeSampleStats(std::vector<double> values) {
  return FromSummary(Summarize(std::move(values)));
}

}  // namespace slshadow::twin::internal
