#include "reconstruct/filters.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <utility>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

namespace slshadow {
namespace {

constexpr double kFocal = 500;

// An organised grid of a pinhole camera (at the origin, focal kFocal) looking at z = depth(u, v).
template <typename Depth>
DenseGrid MakeGrid(int w, int h, Depth depth) {
  DenseGrid grid;
  grid.Allocate(w, h);
  grid.focal_px = kFocal;
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const size_t i = grid.Index(u, v);
      const double z = depth(u, v);
      grid.point_in_rig[i] =
          Eigen::Vector3d((u - w / 2.0) / kFocal * z, (v - h / 2.0) / kFocal * z, z);
      grid.reason[i] = static_cast<uint8_t>(RejectReason::kAccepted);
    }
  }
  return grid;
}

// The same camera looking at the plane n . x = d.
DenseGrid MakePlaneGrid(int w, int h, const Eigen::Vector3d& n, double d) {
  return MakeGrid(w, h, [&](int u, int v) {
    const Eigen::Vector3d ray((u - w / 2.0) / kFocal, (v - h / 2.0) / kFocal, 1.0);
    return d / n.dot(ray);  // z of the hit, since ray.z() == 1
  });
}

int64_t Count(const DenseGrid& g, RejectReason r) {
  return g.CountByReason()[static_cast<size_t>(r)];
}

TEST(DepthDiscontinuityTest, MarksBothSidesOfAJumpAndTheDilation) {
  DenseGrid grid = MakeGrid(60, 40, [](int u, int) { return u < 30 ? 400.0 : 450.0; });
  const int64_t rejected = FilterDepthDiscontinuities(grid, 8, 0);
  EXPECT_EQ(rejected, 2 * 40);  // columns 29 and 30
  for (int v = 0; v < 40; ++v) {
    EXPECT_EQ(grid.reason[grid.Index(29, v)],
              static_cast<uint8_t>(RejectReason::kDepthDiscontinuity));
    EXPECT_EQ(grid.reason[grid.Index(30, v)],
              static_cast<uint8_t>(RejectReason::kDepthDiscontinuity));
    EXPECT_TRUE(grid.Accepted(grid.Index(28, v)));
  }
  DenseGrid dilated = MakeGrid(60, 40, [](int u, int) { return u < 30 ? 400.0 : 450.0; });
  EXPECT_EQ(FilterDepthDiscontinuities(dilated, 8, 2), 6 * 40);  // columns 27..32
}

TEST(DepthDiscontinuityTest, KeepsSteepButContinuousSurfaces) {
  // A plane tilted 75 degrees to the line of sight: range grows by tan(72..78 deg) = 3.0..4.8
  // footprints per pixel over this narrow image.
  const double a = 75 * M_PI / 180;
  const Eigen::Vector3d n(std::sin(a), 0, -std::cos(a));
  DenseGrid grid = MakePlaneGrid(60, 40, n, n.dot(Eigen::Vector3d(0, 0, 400)));
  EXPECT_EQ(FilterDepthDiscontinuities(grid, 8, 1), 0);
  // A threshold below the slope takes it for a jump.
  DenseGrid again = MakePlaneGrid(60, 40, n, n.dot(Eigen::Vector3d(0, 0, 400)));
  EXPECT_GT(FilterDepthDiscontinuities(again, 2.5, 1), 0);
}

TEST(DepthDiscontinuityTest, IsolatedSpikeAndItsNeighboursGo) {
  DenseGrid grid =
      MakeGrid(20, 20, [](int u, int v) { return u == 10 && v == 10 ? 440.0 : 400.0; });
  // The spike and its 4 neighbours sit on jumps; dilated by 1: the 5x5 block less its corners.
  EXPECT_EQ(FilterDepthDiscontinuities(grid, 8, 1), 25 - 4);
}

