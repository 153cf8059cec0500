#include "compare/mesh_distance.h"

#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

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
      const Eigen::Vector3d q =
          ClosestPointOnTriangle(p, mesh.vertices[static_cast<size_t>(f[0])], mesh.vertices[static_cast<size_t>(f[1])],
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
      ASSERT_EQ(warm.signed_distance_mm, cold.signed_distance_mm) << p.transpose() << " hint " << hint;
    }
    previous = cold.triangle;
  }
}

}  // namespace
}  // namespace slshadow::compare
