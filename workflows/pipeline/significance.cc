#include "workflows/pipeline/significance.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace slshadow::pipeline {

double SignificanceThreshold(double sigma, double floor) { return std::max(3 * sigma, floor); }

bool Significant(double effect, double sigma, double floor) {
  return std::abs(effect) > SignificanceThreshold(sigma, floor);
}

double BandSigma(const std::vector<double>& band_values) {
  std::vector<double> v;
  for (double x : band_values) {
    if (std::isfinite(x)) v.push_back(x);
  }
  if (v.size() < 2) return std::nan("");
  const double mean = std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
  double ss = 0;
  for (double x : v) ss += (x - mean) * (x - mean);
  return std::sqrt(ss / static_cast<double>(v.size() - 1)) /
         std::sqrt(static_cast<double>(v.size()));
}

}  // namespace slshadow::pipeline
