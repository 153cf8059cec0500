#include "compare/kdtree.h"

#include <algorithm>
#include <cmath>

#include <gtest/gtest.h>

#include "tests/compare/test_shapes.h"

namespace slshadow::compare {
namespace {

using testing::RandomPoints;

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
    for (int i = 0; i < 7; ++i) EXPECT_EQ(nn[static_cast<size_t>(i)].distance_sq, sorted[static_cast<size_t>(i)]);
    tree.Radius(q, 1.1, &nn, /*sorted=*/true);
    const auto expected = std::count_if(d2.begin(), d2.end(), [](double v) { return v <= 1.1 * 1.1; });
    EXPECT_EQ(static_cast<long>(nn.size()), expected);
    for (size_t i = 1; i < nn.size(); ++i) EXPECT_LE(nn[i - 1].distance_sq, nn[i].distance_sq);
  }
}

TEST(KdTree, MedianSpacingOfAGrid) {
  std::vector<Eigen::Vector3d> grid;
  for (int i = 0; i < 30; ++i)
    for (int j = 0; j < 30; ++j) grid.emplace_back(0.5 * i, 0.5 * j, 0.0);
  const KdTree tree(grid);
  EXPECT_DOUBLE_EQ(MedianSpacing(tree), 0.5);
}

}  // namespace
}  // namespace slshadow::compare
