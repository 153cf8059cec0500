#include "workflows/multiview/turntable_scene.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

#include "core/error.h"
#include "sim/raycaster.h"
#include "sim/shapes.h"
#include "tests/testing/error_of.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace {

// x' = R(n, theta) (x - p) + p by Rodrigues' formula, written out (not through Eigen's
// AngleAxis, which RigFromTableTurn uses).
Eigen::Vector3d Turned(const Eigen::Vector3d& x, const TurntableAxis& axis, double commanded_deg) {
  const double theta = (axis.angle_scale * commanded_deg + axis.angle_offset_deg) * M_PI / 180;
  const Eigen::Vector3d n = axis.direction_in_rig.normalized();
  const Eigen::Vector3d v = x - axis.point_in_rig_mm;
  return axis.point_in_rig_mm + v * std::cos(theta) + n.cross(v) * std::sin(theta) +
         n * n.dot(v) * (1 - std::cos(theta));
}

TEST(TurntableSceneTest, DemoSetupPutsTheAxisOnTheTableNormalThroughThePart) {
  const Scene demo = pipeline::LoadSceneOrDemo("");
  const TurntableSetup setup = DemoTurntableSetup();
  ASSERT_TRUE(setup.rig.turntable.has_value());
  const TurntableAxis& axis = *setup.rig.turntable;
  // The demo table's normal (its plane's local z) and the part's base centre (its local origin).
  const SceneObject* table = nullptr;
  const SceneObject* part = nullptr;
  for (const auto& o : demo.objects) {
    if (o.name == "table") table = &o;
    if (o.name == "part") part = &o;
  }
  ASSERT_TRUE(table && part);
  const Eigen::Vector3d normal = table->rig_from_object.rotation * Eigen::Vector3d::UnitZ();
  EXPECT_NEAR(std::abs(axis.direction_in_rig.dot(normal)), 1.0, 1e-12);
  EXPECT_LT(axis.direction_in_rig.z(), 0) << "up, towards the cameras";
  EXPECT_NEAR((axis.point_in_rig_mm - Eigen::Vector3d(0, 10, 545)).norm(), 0, 1e-9);
  // 20 degrees between the axis and the left camera's optical axis (reversed).
  EXPECT_NEAR(std::acos(-axis.direction_in_rig.z()) * 180 / M_PI, 20.0, 1e-6);
  // The fixed table plane is gone, a disc under the part took its place; the part is unchanged.
  ASSERT_EQ(setup.scene.objects.size(), 2u);
  EXPECT_EQ(setup.scene.objects[0].name, "part");
  const SceneObject& disc = setup.scene.objects[1];
  EXPECT_EQ(disc.name, "turntable");
  EXPECT_EQ(disc.type, ObjectType::kCylinder);
  const Eigen::Vector3d disc_top = disc.rig_from_object * Eigen::Vector3d(0, 0, disc.height_mm / 2);
  EXPECT_NEAR((disc_top - (axis.point_in_rig_mm - 0.05 * axis.direction_in_rig)).norm(), 0, 1e-9);
  EXPECT_NEAR((disc.rig_from_object.rotation * Eigen::Vector3d::UnitZ()).dot(axis.direction_in_rig),
              1, 1e-12);
  EXPECT_EQ(PartSurface(setup.scene).NumTriangles(), part->mesh->NumTriangles());
  EXPECT_FALSE(setup.scene.artefacts.contains("table"));
}

TEST(TurntableSceneTest, TurnedSceneMatchesItsDefinition) {
  TurntableSetup setup = DemoTurntableSetup();
  TurntableAxis axis = *setup.rig.turntable;
  axis.angle_offset_deg = 0.7;
  axis.angle_scale = 1.01;
  for (const double a : {0.0, 30.0, -95.0, 200.0}) {
    const Scene turned = SceneAtTableAngle(setup.scene, axis, a);
    ASSERT_EQ(turned.objects.size(), setup.scene.objects.size());
    for (size_t k = 0; k < turned.objects.size(); ++k) {
      const SceneObject& before = setup.scene.objects[k];
      const SceneObject& after = turned.objects[k];
      for (const Eigen::Vector3d& local :
           {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(80, -50, 30), Eigen::Vector3d(-12, 40, 50)}) {
        const Eigen::Vector3d expected = Turned(before.rig_from_object * local, axis, a);
        EXPECT_NEAR((after.rig_from_object * local - expected).norm(), 0, 1e-9)
            << after.name << " at " << a << " deg";
      }
    }
    // Points on the axis stay where they are.
    const Scene at = SceneAtTableAngle(setup.scene, axis, a);
    EXPECT_NEAR((at.objects[0].rig_from_object.translation - axis.point_in_rig_mm).norm(), 0, 1e-9);
    // The artefact (the dome's sphere centre) moved with the part.
    const auto& c = turned.artefacts["part"]["dome_sphere_center_in_rig_mm"];
    const auto& c0 = setup.scene.artefacts["part"]["dome_sphere_center_in_rig_mm"];
    const Eigen::Vector3d expected = Turned(Eigen::Vector3d(c0[0], c0[1], c0[2]), axis, a);
    EXPECT_NEAR((Eigen::Vector3d(c[0], c[1], c[2]) - expected).norm(), 0, 1e-9);
    EXPECT_TRUE(turned.source_config.is_null());
  }
}

