#include "compare/compare.h"
#include "compare/mesh_distance.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <limits>

#include "core/config.h"
#include "core/error.h"
#include "tests/compare/test_shapes.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::compare {
namespace {

using testing::IcoSphere;

// Points on the upper half (z > 0) of a tessellated sphere, moved `offset` mm along their
// triangle's outward normal: their exact signed distance to the mesh is `offset`.
PointCloud OffsetUpperHalf(const TriangleMesh& mesh, double offset, unsigned seed,
                           size_t per_triangle) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  PointCloud c;
  for (size_t t = 0; t < mesh.NumTriangles(); ++t) {
    const auto& f = mesh.triangles[t];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& cc = mesh.vertices[static_cast<size_t>(f[2])];
    if ((a + b + cc).z() <= 0) continue;
    for (size_t k = 0; k < per_triangle; ++k) {
      // Uniform on the triangle. On a convex mesh an outward offset along the face normal keeps
      // the foot as the closest point, edges and corners included.
      const double s = std::sqrt(u(rng)), r = u(rng);
      c.points.push_back((1 - s) * a + s * (1 - r) * b + s * r * cc + offset * mesh.FaceNormal(t));
    }
  }
  return c;
}

TEST(Compare, MeshReferenceGivesExactSignedDeviationsAndHalfCoverage) {
  const TriangleMesh mesh = IcoSphere(20.0, 4);  // 5120 triangles
  const Reference ref = ReferenceFromMesh(mesh, "sphere", 100000);
  PointCloud cloud = OffsetUpperHalf(mesh, 0.1, 41, 12);
  // 1 % of the points pushed 0.6 mm further out: outliers.
  for (size_t i = 0; i < cloud.size(); i += 100) cloud.points[i] *= (20.0 + 0.7) / (20.0 + 0.1);
  CompareOptions o;
  const CompareResult r = Compare(cloud, ref, o, "offset sphere");
  ASSERT_TRUE(r.c2m.has_value());
  EXPECT_EQ(r.distance_method, "nearest_triangle");
  size_t expected_outliers = 0;
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (i % 100 == 0) {
      ++expected_outliers;
      EXPECT_GT(r.deviations_mm[i], 0.5);
    } else {
      EXPECT_NEAR(r.deviations_mm[i], 0.1, 1e-9);
    }
  }
  EXPECT_EQ(r.c2c.outliers, expected_outliers);
  EXPECT_EQ(r.c2c.count, cloud.size());
  EXPECT_GT(r.c2m->signed_mean_mm, 0.1);
  // The cloud covers the triangles of the upper hemisphere: about half of the area (plus a rim
  // of one coverage radius, < 1 %).
  EXPECT_NEAR(r.coverage, 0.5, 0.03);
  EXPECT_EQ(r.compared.Scalar("deviation")->size(), cloud.size());
  EXPECT_EQ(r.compared.colors.size(), cloud.size());
  EXPECT_NE(r.Summary().find("coverage"), std::string::npos);
}

TEST(Compare, CloudReferenceUsesC2CAndIcpUndoesAMisalignment) {
  const TriangleMesh mesh = IcoSphere(20.0, 4);
  // An ellipsoid-ish part (a sphere scaled per axis) so that ICP has a unique answer.
  TriangleMesh part = mesh;
  for (auto& v : part.vertices) v = Eigen::Vector3d(1.5 * v.x(), v.y(), 0.7 * v.z());
  const Reference dense = ReferenceFromMesh(part, "part", 200000);
  const Reference ref = ReferenceFromCloud(dense.cloud, "part samples");
  const Reference other = ReferenceFromMesh(part, "part", 60000);
  PointCloud cloud;
  const Rigid3d cloud_from_ref(
      Eigen::Quaterniond(Eigen::AngleAxisd(0.05, Eigen::Vector3d(0, 0.6, 0.8))),
      Eigen::Vector3d(0.8, -0.5, 0.3));
  for (size_t i = 0; i < other.cloud.size(); i += 2)
    cloud.points.push_back(cloud_from_ref * other.cloud.points[i]);
  CompareOptions o;
  o.registration.method = RegistrationMethod::kIcp;
  const CompareResult r = Compare(cloud, ref, o, "moved samples");
  EXPECT_FALSE(r.c2m.has_value());
  EXPECT_EQ(r.distance_method, "nearest_point");
  const Rigid3d err = r.registration.reference_from_cloud * cloud_from_ref;
  EXPECT_LT(err.rotation.angularDistance(Eigen::Quaterniond::Identity()), 1e-3);
  EXPECT_LT(err.translation.norm(), 0.02);
  // Two independent samples of the same surface, ~0.1 mm spacing: all within the threshold.
  EXPECT_LT(r.c2c.p95_mm, 0.2);
  EXPECT_EQ(r.c2c.outliers, 0u);
  EXPECT_GT(r.coverage, 0.97);
}

