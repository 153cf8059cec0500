#include "compare/coverage.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include "compare/internal/point_grid.h"
#include "core/error.h"
#include "core/kdtree.h"

namespace slshadow::compare {

using internal::PointGrid;

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
          if (reached.Nearest(reference_samples[order[k]], &nb, std::nextafter(radius_mm, 1e300)))
            ++acc;
        }
        return acc;
      },
      [](size_t a, size_t b) { return a + b; });
  return static_cast<double>(covered) / static_cast<double>(reference_samples.size());
}

double Coverage(const std::vector<Eigen::Vector3d>& reference_samples,
                const std::vector<Eigen::Vector3d>& reached, double radius_mm) {
  return Coverages({&reference_samples}, reached, radius_mm).front();
}

std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& reached, double radius_mm) {
  return Coverages(sample_sets, reached, std::vector<uint8_t>(reached.size(), 1), radius_mm);
}

std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& points,
                              const std::vector<uint8_t>& reached, double radius_mm) {
  SLSHADOW_THROW_IF(reached.size() != points.size(), "coverage: ", reached.size(), " flags for ",
                    points.size(), " points");
  std::vector<double> out(sample_sets.size(), 0.0);
  bool any = false;
  for (const auto* samples : sample_sets) any = any || !samples->empty();
  if (!any || std::none_of(reached.begin(), reached.end(), [](uint8_t f) { return f != 0; }))
    return out;
  // The criterion of the KdTree overload, bit for bit: squared distance < nextafter(radius)^2.
  const double r = std::nextafter(radius_mm, 1e300);
  const double bound = r * r;
  if (!(bound > 0) || !std::isfinite(bound)) {
    std::vector<Eigen::Vector3d> kept;
    for (size_t i = 0; i < points.size(); ++i) {
      if (reached[i]) kept.push_back(points[i]);
    }
    const KdTree tree(kept);
    for (size_t k = 0; k < sample_sets.size(); ++k) {
      out[k] = Coverage(*sample_sets[k], tree, radius_mm);
    }
    return out;
  }
  const PointGrid grid(points, r * 1.001, nullptr, reached.data());  // margin: cells round
  for (size_t k = 0; k < sample_sets.size(); ++k) {
    const std::vector<Eigen::Vector3d>& samples = *sample_sets[k];
    if (samples.empty()) continue;
    const std::vector<uint32_t> order = SpatialOrder(samples);
    const size_t covered = tbb::parallel_reduce(
        tbb::blocked_range<size_t>(0, samples.size(), 2048), size_t{0},
        [&](const tbb::blocked_range<size_t>& range, size_t acc) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            if (grid.AnyWithin(samples[order[i]], bound)) ++acc;
          }
          return acc;
        },
        [](size_t a, size_t b) { return a + b; });
    out[k] = static_cast<double>(covered) / static_cast<double>(samples.size());
  }
  return out;
}

}  // namespace slshadow::compare
