#include "compare/neighbour_grid.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <gtest/gtest.h>

#include "core/kdtree.h"

namespace slshadow::compare {
namespace {

// A wavy surface sampled on a jittered grid (a scan's organised cloud), with a hole, a few points
// off the surface and duplicates.
std::vector<Eigen::Vector3d> SurfaceCloud(int n_side, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> jitter(-0.2, 0.2), u(0, 1);
  std::vector<Eigen::Vector3d> points;
  for (int i = 0; i < n_side; ++i) {
    for (int j = 0; j < n_side; ++j) {
      const double x = 0.5 * (i + jitter(rng)), y = 0.5 * (j + jitter(rng));
      if (std::hypot(x - 20, y - 30) < 6) continue;  // a hole
      const double z = 400 + 3 * std::sin(x / 7) * std::cos(y / 9) + 0.4 * x;
      points.emplace_back(x, y, z);
      if (u(rng) < 0.002) points.emplace_back(x, y, z + 5 + 20 * u(rng));  // off the surface
      if (u(rng) < 0.001) points.push_back(points.back());                 // a duplicate
    }
  }
  return points;
}

// The grid's k nearest are KdTree's: the same points in the same order, the same
// distances bit for bit (ties in distance, here only duplicates, are compared as sets).
void ExpectSameAsKdTree(const std::vector<Eigen::Vector3d>& points,
                        const std::vector<Eigen::Vector3d>& queries, int k) {
  const KdTree tree(points);
  const NeighbourGrid grid(points, k);
  NeighbourGrid::Scratch scratch;
  std::vector<Neighbor> a, b;
  int64_t compared = 0;
  for (const Eigen::Vector3d& q : queries) {
    tree.KNearest(q, k, &a);
    grid.KNearest(q, k, &scratch, &b);
    ASSERT_EQ(a.size(), b.size());
    for (size_t i = 0; i < a.size(); ++i) {
      ASSERT_EQ(a[i].distance_sq, b[i].distance_sq) << "query " << q.transpose() << " rank " << i;
      if (a[i].index != b[i].index) {
        // A tie (a duplicate point): another point at exactly the same distance.
        const Eigen::Vector3d& p = points[b[i].index];
        const double dx = q.x() - p.x(), dy = q.y() - p.y(), dz = q.z() - p.z();
        ASSERT_EQ(dx * dx + dy * dy + dz * dz, a[i].distance_sq);
      }
      ++compared;
    }
    Neighbor n1, n2;
    const bool f1 = tree.Nearest(q, &n1, 1.0), f2 = grid.Nearest(q, &n2, 1.0);
    ASSERT_EQ(f1, f2);
    if (f1) {
      EXPECT_EQ(n1.distance_sq, n2.distance_sq);
    }
    const bool g1 = tree.Nearest(q, &n1), g2 = grid.Nearest(q, &n2);
    ASSERT_EQ(g1, g2);
    if (g1) {
      EXPECT_EQ(n1.distance_sq, n2.distance_sq);
    }
  }
  EXPECT_EQ(compared, static_cast<int64_t>(queries.size()) *
                          std::min<int64_t>(k, static_cast<int64_t>(points.size())));
}

TEST(NeighbourGrid, SameNeighboursAsKdTreeOnASurface) {
  const std::vector<Eigen::Vector3d> points = SurfaceCloud(160, 11);
  std::vector<Eigen::Vector3d> queries;
  for (size_t i = 0; i < points.size(); i += 7) {
    if (points[i].allFinite()) queries.push_back(points[i]);  // queries from the cloud, in order
  }
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-20, 100);
  for (int i = 0; i < 300; ++i) queries.emplace_back(u(rng), u(rng), 400 + u(rng));  // anywhere
  for (int k : {1, 2, 64, 200}) ExpectSameAsKdTree(points, queries, k);
}

TEST(NeighbourGrid, SameNeighboursAsKdTreeOnAVolumeAndFewPoints) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0, 50);
  std::vector<Eigen::Vector3d> volume;
  for (int i = 0; i < 20000; ++i) volume.emplace_back(u(rng), u(rng), u(rng));
  std::vector<Eigen::Vector3d> queries(volume.begin(), volume.begin() + 500);
  ExpectSameAsKdTree(volume, queries, 64);
  // Fewer points than asked for: all of them; points on one line; a single point repeated.
  std::vector<Eigen::Vector3d> few(volume.begin(), volume.begin() + 40), line, same(10);
  for (int i = 0; i < 1000; ++i) line.emplace_back(0.1 * i, 0, 0);
  for (auto& p : same) p = Eigen::Vector3d(1, 2, 3);
  ExpectSameAsKdTree(few, queries, 64);
  ExpectSameAsKdTree(line, queries, 64);
  NeighbourGrid grid(same, 64);
  NeighbourGrid::Scratch scratch;
  std::vector<Neighbor> out;
  grid.KNearest(Eigen::Vector3d(0, 0, 0), 64, &scratch, &out);
  ASSERT_EQ(out.size(), 10u);
  for (size_t i = 0; i < out.size(); ++i) EXPECT_EQ(out[i].index, i);  // ties: lower index first
  // Non-finite points are skipped.
  std::vector<Eigen::Vector3d> with_nan = few;
  with_nan.insert(with_nan.begin() + 5, Eigen::Vector3d(std::nan(""), 1, 1));
  const NeighbourGrid nan_grid(with_nan, 64);
  nan_grid.KNearest(Eigen::Vector3d(1, 1, 1), 64, &scratch, &out);
  ASSERT_EQ(out.size(), 40u);
  for (const auto& nb : out) EXPECT_NE(nb.index, 5u);
  const std::vector<Eigen::Vector3d> none;
  const NeighbourGrid empty(none);
  Neighbor n;
  EXPECT_FALSE(empty.Nearest(Eigen::Vector3d::Zero(), &n));
  empty.KNearest(Eigen::Vector3d::Zero(), 5, &scratch, &out);
  EXPECT_TRUE(out.empty());
}

}  // namespace
}  // namespace slshadow::compare
