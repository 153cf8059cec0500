#include "core/kdtree.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

namespace slshadow {
namespace {

std::vector<Eigen::Vector3d> RandomPoints(size_t n, double extent, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-extent, extent);
  std::vector<Eigen::Vector3d> pts(n);
  for (auto& p : pts) p = {u(rng), u(rng), u(rng)};
  return pts;
}

TEST(KdTree, NearestEqualsBruteForceExactly) {
  const auto ref = RandomPoints(3000, 10.0, 1);
  const auto qs = RandomPoints(2000, 12.0, 2);
  const KdTree tree(ref);
  for (const auto& q : qs) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& p : ref) best = std::min(best, (q - p).squaredNorm());
    Neighbor nb;
    ASSERT_TRUE(tree.Nearest(q, &nb));
    EXPECT_EQ(nb.distance_sq, best);  // bit-exact
    EXPECT_EQ((q - ref[nb.index]).squaredNorm(), best);
  }
}

TEST(KdTree, MaxDistanceBoundsTheSearch) {
  const auto ref = RandomPoints(500, 10.0, 3);
  const KdTree tree(ref);
  const auto qs = RandomPoints(500, 10.0, 4);
  int inside = 0;
  for (const auto& q : qs) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& p : ref) best = std::min(best, (q - p).norm());
    Neighbor nb;
    const bool found = tree.Nearest(q, &nb, 0.8);
    EXPECT_EQ(found, best < 0.8);
    inside += found;
  }
  EXPECT_GT(inside, 50);
  EXPECT_LT(inside, 450);
}

TEST(KdTree, KNearestAndRadiusEqualBruteForce) {
  const auto ref = RandomPoints(2000, 5.0, 5);
  const KdTree tree(ref);
  const auto qs = RandomPoints(100, 5.0, 6);
  std::vector<Neighbor> nn;
  for (const auto& q : qs) {
    std::vector<double> d2;
    for (const auto& p : ref) d2.push_back((q - p).squaredNorm());
    std::vector<double> sorted = d2;
    std::sort(sorted.begin(), sorted.end());
    tree.KNearest(q, 7, &nn);
    ASSERT_EQ(nn.size(), 7u);
    for (int i = 0; i < 7; ++i)
      EXPECT_EQ(nn[static_cast<size_t>(i)].distance_sq, sorted[static_cast<size_t>(i)]);
    tree.Radius(q, 1.1, &nn, /*sorted=*/true);
    const auto expected =
        std::count_if(d2.begin(), d2.end(), [](double v) { return v <= 1.1 * 1.1; });
    EXPECT_EQ(static_cast<long>(nn.size()), expected);
    for (size_t i = 1; i < nn.size(); ++i) EXPECT_LE(nn[i - 1].distance_sq, nn[i].distance_sq);
  }
}

// The build runs in parallel above 32 768 points per subtree: one thread and two threads must give
// the same tree, i.e. the same neighbour indices (also among ties: the points lie on a grid, so
// many queries have several nearest points at the same distance), equal to brute force.
TEST(KdTree, SameTreeWhateverTheThreadCount) {
  std::vector<Eigen::Vector3d> ref;
  for (int i = 0; i < 300; ++i)
    for (int j = 0; j < 300; ++j)
      ref.emplace_back(0.25 * i, 0.25 * j, 0.01 * ((i * 7 + j * 3) % 5));
  const auto qs = RandomPoints(3000, 80.0, 7);
  const auto run = [&](int threads) {
    std::vector<std::vector<Neighbor>> out;
    tbb::task_arena arena(threads);
    arena.execute([&] {
      const KdTree tree(ref);
      std::vector<Neighbor> nn;
      for (const auto& q : qs) {
        Neighbor nb;
        EXPECT_TRUE(tree.Nearest(q, &nb));
        tree.KNearest(q, 5, &nn);
        nn.insert(nn.begin(), nb);
        out.push_back(nn);
      }
    });
    return out;
  };
  const auto one = run(1), two = run(2);
  ASSERT_EQ(one.size(), two.size());
  for (size_t i = 0; i < one.size(); ++i) {
    ASSERT_EQ(one[i].size(), 6u);
    double best = std::numeric_limits<double>::infinity();
    for (const auto& p : ref) best = std::min(best, (qs[i] - p).squaredNorm());
    EXPECT_EQ(one[i][0].distance_sq, best);
    for (size_t k = 0; k < 6; ++k) {
      EXPECT_EQ(one[i][k].index, two[i][k].index);
      EXPECT_EQ(one[i][k].distance_sq, two[i][k].distance_sq);
    }
  }
}

TEST(KdTree, EmptyAndTinyTrees) {
  const std::vector<Eigen::Vector3d> none;
  const KdTree empty(none);
  Neighbor nb;
  EXPECT_FALSE(empty.Nearest(Eigen::Vector3d::Zero(), &nb));
  std::vector<Neighbor> nn;
  empty.KNearest(Eigen::Vector3d::Zero(), 3, &nn);
  EXPECT_TRUE(nn.empty());
  for (int n = 1; n <= 40; ++n) {
    const auto pts = RandomPoints(static_cast<size_t>(n), 1.0, static_cast<unsigned>(10 + n));
    for (int leaf : {1, 2, 12}) {
      const KdTree tree(pts, leaf);
      tree.KNearest(Eigen::Vector3d(0.1, 0.2, 0.3), n + 5, &nn);
      ASSERT_EQ(nn.size(), static_cast<size_t>(n));
      std::vector<bool> seen(static_cast<size_t>(n));
      for (const auto& x : nn) seen[x.index] = true;
      EXPECT_EQ(std::count(seen.begin(), seen.end(), true), n);
      for (size_t i = 1; i < nn.size(); ++i) EXPECT_LE(nn[i - 1].distance_sq, nn[i].distance_sq);
    }
  }
}

// SpatialOrder: a permutation, duplicates in index order (the radix sort is stable), and
// consecutive points close together (the path is far shorter than in index order).
TEST(SpatialOrder, StablePermutationAlongACurve) {
  auto pts = RandomPoints(50000, 100.0, 8);
  for (size_t i = 0; i < 1000; ++i) pts[2 * i + 1] = pts[2 * i];  // duplicates
  const std::vector<uint32_t> order = SpatialOrder(pts);
  ASSERT_EQ(order.size(), pts.size());
  std::vector<int> seen(pts.size());
  for (uint32_t i : order) ++seen[i];
  EXPECT_EQ(std::count(seen.begin(), seen.end(), 1), static_cast<long>(pts.size()));
  std::vector<size_t> rank(pts.size());
  for (size_t k = 0; k < order.size(); ++k) rank[order[k]] = k;
  for (size_t i = 0; i < 1000; ++i) EXPECT_LT(rank[2 * i], rank[2 * i + 1]);
  double along = 0, by_index = 0;
  for (size_t k = 1; k < order.size(); ++k) {
    along += (pts[order[k]] - pts[order[k - 1]]).norm();
    by_index += (pts[k] - pts[k - 1]).norm();
  }
  EXPECT_LT(along, 0.1 * by_index);
}

}  // namespace
}  // namespace slshadow