TEST(DepthDiscontinuityTest, MatchesABruteForceOracleForEveryDilation) {
  // Random steps and holes; the oracle tests the 4-neighbour jumps and the (2r + 1)^2 window
  // literally.
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  DenseGrid base = MakeGrid(53, 37, [&](int u, int v) {
    return 400.0 + 0.2 * u + (uniform(rng) < 0.03 ? 30.0 : 0.0) + 0.1 * v;
  });
  for (size_t i = 0; i < base.reason.size(); ++i) {
    if (uniform(rng) < 0.1) base.reason[i] = static_cast<uint8_t>(RejectReason::kNotDecoded);
  }
  const int w = base.width, h = base.height;
  auto range = [&](size_t i) { return (base.point_in_rig[i] - base.viewpoint_in_rig).norm(); };
  std::vector<uint8_t> jump(base.reason.size(), 0);
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const size_t i = base.Index(u, v);
      if (!base.Accepted(i)) continue;
      for (auto [un, vn] :
           {std::pair{u - 1, v}, std::pair{u + 1, v}, std::pair{u, v - 1}, std::pair{u, v + 1}}) {
        if (un < 0 || vn < 0 || un >= w || vn >= h || !base.Accepted(base.Index(un, vn))) continue;
        if (std::abs(range(base.Index(un, vn)) - range(i)) > 8 * range(i) / kFocal) jump[i] = 1;
      }
    }
  }
  for (int r = 0; r <= 3; ++r) {
    std::vector<uint8_t> expected = base.reason;
    int64_t expected_count = 0;
    for (int v = 0; v < h; ++v) {
      for (int u = 0; u < w; ++u) {
        const size_t i = base.Index(u, v);
        if (!base.Accepted(i)) continue;
        bool hit = false;
        for (int vn = v - r; vn <= v + r; ++vn) {
          for (int un = u - r; un <= u + r; ++un) {
            if (un >= 0 && vn >= 0 && un < w && vn < h && jump[base.Index(un, vn)]) hit = true;
          }
        }
        if (hit) {
          expected[i] = static_cast<uint8_t>(RejectReason::kDepthDiscontinuity);
          ++expected_count;
        }
      }
    }
    DenseGrid grid = base;
    EXPECT_GT(expected_count, 0);
    EXPECT_EQ(FilterDepthDiscontinuities(grid, 8, r), expected_count) << "r " << r;
    EXPECT_EQ(grid.reason, expected) << "r " << r;
  }
}

TEST(OutlierRemovalTest, CleanSurfaceKeepsEveryPointAndOffSurfacePointsGo) {
  DenseGrid clean = MakeGrid(80, 60, [](int u, int v) { return 500.0 + 0.05 * u + 0.02 * v; });
  EXPECT_EQ(FilterStatisticalOutliers(clean, 2, 8, 3.0), 0);  // border cells included
  EXPECT_EQ(Count(clean, RejectReason::kAccepted), 80 * 60);
  DenseGrid grid = MakeGrid(80, 60, [](int u, int v) { return 500.0 + 0.05 * u + 0.02 * v; });
  std::mt19937 rng(4);
  std::uniform_int_distribution<int> pu(0, 79), pv(0, 59);
  std::set<size_t> moved;
  while (moved.size() < 30) {
    const size_t i = grid.Index(pu(rng), pv(rng));
    if (moved.insert(i).second)
      grid.point_in_rig[i] += Eigen::Vector3d(0, 0, 15.0);  // 15 footprints off
  }
  const int64_t rejected = FilterStatisticalOutliers(grid, 2, 8, 3.0);
  for (size_t i : moved) EXPECT_EQ(grid.reason[i], static_cast<uint8_t>(RejectReason::kOutlier));
  EXPECT_EQ(rejected, static_cast<int64_t>(moved.size()));
  EXPECT_EQ(Count(grid, RejectReason::kOutlier), rejected);
}

TEST(OutlierRemovalTest, PointsWithoutNeighboursGo) {
  DenseGrid grid = MakeGrid(30, 30, [](int, int) { return 500.0; });
  for (size_t i = 0; i < grid.reason.size(); ++i)
    grid.reason[i] = static_cast<uint8_t>(RejectReason::kNotDecoded);
  grid.reason[grid.Index(5, 5)] = static_cast<uint8_t>(RejectReason::kAccepted);
  grid.reason[grid.Index(20, 20)] = static_cast<uint8_t>(RejectReason::kAccepted);
  grid.reason[grid.Index(21, 20)] = static_cast<uint8_t>(RejectReason::kAccepted);
  EXPECT_EQ(FilterStatisticalOutliers(grid, 2, 8, 3.0), 1);
  EXPECT_EQ(grid.reason[grid.Index(5, 5)], static_cast<uint8_t>(RejectReason::kOutlier));
}

// Brute-force oracle of the statistical outlier removal: per accepted cell, all squared distances
// to the accepted cells of the window, sorted, the k smallest summed; mean and std over the
// cells with a neighbour; the same limit.
std::vector<uint8_t> OutlierOracle(const DenseGrid& grid, int r, int k, double ratio,
                                   double floor) {
  std::vector<double> score(grid.reason.size(), -1.0);
  for (int v = 0; v < grid.height; ++v) {
    for (int u = 0; u < grid.width; ++u) {
      const size_t i = grid.Index(u, v);
      if (!grid.Accepted(i)) continue;
      std::vector<double> d;
      for (int vn = std::max(0, v - r); vn <= std::min(grid.height - 1, v + r); ++vn) {
        for (int un = std::max(0, u - r); un <= std::min(grid.width - 1, u + r); ++un) {
          const size_t j = grid.Index(un, vn);
          if (j != i && grid.Accepted(j))
            d.push_back((grid.point_in_rig[j] - grid.point_in_rig[i]).squaredNorm());
        }
      }
      if (d.empty()) {
        score[i] = std::numeric_limits<double>::infinity();
        continue;
      }
      std::sort(d.begin(), d.end());
      const int m = std::min<int>(k, static_cast<int>(d.size()));
      double sum = 0;
      for (int q = 0; q < m; ++q) sum += d[static_cast<size_t>(q)];
      score[i] = std::sqrt(sum / m * (grid.focal_px * grid.focal_px) /
                           (grid.point_in_rig[i] - grid.viewpoint_in_rig).squaredNorm());
    }
  }
  double sum = 0, sum2 = 0;
  int64_t n = 0;
  for (double s : score) {
    if (s >= 0 && std::isfinite(s)) {
      sum += s;
      sum2 += s * s;
      ++n;
    }
  }
  const double mean = sum / static_cast<double>(n);
  const double var = std::max(0.0, (sum2 - sum * mean) / static_cast<double>(n - 1));
  const double limit = std::max(mean + ratio * std::sqrt(var), floor);
  std::vector<uint8_t> reason = grid.reason;
  for (size_t i = 0; i < score.size(); ++i) {
    if (score[i] >= 0 && score[i] > limit) reason[i] = static_cast<uint8_t>(RejectReason::kOutlier);
  }
  return reason;
}

