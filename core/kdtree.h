// KdTree: exact nearest-neighbour queries over a borrowed array of 3D points (the one spatial tree
// of the project: compare's distances and registration, sim's disc radii, the workflows).
//
// Distances are Euclidean and computed in double exactly as (q - p).squaredNorm() would be, so
// a query returns bit-for-bit the minimum a brute-force scan finds (ties may pick either index).
// The tree splits at the median along the widest axis of each subtree's bounding box, down to
// leaf_size points; it is built in parallel (TBB) and is the same tree whatever the number of
// threads, so every query result is too. The points are copied in leaf order inside the tree.
// Precondition: the points vector outlives the tree and is not modified while the tree exists.
#pragma once

#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

#include <Eigen/Core>

namespace slshadow {

struct Neighbor {
  uint32_t index = 0;        // into the indexed points
  double distance_sq = 0.0;  // squared Euclidean distance, mm^2
};

class KdTree {
 public:
  // Builds the tree (O(n log n)); leaf_size (clamped to 1..4096) trades build time for query time.
  explicit KdTree(const std::vector<Eigen::Vector3d>& points, int leaf_size = 20);
  ~KdTree();
  KdTree(const KdTree&) = delete;
  KdTree& operator=(const KdTree&) = delete;

  size_t size() const;
  const std::vector<Eigen::Vector3d>& points() const { return *points_; }

  // The nearest point, or false when none lies within max_distance (strictly closer than it).
  bool Nearest(const Eigen::Vector3d& query, Neighbor* nearest,
               double max_distance = std::numeric_limits<double>::infinity()) const;
  // The k nearest points sorted by distance (fewer when the tree holds fewer points).
  void KNearest(const Eigen::Vector3d& query, int k, std::vector<Neighbor>* out) const;
  // All points with distance <= radius, sorted by distance when `sorted`.
  void Radius(const Eigen::Vector3d& query, double radius, std::vector<Neighbor>* out,
              bool sorted = false) const;

 private:
  struct Impl;
  const std::vector<Eigen::Vector3d>* points_;
  std::unique_ptr<Impl> impl_;
};

// A permutation of the points along a Morton (Z-order) curve over their bounding box. Queries
// processed in this order hit the tree's memory coherently (faster on shuffled clouds).
std::vector<uint32_t> SpatialOrder(const std::vector<Eigen::Vector3d>& points);

}  // namespace slshadow