TEST(Compare, M3C2FieldsAndBadInput) {
  const Reference ref = ReferenceFromMesh(IcoSphere(10.0, 4), "sphere", 50000);
  PointCloud cloud = OffsetUpperHalf(IcoSphere(10.0, 4), 0.05, 42, 8);
  CompareOptions o;
  o.m3c2 = true;
  o.m3c2_options.projection_radius_mm = 0.6;
  const CompareResult r = Compare(cloud, ref, o);
  ASSERT_TRUE(r.m3c2.has_value());
  EXPECT_GT(r.m3c2->num_valid, cloud.size() / 2);
  EXPECT_NEAR(r.m3c2->stats.signed_mean_mm, 0.05, 0.01);
  EXPECT_NE(r.compared.Scalar("m3c2_lod95"), nullptr);
  o.threshold_mm = -1;
  EXPECT_THROW(Compare(cloud, ref, o), Error);
  EXPECT_THROW(Compare(PointCloud{}, ref, CompareOptions{}), Error);
}

// The reference's shared hierarchy, one built inside Compare, and brute force over every
// triangle give the same deviations; moving the cloud in gives the same result as copying it.
TEST(Compare, SharedHierarchyAndMovedCloudChangeNothing) {
  const TriangleMesh mesh = IcoSphere(10.0, 3);
  Reference shared = ReferenceFromMesh(mesh, "sphere", 5000);
  ASSERT_NE(shared.mesh_distance, nullptr);
  Reference own = shared;
  own.mesh_distance.reset();
  const PointCloud cloud = OffsetUpperHalf(mesh, 0.05, 43, 4);
  const CompareResult a = Compare(cloud, shared, CompareOptions{});
  const CompareResult b = Compare(cloud, own, CompareOptions{});
  const CompareResult c = Compare(PointCloud(cloud), shared, CompareOptions{});
  ASSERT_EQ(a.deviations_mm.size(), cloud.size());
  EXPECT_EQ(a.deviations_mm, b.deviations_mm);
  EXPECT_EQ(a.deviations_mm, c.deviations_mm);
  EXPECT_EQ(a.compared.points, c.compared.points);
  for (size_t i = 0; i < cloud.size(); i += 7) {
    double best = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < mesh.triangles.size(); ++t) {
      const auto& f = mesh.triangles[t];
      int feature = 0;
      const Eigen::Vector3d q =
          ClosestPointOnTriangle(cloud.points[i], mesh.vertices[static_cast<size_t>(f[0])],
                                 mesh.vertices[static_cast<size_t>(f[1])],
                                 mesh.vertices[static_cast<size_t>(f[2])], &feature);
      best = std::min(best, (cloud.points[i] - q).squaredNorm());
    }
    EXPECT_EQ(std::abs(a.deviations_mm[i]), std::sqrt(best));
  }
}

TEST(LoadReference, ReadsMeshesAndClouds) {
  slshadow::testing::TempDir tmp;
  const TriangleMesh mesh = IcoSphere(5.0, 2);
  WriteMesh(tmp / "m.stl", mesh);
  WriteMesh(tmp / "m.ply", mesh);
  PointCloud c;
  c.points = mesh.vertices;
  WritePly(tmp / "c.ply", c);
  EXPECT_TRUE(LoadReference(tmp / "m.stl", 1000).IsMesh());
  EXPECT_TRUE(LoadReference(tmp / "m.ply", 1000).IsMesh());
  const Reference rc = LoadReference(tmp / "c.ply");
  EXPECT_FALSE(rc.IsMesh());
  EXPECT_EQ(rc.cloud.size(), mesh.vertices.size());
  EXPECT_THROW(LoadReference(tmp / "m.xyz"), Error);
}

