// The coverage of a reference surface by compared points.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

namespace slshadow {
class KdTree;
}  // namespace slshadow

namespace slshadow::compare {

// Coverage of the reference surface: the fraction of `reference_samples` (points that sample
// the reference surface uniformly by area, or the reference cloud's own points) that have a
// point of `reached` (the compared points within the threshold of the reference) within
// `radius_mm`. In [0, 1]; 0 when there are no samples.
double Coverage(const std::vector<Eigen::Vector3d>& reference_samples, const KdTree& reached,
                double radius_mm);
// The same value from the reached points themselves, through a uniform grid of cell ~radius
// (no tree to build: cheaper on millions of reached points).
double Coverage(const std::vector<Eigen::Vector3d>& reference_samples,
                const std::vector<Eigen::Vector3d>& reached, double radius_mm);
// Coverage(*sample_sets[k], reached, radius_mm) for every k, bit for bit, from one grid over the
// reached points (built once instead of once per sample set).
std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& reached, double radius_mm);
// The same with the reached points given as flags over `points` (non-zero: reached), without
// copying them out.
std::vector<double> Coverages(const std::vector<const std::vector<Eigen::Vector3d>*>& sample_sets,
                              const std::vector<Eigen::Vector3d>& points,
                              const std::vector<uint8_t>& reached, double radius_mm);

}  // namespace slshadow::compare
