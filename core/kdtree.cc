#include "core/kdtree.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/parallel_reduce.h>

namespace slshadow {
namespace {

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
  // 30-bit Morton key (1024 cells per axis: fine enough for coherence); ties keep index order
  // (a stable radix sort, two passes of 15 bits), as a sort of (key << 32 | index) would.
  const double scale = 1023.0 / extent;
  std::vector<uint32_t> keys(points.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 16384),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i != r.end(); ++i) {
                        const Eigen::Vector3d q =
                            ((points[i] - lo) * scale).cwiseMax(0.0).cwiseMin(1023.0);
                        keys[i] = q.allFinite() ? Spread3(static_cast<uint32_t>(q.x())) |
                                                      (Spread3(static_cast<uint32_t>(q.y())) << 1) |
                                                      (Spread3(static_cast<uint32_t>(q.z())) << 2)
                                                : 0x3FFFFFFFu;
                      }
                    });
  constexpr uint32_t kBits = 15, kBuckets = 1u << kBits;
  std::vector<uint32_t> tmp(points.size());
  std::vector<uint32_t> count(kBuckets);
  for (int pass = 0; pass < 2; ++pass) {
    const uint32_t shift = pass * kBits;
    std::fill(count.begin(), count.end(), 0u);
    for (uint32_t k : keys) ++count[(k >> shift) & (kBuckets - 1)];
    uint32_t sum = 0;
    for (uint32_t& c : count) sum += std::exchange(c, sum);
    if (pass == 0) {
      for (size_t i = 0; i < keys.size(); ++i)
        tmp[count[keys[i] & (kBuckets - 1)]++] = static_cast<uint32_t>(i);
    } else {
      for (uint32_t i : tmp) order[count[keys[i] >> shift]++] = i;
    }
  }
  return order;
}

namespace {

// A node of the tree, in pre-order: the left child of an inner node follows it, the right child
// is at `right`. An inner node splits along `dim` its points into a left half whose coordinates
// along dim are <= low and a right half whose coordinates are >= high (low <= high: the extreme
// coordinates of each half, so the gap between them is empty space).
struct Node {
  double low = 0, high = 0;  // inner only
  uint32_t first = 0;        // inner: index of the right child; leaf: first point (leaf order)
  uint16_t count = 0;        // leaf: number of points (>= 1); inner: 0
  uint16_t dim = 0;          // inner: split axis
};

struct Item {
  Eigen::Vector3d p;
  uint32_t index;  // in the caller's array
};

struct Box {
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  void Add(const Eigen::Vector3d& p) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  void Add(const Box& b) {
    lo = lo.cwiseMin(b.lo);
    hi = hi.cwiseMax(b.hi);
  }
};

// Above this many points a subtree's bounding box and its two halves are computed in parallel.
constexpr size_t kParallelBuild = 32768;

Box BoundsOf(const Item* items, size_t n) {
  if (n < kParallelBuild) {
    Box b;
    for (size_t i = 0; i < n; ++i) b.Add(items[i].p);
    return b;
  }
  return tbb::parallel_reduce(
      tbb::blocked_range<size_t>(0, n, 8192), Box(),
      [&](const tbb::blocked_range<size_t>& r, Box b) {
        for (size_t i = r.begin(); i != r.end(); ++i) b.Add(items[i].p);
        return b;
      },
      [](Box a, const Box& b) {
        a.Add(b);
        return a;
      });
}

// Number of nodes of the tree over n >= 1 points, and over n + 1 (a split halves n into
// floor(n / 2) and the rest, so the subtrees below a level only ever have two sizes m, m + 1).
std::pair<uint32_t, uint32_t> NodeCounts(size_t n, size_t leaf) {
  if (n <= leaf) return {1u, n + 1 <= leaf ? 1u : 3u};
  const size_t m = n / 2;
  const std::pair<uint32_t, uint32_t> below = NodeCounts(m, leaf);
  const uint32_t cm = below.first, cm1 = below.second;  // named copies: lambdas capture them
  const auto count = [&](size_t k) -> uint32_t {
    if (k <= leaf) return 1u;
    const size_t a = k / 2, b = k - a;
    return 1u + (a == m ? cm : cm1) + (b == m ? cm : cm1);
  };
  return {count(n), count(n + 1)};
}

// Builds the subtree of items [begin, end) at nodes[index]: the split axis is the bounding box's
// widest, the split the median (nth_element), so the tree's shape depends only on the points and
// each subtree's node range is known before it is built: the halves are built in parallel and
// the result does not depend on the number of threads. Returns the subtree's bounding box.
Box Build(std::vector<Item>& items, std::vector<Node>& nodes, size_t leaf, uint32_t index,
          size_t begin, size_t end) {
  const size_t n = end - begin;
  Node& node = nodes[index];
  if (n <= leaf) {
    node.first = static_cast<uint32_t>(begin);
    node.count = static_cast<uint16_t>(n);
    return BoundsOf(items.data() + begin, n);
  }
  const Box box = BoundsOf(items.data() + begin, n);
  int dim = 0;
  (box.hi - box.lo).maxCoeff(&dim);
  const size_t mid = begin + n / 2;
  std::nth_element(items.begin() + static_cast<std::ptrdiff_t>(begin),
                   items.begin() + static_cast<std::ptrdiff_t>(mid),
                   items.begin() + static_cast<std::ptrdiff_t>(end),
                   [dim](const Item& a, const Item& b) { return a.p[dim] < b.p[dim]; });
  const uint32_t right = index + 1 + NodeCounts(mid - begin, leaf).first;
  node.first = right;
  node.count = 0;
  node.dim = static_cast<uint16_t>(dim);
  Box left_box, right_box;
  if (n >= kParallelBuild) {
    tbb::parallel_invoke([&] { left_box = Build(items, nodes, leaf, index + 1, begin, mid); },
                         [&] { right_box = Build(items, nodes, leaf, right, mid, end); });
  } else {
    left_box = Build(items, nodes, leaf, index + 1, begin, mid);
    right_box = Build(items, nodes, leaf, right, mid, end);
  }
  nodes[index].low = left_box.hi[dim];
  nodes[index].high = right_box.lo[dim];
  return box;
}

// Lower bounds are compared after this factor: the squared gaps are rounded (relative 2^-52 per
// operation), so a subtree is skipped only when even its slightly lowered bound exceeds the
// current worst distance, and no point a brute-force scan would pick is missed.
constexpr double kSafe = 1.0 - 1e-12;

}  // namespace