// Options as files: every field (nested registration, c2c, M3C2, artefacts, VDI/VDE 2634) written
// is read back from JSON and YAML; unknown keys at any level and bad values are refused.
TEST(CompareOptionsFile, RoundTripsEveryFieldAndRejectsUnknownKeys) {
  CompareOptions o;
  o.registration.method = RegistrationMethod::kIcp;
  o.registration.voxel_mm = 1.5;
  o.registration.feature_radius_mm = 7;
  o.registration.ransac_iterations = 1000;
  o.registration.ransac_inlier_fraction = 0.3;
  o.registration.seed = 42;
  o.registration.icp_max_correspondence_mm = 2;
  o.registration.icp_max_iterations = 30;
  o.registration.icp_max_points = 5000;
  o.registration.icp_tolerance = 1e-6;
  o.c2c.max_distance_mm = 4;
  o.c2c.local_model = LocalModel::kQuadric;
  o.c2c.local_model_neighbors = 15;
  o.threshold_mm = 0.1;
  o.coverage_radius_mm = 0.4;
  o.histogram_bins = 40;
  o.color_range_mm = 0.05;
  o.m3c2 = true;
  o.m3c2_options.projection_radius_mm = 0.8;
  o.m3c2_options.max_depth_mm = 3;
  o.m3c2_options.registration_error_mm = 0.01;
  o.m3c2_options.min_points = 5;
  ArtefactSpec artefacts;
  artefacts.search_margin_mm = 3;
  artefacts.spheres = {{"s1", Eigen::Vector3d(1, 2, 3), 25.0},
                       {"s2", Eigen::Vector3d(101, 2, 3), 25.0}};
  artefacts.pairs = {{"bar", "s1", "s2", 100.0}};
  artefacts.planes = {{"flat", Eigen::Vector3d(0, 0, 10), Eigen::Vector3d(0, 0, 1), 40.0}};
  o.artefacts = artefacts;
  o.vdi2634.exclude_fraction = 0.001;
  o.vdi2634.ransac_iterations = 200;
  o.vdi2634.min_points = 20;
  o.vdi2634.seed = 9;
  const nlohmann::json j = CompareOptionsToJson(o);
  for (const ConfigNode& node :
       {ConfigNode::FromJson(j, "c.json"), ConfigNode::ParseYaml(JsonToYaml(j), "c.yaml")}) {
    const CompareOptions r = CompareOptionsFromConfig(node);
    EXPECT_EQ(r.registration.method, RegistrationMethod::kIcp);
    EXPECT_EQ(r.registration.seed, 42u);
    EXPECT_EQ(r.c2c.local_model, LocalModel::kQuadric);
    EXPECT_EQ(r.threshold_mm, 0.1);
    EXPECT_EQ(r.color_range_mm, 0.05);
    EXPECT_TRUE(r.m3c2);
    ASSERT_TRUE(r.artefacts.has_value());
    EXPECT_EQ(r.artefacts->pairs.size(), 1u);
    EXPECT_EQ(r.artefacts->spheres[1].nominal_center_mm, Eigen::Vector3d(101, 2, 3));
    EXPECT_EQ(r.vdi2634.seed, 9u);
    EXPECT_EQ(CompareOptionsToJson(r), j);  // every other field
  }
  // Defaults (no registration, no artefacts) survive an empty file and a written default.
  const CompareOptions defaults;
  EXPECT_EQ(CompareOptionsToJson(
                CompareOptionsFromConfig(ConfigNode::FromJson(nlohmann::json::object(), "c.json"))),
            CompareOptionsToJson(defaults));
  const CompareOptions read_defaults =
      CompareOptionsFromConfig(ConfigNode::FromJson(CompareOptionsToJson(defaults), "c.json"));
  EXPECT_EQ(read_defaults.registration.method, RegistrationMethod::kNone);
  EXPECT_FALSE(read_defaults.artefacts.has_value());

  nlohmann::json typo = j;
  typo["registration"]["icp_iterations"] = 10;
  try {
    CompareOptionsFromConfig(ConfigNode::FromJson(typo, "c.json"));
    FAIL() << "unknown nested key accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("icp_iterations"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("c.json"), std::string::npos) << e.what();
  }
  nlohmann::json bad = j;
  bad["c2c"]["local_model"] = "cubic";
  EXPECT_THROW(CompareOptionsFromConfig(ConfigNode::FromJson(bad, "c.json")), Error);
  bad = j;
  bad["threshold_mm"] = -1;
  try {
    CompareOptionsFromConfig(ConfigNode::FromJson(bad, "c.json"));
    FAIL() << "negative threshold accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("threshold_mm"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace slshadow::compare
