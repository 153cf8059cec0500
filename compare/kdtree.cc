#include "compare/kdtree.h"

#include <algorithm>
#include <cmath>

#include <nanoflann.hpp>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>

namespace slshadow::compare {
namespace {

struct Adaptor {
  const std::vector<Eigen::Vector3d>* points;
  size_t kdtree_get_point_count() const { return points->size(); }
  double kdtree_get_pt(size_t i, size_t dim) const { return (*points)[i][static_cast<int>(dim)]; }
  template <class Box>
  bool kdtree_get_bbox(Box&) const {
    return false;
  }
};

// L2 squared distance computed as (q - p).squaredNorm() in the same summation order, so a tree
// query and a brute-force scan agree bit for bit.
struct ExactL2 {
  using ElementType = double;
  using DistanceType = double;
  const Adaptor& data;
  explicit ExactL2(const Adaptor& d) : data(d) {}
  double evalMetric(const double* a, size_t b_idx, size_t /*size*/) const {
    const Eigen::Vector3d& p = (*data.points)[b_idx];
    const double dx = a[0] - p.x(), dy = a[1] - p.y(), dz = a[2] - p.z();
    return dx * dx + dy * dy + dz * dz;
  }
  template <typename U, typename V>
  double accum_dist(const U a, const V b, size_t) const {
    return (a - b) * (a - b);
  }
};

using Tree = nanoflann::KDTreeSingleIndexAdaptor<ExactL2, Adaptor, 3, uint32_t>;

// 1-NN result set with an initial bound (the max search distance).
class BoundedNearest {
 public:
  using DistanceType = double;
  using IndexType = uint32_t;
  explicit BoundedNearest(double bound_sq) : best_(bound_sq) {}
  bool full() const { return true; }
  size_t size() const { return found_ ? 1 : 0; }
  bool addPoint(double dist, uint32_t index) {
    if (dist < best_) {
      best_ = dist;
      index_ = index;
      found_ = true;
    }
    return true;
  }
  double worstDist() const { return best_; }
  bool found() const { return found_; }
  uint32_t index() const { return index_; }
  double best() const { return best_; }

 private:
  double best_;
  uint32_t index_ = 0;
  bool found_ = false;
};

// Spreads the low 10 bits of v to every third bit.
uint32_t Spread3(uint32_t v) {
  v &= 0x3FF;
  v = (v | (v << 16)) & 0x030000FF;
  v = (v | (v << 8)) & 0x0300F00F;
  v = (v | (v << 4)) & 0x030C30C3;
  v = (v | (v << 2)) & 0x09249249;
  return v;
}

}  // namespace

std::vector<uint32_t> SpatialOrder(const std::vector<Eigen::Vector3d>& points) {
  std::vector<uint32_t> order(points.size());
  if (points.empty()) return order;
  Eigen::Vector3d lo = points.front(), hi = points.front();
  for (const auto& p : points) {
    if (!p.allFinite()) continue;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const double extent = std::max((hi - lo).maxCoeff(), 1e-300);
  // 30-bit Morton key (1024 cells per axis: fine enough for coherence) above the 32-bit index,
  // so one sort of 64-bit integers orders the points.
  const double scale = 1023.0 / extent;
  std::vector<uint64_t> keys(points.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 16384), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) {
      const Eigen::Vector3d q = ((points[i] - lo) * scale).cwiseMax(0.0).cwiseMin(1023.0);
      const uint64_t morton = q.allFinite() ? Spread3(static_cast<uint32_t>(q.x())) |
                                                  (Spread3(static_cast<uint32_t>(q.y())) << 1) |
                                                  (Spread3(static_cast<uint32_t>(q.z())) << 2)
                                            : 0x3FFFFFFFu;
      keys[i] = (morton << 32) | i;
    }
  });
  tbb::parallel_sort(keys.begin(), keys.end());
  for (size_t i = 0; i < keys.size(); ++i) order[i] = static_cast<uint32_t>(keys[i] & 0xFFFFFFFFu);
  return order;
}