// The nearest hit of the ray o + t d (t > 0) with the triangles, by brute force (Moller-Trumbore
// in double): infinity when none.
double BruteForceHit(const std::vector<Eigen::Vector3d>& v,
                     const std::vector<Eigen::Vector3i>& tris, const Eigen::Vector3d& o,
                     const Eigen::Vector3d& d) {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : tris) {
    const Eigen::Vector3d& a = v[static_cast<size_t>(t[0])];
    const Eigen::Vector3d e1 = v[static_cast<size_t>(t[1])] - a,
                          e2 = v[static_cast<size_t>(t[2])] - a;
    const Eigen::Vector3d p = d.cross(e2);
    const double det = e1.dot(p);
    if (std::abs(det) < 1e-12) continue;
    const Eigen::Vector3d s = o - a;
    const double u = s.dot(p) / det;
    if (u < 0 || u > 1) continue;
    const Eigen::Vector3d q = s.cross(e1);
    const double w = d.dot(q) / det;
    if (w < 0 || u + w > 1) continue;
    const double t_hit = e2.dot(q) / det;
    if (t_hit > 1e-9) best = std::min(best, t_hit);
  }
  return best;
}

TEST(TurntableSceneTest, RaysHitTheTurnedPartWhereItsDefinitionPutsIt) {
  const TurntableSetup setup = DemoTurntableSetup();
  const TurntableAxis& axis = *setup.rig.turntable;
  const SceneObject& part = setup.scene.objects[0];
  const TriangleMesh& mesh = *part.mesh;
  for (const double a : {0.0, 45.0, 120.0, 270.0}) {
    const Scene turned = SceneAtTableAngle(setup.scene, axis, a);
    const RayCaster caster(turned);
    // The part's triangles where the definition (Rodrigues, above) puts them at this angle.
    std::vector<Eigen::Vector3d> v;
    for (const auto& x : mesh.vertices) v.push_back(Turned(part.rig_from_object * x, axis, a));
    int hits = 0;
    for (size_t k = 0; k < mesh.triangles.size(); k += 4001) {
      const auto& t = mesh.triangles[k];
      const Eigen::Vector3d target = (v[static_cast<size_t>(t[0])] + v[static_cast<size_t>(t[1])] +
                                      v[static_cast<size_t>(t[2])]) /
                                     3;
      const Eigen::Vector3d dir = target.normalized();  // from the left camera's centre (origin)
      const double expected = BruteForceHit(v, mesh.triangles, Eigen::Vector3d::Zero(), dir);
      RayPacket packet{};
      packet.dir_x[0] = static_cast<float>(dir.x());
      packet.dir_y[0] = static_cast<float>(dir.y());
      packet.dir_z[0] = static_cast<float>(dir.z());
      packet.tfar[0] = 2000;
      packet.active[0] = 1;
      caster.Intersect(packet, TraceMode::kSingleRay, false);
      ASSERT_TRUE(std::isfinite(expected));
      // The disc lies under the part: where the ray reaches the part, Embree finds the part at
      // the distance the definition gives.
      if (packet.object[0] != 0) continue;
      EXPECT_NEAR(packet.tfar[0], expected, 2e-3) << "triangle " << k << " at " << a << " deg";
      ++hits;
    }
    EXPECT_GT(hits, 15) << a << " deg";
  }
}

TEST(TurntableSceneTest, FixedObjectsStayAndBadInputs) {
  const TurntableSetup setup = DemoTurntableSetup();
  const Scene turned = SceneAtTableAngle(setup.scene, *setup.rig.turntable, 90, {"turntable"});
  EXPECT_EQ(turned.objects[1].rig_from_object.translation,
            setup.scene.objects[1].rig_from_object.translation);
  EXPECT_GT((turned.objects[0].rig_from_object * Eigen::Vector3d(80, 0, 0) -
             setup.scene.objects[0].rig_from_object * Eigen::Vector3d(80, 0, 0))
                .norm(),
            100.0);
  EXPECT_NE(testing::ErrorOf([&] {
              SceneAtTableAngle(setup.scene, *setup.rig.turntable, 1, {"floor"});
            }).find("no object named 'floor' to keep fixed"),
            std::string::npos);
  TableDisc disc;
  disc.radius_mm = -1;
  EXPECT_NE(testing::ErrorOf([&] {
              WithTableDisc(setup.scene, *setup.rig.turntable, disc);
            }).find("radius_mm must be positive (got -1)"),
            std::string::npos);
  EXPECT_NE(testing::ErrorOf([&] {
              WithTableDisc(setup.scene, *setup.rig.turntable);
            }).find("already has an object named 'turntable'"),
            std::string::npos);
  Scene no_mesh;
  no_mesh.name = "empty";
  EXPECT_THROW(PartSurface(no_mesh), Error);
}

TEST(TurntableSceneTest, OcclusionPartStandsOnTheTableToo) {
  Scene scene = pipeline::LoadSceneOrDemo("");
  scene.objects[0].mesh = std::make_shared<const TriangleMesh>(MakeOcclusionPart(2.0));
  const TurntableSetup setup =
      MakeTurntableSetup(pipeline::LoadRigOrDemo(""), scene, "part", {"table"});
  EXPECT_EQ(PartSurface(setup.scene).NumTriangles(), MakeOcclusionPart(2.0).NumTriangles());
  EXPECT_THROW(MakeTurntableSetup(pipeline::LoadRigOrDemo(""), scene, "block"), Error);
}

}  // namespace
}  // namespace slshadow::multiview