// The points are stored in leaf order (a leaf's points contiguous in memory) with their original
// indices beside them.
struct KdTree::Impl {
  std::vector<Eigen::Vector3d> ordered;
  std::vector<uint32_t> original;  // ordered[i] == points[original[i]]
  std::vector<Node> nodes;
  Box root;

  Impl(const std::vector<Eigen::Vector3d>& points, size_t leaf) {
    const size_t n = points.size();
    if (n == 0) return;
    std::vector<Item> items(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 16384),
                      [&](const tbb::blocked_range<size_t>& r) {
                        for (size_t i = r.begin(); i != r.end(); ++i)
                          items[i] = {points[i], static_cast<uint32_t>(i)};
                      });
    nodes.resize(NodeCounts(n, leaf).first);
    root = Build(items, nodes, leaf, 0, 0, n);
    ordered.resize(n);
    original.resize(n);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 16384),
                      [&](const tbb::blocked_range<size_t>& r) {
                        for (size_t i = r.begin(); i != r.end(); ++i) {
                          ordered[i] = items[i].p;
                          original[i] = items[i].index;
                        }
                      });
  }

  // Depth-first search, nearer child first; `visit` sees (squared distance, leaf-order index)
  // and `worst()` bounds what can still be accepted.
  template <class Visitor>
  void Search(const double* q, uint32_t index, double* gaps, Visitor& visit) const {
    const Node& node = nodes[index];
    if (node.count > 0) {
      for (uint32_t i = node.first, end = node.first + node.count; i < end; ++i) {
        const Eigen::Vector3d& p = ordered[i];
        const double dx = q[0] - p.x(), dy = q[1] - p.y(), dz = q[2] - p.z();
        visit.Add(dx * dx + dy * dy + dz * dz, i);
      }
      return;
    }
    const int dim = node.dim;
    const double below = q[dim] - node.low, above = q[dim] - node.high;
    uint32_t near_child = index + 1, far_child = node.first;
    double cut = above * above;
    if (below + above >= 0) {
      std::swap(near_child, far_child);
      cut = below * below;
    }
    Search(q, near_child, gaps, visit);
    const double saved = gaps[dim];
    gaps[dim] = std::max(cut, saved);
    if ((gaps[0] + gaps[1] + gaps[2]) * kSafe <= visit.worst()) Search(q, far_child, gaps, visit);
    gaps[dim] = saved;
  }

  template <class Visitor>
  void Run(const Eigen::Vector3d& query, Visitor& visit) const {
    if (nodes.empty()) return;
    double gaps[3];
    for (int d = 0; d < 3; ++d) {
      const double g = std::max({root.lo[d] - query[d], query[d] - root.hi[d], 0.0});
      gaps[d] = g * g;
    }
    if ((gaps[0] + gaps[1] + gaps[2]) * kSafe > visit.worst()) return;
    Search(query.data(), 0, gaps, visit);
  }
};

