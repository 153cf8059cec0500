// The median nearest-neighbour spacing of a cloud.
#pragma once

#include <cstddef>
#include <vector>

#include <Eigen/Core>

namespace slshadow {
class KdTree;
}  // namespace slshadow

namespace slshadow::compare {

// Median distance from each point to its nearest other point (exact, on at most max_samples
// evenly strided points): the typical point spacing of a cloud, mm. 0 for fewer than 2 points.
double MedianSpacing(const KdTree& tree, size_t max_samples = 20000);

// MedianSpacing(KdTree(points), max_samples) without the tree, the same double. A cloud whose
// array order follows space (a scan's cloud, in grid order): each sample's distance to its array
// neighbours bounds its nearest, hashed cells sized from those bounds list the samples searching
// them, and one pass over the points compares each with the samples searching its cell. Any
// other cloud (or one with a non-finite sample, or many isolated ones): a uniform grid from the
// bounding box answers the samples whose nearest other point lies within its cell, a tree only
// the others (compare/internal/median_spacing.h).
double MedianSpacing(const std::vector<Eigen::Vector3d>& points, size_t max_samples = 20000);

}  // namespace slshadow::compare