TEST(OutlierRemovalTest, MatchesABruteForceOracleForEveryWindowAndNeighbourCount) {
  // A noisy wavy surface with holes (so cells have 0..8 accepted neighbours) and spikes; the
  // 3x3 window has its own sorting-network path, larger windows the general one.
  std::mt19937 rng(11);
  std::normal_distribution<double> noise(0.0, 0.3);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  DenseGrid base = MakeGrid(
      70, 50, [&](int u, int v) { return 450.0 + 10 * std::sin(0.2 * u) + 0.1 * v + noise(rng); });
  for (size_t i = 0; i < base.reason.size(); ++i) {
    const double x = uniform(rng);
    if (x < 0.15)
      base.reason[i] = static_cast<uint8_t>(RejectReason::kNotDecoded);
    else if (x < 0.18)
      base.point_in_rig[i].z() += 20 + 40 * uniform(rng);
  }
  for (int r = 1; r <= 2; ++r) {
    for (int k = 1; k <= 8; ++k) {
      for (double floor : {0.0, 4.0}) {
        DenseGrid grid = base;
        const std::vector<uint8_t> expected = OutlierOracle(grid, r, k, 2.0, floor);
        const int64_t rejected = FilterStatisticalOutliers(grid, r, k, 2.0, floor);
        int64_t expected_rejected = 0;
        for (size_t i = 0; i < expected.size(); ++i)
          expected_rejected += expected[i] != base.reason[i] ? 1 : 0;
        EXPECT_GT(expected_rejected, 0) << "r " << r << " k " << k;
        EXPECT_EQ(rejected, expected_rejected) << "r " << r << " k " << k << " floor " << floor;
        EXPECT_EQ(grid.reason, expected) << "r " << r << " k " << k << " floor " << floor;
      }
    }
  }
}

TEST(NormalsTest, PlaneNormalsAreExactAndFaceTheViewpoint) {
  const Eigen::Vector3d plane_normal = Eigen::Vector3d(0.3, -0.2, -1.0).normalized();
  DenseGrid grid =
      MakePlaneGrid(40, 30, plane_normal, plane_normal.dot(Eigen::Vector3d(0, 0, 500)));
  int64_t fallbacks = -1;
  const auto normals = EstimateNormals(grid, &fallbacks);
  EXPECT_EQ(fallbacks, 0);
  const Eigen::Vector3d a = grid.point_in_rig[grid.Index(0, 0)];
  const Eigen::Vector3d b = grid.point_in_rig[grid.Index(39, 0)];
  const Eigen::Vector3d c = grid.point_in_rig[grid.Index(0, 29)];
  Eigen::Vector3d n = (b - a).cross(c - a).normalized();
  if (n.dot(-a) < 0) n = -n;
  for (size_t i = 0; i < normals.size(); ++i) {
    EXPECT_GT(normals[i].cast<double>().dot(n), 1 - 1e-6);
    EXPECT_GT(normals[i].cast<double>().dot(grid.viewpoint_in_rig - grid.point_in_rig[i]), 0);
  }
}

TEST(NormalsTest, IsolatedPointsFaceTheViewpoint) {
  DenseGrid grid = MakeGrid(5, 5, [](int, int) { return 300.0; });
  for (size_t i = 0; i < grid.reason.size(); ++i)
    grid.reason[i] = static_cast<uint8_t>(RejectReason::kOutlier);
  const size_t i = grid.Index(2, 2);
  grid.reason[i] = static_cast<uint8_t>(RejectReason::kAccepted);
  int64_t fallbacks = 0;
  const auto normals = EstimateNormals(grid, &fallbacks);
  EXPECT_EQ(fallbacks, 1);
  EXPECT_NEAR(normals[i].cast<double>().dot(-grid.point_in_rig[i].normalized()), 1.0, 1e-6);
  EXPECT_EQ(normals[0], Eigen::Vector3f::Zero());
}

}  // namespace
}  // namespace slshadow