namespace {

// The nearest point strictly closer than a bound.
struct NearestVisitor {
  double best;
  uint32_t index = 0;
  bool found = false;
  double worst() const { return best; }
  void Add(double d2, uint32_t i) {
    if (d2 < best) {
      best = d2;
      index = i;
      found = true;
    }
  }
};

// The k nearest, kept sorted by distance (then by order of discovery).
struct KnnVisitor {
  size_t k;
  std::vector<Neighbor>* out;
  double worst() const {
    return out->size() < k ? std::numeric_limits<double>::infinity() : out->back().distance_sq;
  }
  void Add(double d2, uint32_t i) {
    if (out->size() == k) {
      if (!(d2 < out->back().distance_sq)) return;
      out->pop_back();
    }
    out->push_back({i, d2});
    for (size_t j = out->size() - 1; j > 0 && (*out)[j].distance_sq < (*out)[j - 1].distance_sq;
         --j) {
      std::swap((*out)[j], (*out)[j - 1]);
    }
  }
};

struct RadiusVisitor {
  double radius_sq;
  std::vector<Neighbor>* out;
  double worst() const { return radius_sq; }
  void Add(double d2, uint32_t i) {
    if (d2 <= radius_sq) out->push_back({i, d2});
  }
};

}  // namespace

KdTree::KdTree(const std::vector<Eigen::Vector3d>& points, int leaf_size)
    : points_(&points),
      impl_(std::make_unique<Impl>(points, static_cast<size_t>(std::clamp(leaf_size, 1, 4096)))) {}

KdTree::~KdTree() = default;

size_t KdTree::size() const { return points_->size(); }

bool KdTree::Nearest(const Eigen::Vector3d& query, Neighbor* nearest, double max_distance) const {
  if (points_->empty()) return false;
  NearestVisitor visit{std::isfinite(max_distance) ? max_distance * max_distance
                                                   : std::numeric_limits<double>::max()};
  impl_->Run(query, visit);
  if (!visit.found) return false;
  nearest->index = impl_->original[visit.index];
  nearest->distance_sq = visit.best;
  return true;
}

void KdTree::KNearest(const Eigen::Vector3d& query, int k, std::vector<Neighbor>* out) const {
  out->clear();
  const size_t n = std::min(static_cast<size_t>(std::max(k, 0)), points_->size());
  if (n == 0) return;
  KnnVisitor visit{n, out};
  impl_->Run(query, visit);
  for (auto& nb : *out) nb.index = impl_->original[nb.index];
}

void KdTree::Radius(const Eigen::Vector3d& query, double radius, std::vector<Neighbor>* out,
                    bool sorted) const {
  out->clear();
  if (points_->empty() || !(radius >= 0)) return;
  RadiusVisitor visit{radius * radius, out};
  impl_->Run(query, visit);
  for (auto& nb : *out) nb.index = impl_->original[nb.index];
  if (sorted) {
    std::sort(out->begin(), out->end(), [](const Neighbor& a, const Neighbor& b) {
      return a.distance_sq < b.distance_sq || (a.distance_sq == b.distance_sq && a.index < b.index);
    });
  }
}

}  // namespace slshadow
