#include "compare/mesh_distance.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "compare/distances.h"
#include "tests/compare/test_shapes.h"

namespace slshadow::compare {
namespace {

using testing::BoxMesh;
using testing::BoxSdf;
using testing::IcoSphere;
using testing::RandomPoints;

TEST(MeshDistance, BoxEqualsAnalyticSignedDistanceEverywhere) {
  const Eigen::Vector3d h(2.0, 1.0, 0.5);
  const MeshDistance md(BoxMesh(h));
  // Random points in and around the box, including the edge and corner regions where the
  // closest feature is an edge or a vertex.
  for (const auto& p : RandomPoints(20000, 3.0, 7)) {
    const MeshHit hit = md.Closest(p);
    ASSERT_NEAR(hit.signed_distance_mm, BoxSdf(p, h), 1e-12) << p.transpose();
  }
}

TEST(MeshDistance, KnownOffsetsAlongFaceNormalsOfASphere) {
  const TriangleMesh mesh = IcoSphere(10.0, 3);
  const MeshDistance md(mesh);
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(0.05, 0.9);
  std::uniform_real_distribution<double> off(-0.3, 2.0);
  for (size_t t = 0; t < mesh.NumTriangles(); t += 3) {
    const auto& f = mesh.triangles[t];
    double a = u(rng), b = u(rng);
    if (a + b > 0.95) {
      a *= 0.5;
      b *= 0.5;
    }
    const Eigen::Vector3d& p0 = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d foot = p0 + a * (mesh.vertices[static_cast<size_t>(f[1])] - p0) +
                                 b * (mesh.vertices[static_cast<size_t>(f[2])] - p0);
    const double d = off(rng);
    // Outside a convex mesh, an offset along the face normal keeps the foot as closest point;
    // inside, only while the offset is smaller than the distance to the other faces, which
    // holds for |d| <= 0.3 mm at this tessellation except next to edges (guarded by a, b).
    const MeshHit hit = md.Closest(foot + d * mesh.FaceNormal(t));
    EXPECT_NEAR(hit.signed_distance_mm, d, 1e-9) << "triangle " << t;
    EXPECT_LT((hit.closest - foot).norm(), 1e-9);
  }
}

TEST(MeshDistance, EqualsBruteForceOverAllTriangles) {
  TriangleMesh mesh = IcoSphere(5.0, 2);
  // Perturb the vertices so the mesh is irregular (still closed).
  std::mt19937 rng(9);
  std::normal_distribution<double> n(0.0, 0.3);
  for (auto& v : mesh.vertices) v += Eigen::Vector3d(n(rng), n(rng), n(rng));
  const MeshDistance md(mesh);
  for (const auto& p : RandomPoints(3000, 8.0, 10)) {
    double best = std::numeric_limits<double>::infinity();
    for (const auto& f : mesh.triangles) {
      int feature = 0;
      const Eigen::Vector3d q = ClosestPointOnTriangle(
          p, mesh.vertices[static_cast<size_t>(f[0])], mesh.vertices[static_cast<size_t>(f[1])],
          mesh.vertices[static_cast<size_t>(f[2])], &feature);
      best = std::min(best, (p - q).norm());
    }
    EXPECT_EQ(std::abs(md.Closest(p).signed_distance_mm), best);
  }
}

TEST(MeshDistance, WarmStartedQueriesEqualColdOnes) {
  TriangleMesh mesh = IcoSphere(5.0, 3);
  std::mt19937 rng(12);
  std::normal_distribution<double> n(0.0, 0.2);
  for (auto& v : mesh.vertices) v += Eigen::Vector3d(n(rng), n(rng), n(rng));
  const MeshDistance md(mesh);
  // Hints: the previous query's triangle (coherent), a random one, and an out-of-range one.
  std::uniform_int_distribution<uint32_t> tri(0, static_cast<uint32_t>(mesh.triangles.size() - 1));
  uint32_t previous = 0;
  for (const auto& p : RandomPoints(5000, 8.0, 13)) {
    const MeshHit cold = md.Closest(p);
    for (const uint32_t hint : {previous, tri(rng), std::numeric_limits<uint32_t>::max()}) {
      const MeshHit warm = md.Closest(p, hint);
      ASSERT_EQ(warm.signed_distance_mm, cold.signed_distance_mm)
          << p.transpose() << " hint " << hint;
    }
    previous = cold.triangle;
  }
}

// Brute force over all triangles with the same closest-point routine: the smallest squared
// distance, ties to the lowest triangle index (the hierarchy's documented result).
struct Brute {
  double d2;
  uint32_t triangle;
  Eigen::Vector3d closest;
};
Brute BruteForce(const TriangleMesh& mesh, const Eigen::Vector3d& p) {
  Brute b{std::numeric_limits<double>::infinity(), 0, Eigen::Vector3d::Zero()};
  for (size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& f = mesh.triangles[t];
    int feature = 0;
    const Eigen::Vector3d q = ClosestPointOnTriangle(
        p, mesh.vertices[static_cast<size_t>(f[0])], mesh.vertices[static_cast<size_t>(f[1])],
        mesh.vertices[static_cast<size_t>(f[2])], &feature);
    const double d2 = (p - q).squaredNorm();
    if (d2 < b.d2) b = {d2, static_cast<uint32_t>(t), q};
  }
  return b;
}

// Generalised winding number (sum of the triangles' solid angles / 4 pi; Van Oosterom & Strackee):
// ~1 inside a closed outward-oriented mesh, ~0 outside. An oracle for the sign independent of
// pseudo-normals.
double WindingNumber(const TriangleMesh& mesh, const Eigen::Vector3d& p) {
  double sum = 0;
  for (const auto& f : mesh.triangles) {
    const Eigen::Vector3d a = mesh.vertices[static_cast<size_t>(f[0])] - p;
    const Eigen::Vector3d b = mesh.vertices[static_cast<size_t>(f[1])] - p;
    const Eigen::Vector3d c = mesh.vertices[static_cast<size_t>(f[2])] - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    sum += 2 * std::atan2(a.dot(b.cross(c)),
                          la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb);
  }
  return sum / (4 * M_PI);
}

// Query points for a mesh: random ones around it, and points exactly on its vertices, on its
// edges and inside its faces (closest feature: vertex / edge / face, distance 0 or tiny), and
// small offsets from them along random directions.
std::vector<Eigen::Vector3d> QueryPoints(const TriangleMesh& mesh, size_t n_random, double extent,
                                         unsigned seed) {
  std::vector<Eigen::Vector3d> pts = RandomPoints(n_random, extent, seed);
  std::mt19937 rng(seed + 1);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::normal_distribution<double> g(0.0, 0.05);
  for (size_t t = 0; t < mesh.triangles.size(); t += 2) {
    const auto& f = mesh.triangles[t];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(f[2])];
    const double s = u(rng), r = u(rng) * (1 - s);
    for (const Eigen::Vector3d& q :
         {a, Eigen::Vector3d(a + s * (b - a)), Eigen::Vector3d(a + s * (b - a) + r * (c - a))}) {
      pts.push_back(q);
      pts.push_back(q + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    }
  }
  return pts;
}

TEST(MeshDistance, EqualsBruteForceWithTiesOnVerticesEdgesAndFaces) {
  for (const unsigned seed : {21u, 22u, 23u}) {
    TriangleMesh mesh = IcoSphere(5.0, 2);
    std::mt19937 rng(seed);
    // 0.1 mm keeps the perturbed sphere free of folds (self-intersections), where the
    // pseudo-normal sign is exact (with 0.4 mm some vertices fold and the oracle disagrees).
    std::normal_distribution<double> n(0.0, 0.1);
    for (auto& v : mesh.vertices) v += Eigen::Vector3d(n(rng), n(rng), n(rng));
    // Far from the origin, where float bounds are coarse (0.25 mm ulp would be far too coarse
    // for pruning without the conservative slack).
    for (auto& v : mesh.vertices) v += Eigen::Vector3d(400.0, -250.0, 900.0);
    const MeshDistance md(mesh);
    auto pts = QueryPoints(mesh, 1500, 9.0, seed + 10);
    for (size_t i = 0; i < 1500; ++i) pts[i] += Eigen::Vector3d(400.0, -250.0, 900.0);
    for (const auto& p : pts) {
      const Brute b = BruteForce(mesh, p);
      const MeshHit hit = md.Closest(p);
      ASSERT_EQ(hit.triangle, b.triangle) << p.transpose();
      ASSERT_EQ(std::abs(hit.signed_distance_mm), std::sqrt(b.d2)) << p.transpose();
      ASSERT_EQ(hit.closest, b.closest);
      if (std::abs(hit.signed_distance_mm) > 1e-6) {
        const bool inside = WindingNumber(mesh, p) > 0.5;
        EXPECT_EQ(hit.signed_distance_mm < 0, inside)
            << p.transpose() << " d " << hit.signed_distance_mm;
      }
    }
  }
}

TEST(MeshDistance, RandomTriangleSoupEqualsBruteForce) {
  // Unrelated, intersecting, sliver and degenerate triangles: no structure to rely on.
  std::mt19937 rng(31);
  std::uniform_real_distribution<double> u(-10.0, 10.0);
  std::normal_distribution<double> g(0.0, 1.5);
  TriangleMesh mesh;
  for (int t = 0; t < 300; ++t) {
    const Eigen::Vector3d c(u(rng), u(rng), u(rng));
    const int base = static_cast<int>(mesh.vertices.size());
    for (int k = 0; k < 3; ++k)
      mesh.vertices.push_back(c + Eigen::Vector3d(g(rng), g(rng), g(rng)));
    if (t % 50 == 0) mesh.vertices.back() = mesh.vertices[static_cast<size_t>(base)];  // degenerate
    mesh.triangles.emplace_back(base, base + 1, base + 2);
  }
  const MeshDistance md(mesh);
  for (const auto& p : QueryPoints(mesh, 3000, 14.0, 32)) {
    const Brute b = BruteForce(mesh, p);
    const MeshHit hit = md.Closest(p);
    ASSERT_EQ(hit.triangle, b.triangle) << p.transpose();
    ASSERT_NEAR(std::abs(hit.signed_distance_mm), std::sqrt(b.d2), 1e-9);
    ASSERT_EQ(std::abs(hit.signed_distance_mm), std::sqrt(b.d2));
  }
}

TEST(CloudToMesh, BitIdenticalRunToRunAndEqualToSerialColdQueries) {
  TriangleMesh mesh = IcoSphere(20.0, 4);
  std::mt19937 rng(41);
  std::normal_distribution<double> n(0.0, 0.3);
  for (auto& v : mesh.vertices) v += Eigen::Vector3d(n(rng), n(rng), n(rng));
  // A scan-like cloud: points near the surface plus a far plane of points (like a table).
  std::vector<Eigen::Vector3d> cloud;
  std::normal_distribution<double> noise(0.0, 0.05);
  for (const auto& v : mesh.vertices) {
    for (int k = 0; k < 20; ++k)
      cloud.push_back(v * (1.0 + noise(rng) / 20.0) + Eigen::Vector3d(noise(rng), noise(rng), 0));
  }
  std::uniform_real_distribution<double> u(-60.0, 60.0);
  for (int k = 0; k < 100000; ++k) cloud.emplace_back(u(rng), u(rng), -25.0);
  const C2MResult a = CloudToMesh(cloud, mesh);
  const C2MResult b = CloudToMesh(cloud, mesh);
  ASSERT_EQ(a.signed_distances_mm.size(), cloud.size());
  EXPECT_EQ(0, std::memcmp(a.signed_distances_mm.data(), b.signed_distances_mm.data(),
                           cloud.size() * sizeof(double)));
  EXPECT_EQ(a.triangles, b.triangles);
  const MeshDistance md(mesh);
  for (size_t i = 0; i < cloud.size(); i += 7) {
    const MeshHit hit = md.Closest(cloud[i]);
    ASSERT_EQ(hit.signed_distance_mm, a.signed_distances_mm[i]) << i;
    ASSERT_EQ(hit.triangle, a.triangles[i]) << i;
  }
}

}  // namespace
}  // namespace slshadow::compare
