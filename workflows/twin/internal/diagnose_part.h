// The `part` cause of the twin's diagnosis (diagnose.h): a deviation on the part's surface that
// every mode finds the same way and a calibration error does not explain. Split from
// diagnose.cc, which calls Part() once the pose is credible.
#pragma once

#include <cmath>
#include <vector>

#include "core/statistics.h"
#include "workflows/twin/diagnose.h"

namespace slshadow::twin::internal {

// 1.4826 x the median absolute deviation from `median`: the standard deviation of Gaussian noise.
inline double Mad(const std::vector<double>& v, double median) {
  std::vector<double> d;
  d.reserve(v.size());
  for (double x : v) d.push_back(std::abs(x - median));
  return 1.4826 * Median(std::move(d));
}

// Per mode the smoothed real - twin distances to the part, their largest significant cluster and
// the pose's bound there; detected when every mode deviates the same way at the strongest mode's
// cluster and calibration_found is false.
Finding Part(const std::vector<ModeEvidence>& modes, const DiagnoseOptions& options,
             bool calibration_found);

}  // namespace slshadow::twin::internal