// After the build, the points are copied in the tree's leaf order and the tree is pointed at the
// copy (its nodes only hold ranges into the index array, so this keeps it valid): a leaf's
// points are then contiguous in memory, which halves the query time on large clouds.
struct KdTree::Impl {
  // Declared before the tree: MortonCopy() fills them while the adaptor is initialised.
  std::vector<uint32_t> morton;
  std::vector<Eigen::Vector3d> ordered;
  std::vector<uint32_t> original;  // ordered[i] == (*points)[original[i]]
  Adaptor adaptor;
  Tree tree;
  // The tree is built over a Morton-ordered copy (cache-friendly partitioning), then that copy
  // is rearranged in leaf order.
  Impl(const std::vector<Eigen::Vector3d>* pts, int leaf)
      : adaptor{MortonCopy(pts)},
        tree(3, adaptor, nanoflann::KDTreeSingleIndexAdaptorParams(static_cast<size_t>(leaf))) {
    original.resize(tree.vAcc.size());
    std::vector<Eigen::Vector3d> leaf_ordered(tree.vAcc.size());
    for (size_t i = 0; i < tree.vAcc.size(); ++i) {
      leaf_ordered[i] = ordered[tree.vAcc[i]];
      original[i] = morton[tree.vAcc[i]];
      tree.vAcc[i] = static_cast<uint32_t>(i);
    }
    ordered = std::move(leaf_ordered);
    morton.clear();
    morton.shrink_to_fit();
  }
  const std::vector<Eigen::Vector3d>* MortonCopy(const std::vector<Eigen::Vector3d>* pts) {
    morton = SpatialOrder(*pts);
    ordered.resize(pts->size());
    for (size_t i = 0; i < pts->size(); ++i) ordered[i] = (*pts)[morton[i]];
    return &ordered;
  }
};

KdTree::KdTree(const std::vector<Eigen::Vector3d>& points, int leaf_size)
    : points_(&points), impl_(std::make_unique<Impl>(&points, std::max(1, leaf_size))) {}

KdTree::~KdTree() = default;

size_t KdTree::size() const { return points_->size(); }

bool KdTree::Nearest(const Eigen::Vector3d& query, Neighbor* nearest, double max_distance) const {
  if (points_->empty()) return false;
  const double bound =
      std::isfinite(max_distance) ? max_distance * max_distance : std::numeric_limits<double>::max();
  BoundedNearest result(bound);
  impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  if (!result.found()) return false;
  nearest->index = impl_->original[result.index()];
  nearest->distance_sq = result.best();
  return true;
}

void KdTree::KNearest(const Eigen::Vector3d& query, int k, std::vector<Neighbor>* out) const {
  out->clear();
  const size_t n = std::min(static_cast<size_t>(std::max(k, 0)), points_->size());
  if (n == 0) return;
  std::vector<uint32_t> idx(n);
  std::vector<double> d2(n);
  nanoflann::KNNResultSet<double, uint32_t> result(n);
  result.init(idx.data(), d2.data());
  impl_->tree.findNeighbors(result, query.data(), nanoflann::SearchParams());
  out->resize(result.size());
  for (size_t i = 0; i < result.size(); ++i) (*out)[i] = {impl_->original[idx[i]], d2[i]};
}

void KdTree::Radius(const Eigen::Vector3d& query, double radius, std::vector<Neighbor>* out,
                    bool sorted) const {
  out->clear();
  if (points_->empty()) return;
  std::vector<std::pair<uint32_t, double>> found;
  nanoflann::SearchParams params;
  params.sorted = sorted;
  impl_->tree.radiusSearch(query.data(), radius * radius, found, params);
  out->reserve(found.size());
  for (const auto& [i, d2] : found) out->push_back({impl_->original[i], d2});
}

double MedianSpacing(const KdTree& tree, size_t max_samples) {
  const auto& pts = tree.points();
  if (pts.size() < 2) return 0.0;
  const size_t stride = std::max<size_t>(1, pts.size() / std::max<size_t>(1, max_samples));
  std::vector<double> d;
  std::vector<Neighbor> nn;
  for (size_t i = 0; i < pts.size(); i += stride) {
    tree.KNearest(pts[i], 2, &nn);
    if (nn.size() == 2) d.push_back(std::sqrt(nn[1].distance_sq));
  }
  if (d.empty()) return 0.0;
  std::nth_element(d.begin(), d.begin() + static_cast<long>(d.size() / 2), d.end());
  return d[d.size() / 2];
}

}  // namespace slshadow::compare
