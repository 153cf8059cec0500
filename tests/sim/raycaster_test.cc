#include "sim/raycaster.h"

#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "sim/shapes.h"
#include "tests/sim/sim_test_util.h"

namespace slshadow {
namespace {

using testing::MakePrimitive;
using testing::Pose;

// Primitive intersections against independent checks: the hit lies on the surface (implicit
// function ~ 0), and no point of the ray before it is inside the solid (sampled densely).
double SignedDistance(const SceneObject& o, const Eigen::Vector3d& p) {
  switch (o.type) {
    case ObjectType::kSphere:
      return p.norm() - o.radius_mm;
    case ObjectType::kBox: {
      const Eigen::Vector3d q = p.cwiseAbs() - o.size_mm / 2;
      return q.cwiseMax(0.0).norm() + std::min(q.maxCoeff(), 0.0);
    }
    case ObjectType::kCylinder: {
      const Eigen::Vector2d d(std::hypot(p.x(), p.y()) - o.radius_mm,
                              std::abs(p.z()) - o.height_mm / 2);
      return std::min(std::max(d.x(), d.y()), 0.0) + d.cwiseMax(0.0).norm();
    }
    default:
      return 0;
  }
}

TEST(IntersectPrimitiveTest, HitsLieOnTheSurfaceAndAreTheFirst) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1, 1);
  for (ObjectType type : {ObjectType::kSphere, ObjectType::kBox, ObjectType::kCylinder}) {
    SceneObject o = MakePrimitive(type, Rigid3d());
    o.radius_mm = 10;
    o.height_mm = 30;
    o.size_mm = Eigen::Vector3d(20, 12, 8);
    int hits = 0;
    for (int trial = 0; trial < 2000; ++trial) {
      const Eigen::Vector3d origin = Eigen::Vector3d(u(rng), u(rng), u(rng)).normalized() * 60;
      const Eigen::Vector3d target = Eigen::Vector3d(u(rng), u(rng), u(rng)) * 12;
      const Eigen::Vector3d dir = (target - origin).normalized();
      PrimitiveHit hit;
      const bool found = IntersectPrimitive(o, origin, dir, 0, 1e9, &hit);
      // Brute force: march along the ray in 0.01 mm steps to the first point inside.
      double first_inside = -1;
      for (double t = 0; t < 120; t += 0.01) {
        if (SignedDistance(o, origin + t * dir) <= 0) {
          first_inside = t;
          break;
        }
      }
      if (found && first_inside < 0) {
        // A grazing chord shorter than the march step: the exit must follow within it.
        PrimitiveHit exit;
        ASSERT_TRUE(IntersectPrimitive(o, origin, dir, hit.t + 1e-9, 1e9, &exit));
        EXPECT_LT(exit.t - hit.t, 0.02) << ToString(type) << " trial " << trial;
        continue;
      }
      ASSERT_EQ(found, first_inside >= 0) << ToString(type) << " trial " << trial;
      if (!found) continue;
      ++hits;
      EXPECT_NEAR(hit.t, first_inside, 0.011) << ToString(type);
      EXPECT_NEAR(SignedDistance(o, origin + hit.t * dir), 0, 1e-9) << ToString(type);
      EXPECT_NEAR(hit.normal.norm(), 1, 1e-12);
      EXPECT_LT(hit.normal.dot(dir), 0) << "outward normal faces the incoming ray";
    }
    EXPECT_GT(hits, 200) << ToString(type);
  }
}

TEST(IntersectPrimitiveTest, PlaneIsBoundedAndTwoSided) {
  SceneObject o = MakePrimitive(ObjectType::kPlane, Rigid3d());
  o.size_mm = Eigen::Vector3d(10, 4, 0);
  PrimitiveHit hit;
  ASSERT_TRUE(
      IntersectPrimitive(o, Eigen::Vector3d(4.9, 1.9, 5), Eigen::Vector3d(0, 0, -1), 0, 100, &hit));
  EXPECT_DOUBLE_EQ(hit.t, 5);
  ASSERT_TRUE(
      IntersectPrimitive(o, Eigen::Vector3d(0, 0, -5), Eigen::Vector3d(0, 0, 2), 0, 100, &hit));
  EXPECT_DOUBLE_EQ(hit.t, 2.5);
  EXPECT_FALSE(
      IntersectPrimitive(o, Eigen::Vector3d(5.1, 0, 5), Eigen::Vector3d(0, 0, -1), 0, 100, &hit));
  EXPECT_FALSE(
      IntersectPrimitive(o, Eigen::Vector3d(0, 2.1, 5), Eigen::Vector3d(0, 0, -1), 0, 100, &hit));
  EXPECT_FALSE(
      IntersectPrimitive(o, Eigen::Vector3d(0, 0, 5), Eigen::Vector3d(0, 0, -1), 0, 4.9, &hit))
      << "beyond t_far";
}

// The packet path and the single-ray path give identical hits on a scene with every geometry
// type (triangles, discs, user primitives), for random rays.
// Every geometry type (triangles, discs, primitives); `extra_spheres` more spheres behind the
// origin (never hit by the test rays, which go towards +z).
Scene MixedScene(int extra_spheres = 0) {
  Scene scene;
  SceneObject part;
  part.name = "part";
  part.type = ObjectType::kMesh;
  part.mesh = std::make_shared<const TriangleMesh>(MakeDemoPart(4.0));
  part.rig_from_object = Pose(Eigen::Vector3d(3.2, 0, 0), Eigen::Vector3d(0, 0, 500));
  scene.objects.push_back(part);
  SceneObject sphere = MakePrimitive(ObjectType::kSphere, Pose({0, 0, 0}, {60, 40, 430}));
  sphere.radius_mm = 15;
  scene.objects.push_back(sphere);
  SceneObject box = MakePrimitive(ObjectType::kBox, Pose({0.3, 0.2, 0.1}, {-70, -40, 440}));
  box.size_mm = Eigen::Vector3d(20, 30, 10);
  scene.objects.push_back(box);
  SceneObject cyl = MakePrimitive(ObjectType::kCylinder, Pose({1.2, 0, 0}, {-60, 50, 450}));
  cyl.radius_mm = 8;
  cyl.height_mm = 40;
  scene.objects.push_back(cyl);
  SceneObject plane = MakePrimitive(ObjectType::kPlane, Pose({0, 0, 0}, {0, 0, 560}));
  plane.size_mm = Eigen::Vector3d(300, 200, 0);
  scene.objects.push_back(plane);
  auto cloud = std::make_shared<PointCloud>();
  for (int i = 0; i < 40; ++i) {
    for (int j = 0; j < 40; ++j) {
      cloud->points.emplace_back(80 + i * 0.5, -60 + j * 0.5, 470 + 0.1 * i);
      cloud->normals.emplace_back(0, 0, -1);
    }
  }
  SceneObject discs;
  discs.name = "discs";
  discs.type = ObjectType::kPointCloud;
  discs.disc_radii_mm = DiscRadiiFromSpacing(cloud->points);
  discs.points = cloud;
  scene.objects.push_back(discs);
  for (int k = 0; k < extra_spheres; ++k) {
    SceneObject far = MakePrimitive(ObjectType::kSphere, Pose({0, 0, 0}, {30.0 * k, 0, -1000}));
    far.radius_mm = 10;
    scene.objects.push_back(far);
  }
  scene.Check("test");
  return scene;
}

RayPacket RandomPacket(std::mt19937& rng, int round) {
  std::uniform_real_distribution<float> u(-0.25f, 0.25f);
  RayPacket a;
  for (int i = 0; i < RayPacket::kSize; ++i) {
    const Eigen::Vector3f d = Eigen::Vector3f(u(rng), u(rng), 1).normalized();
    a.org_x[i] = 0;
    a.org_y[i] = 0;
    a.org_z[i] = 0;
    a.dir_x[i] = d.x();
    a.dir_y[i] = d.y();
    a.dir_z[i] = d.z();
    a.tnear[i] = 0;
    a.tfar[i] = 1e4f;
    a.active[i] = (i + round) % 7 != 0;  // some inactive lanes
  }
  return a;
}

// Lane i of two traces of the same ray: the same object and, on a hit, the same distance and
// normal, bit for bit.
::testing::AssertionResult SameHit(const RayPacket& a, const RayPacket& b, int i) {
  if (a.object[i] != b.object[i])
    return ::testing::AssertionFailure() << "object " << a.object[i] << " vs " << b.object[i];
  if (a.object[i] >= 0 && (a.tfar[i] != b.tfar[i] || a.ng_x[i] != b.ng_x[i] ||
                           a.ng_y[i] != b.ng_y[i] || a.ng_z[i] != b.ng_z[i])) {
    return ::testing::AssertionFailure()
           << "t " << a.tfar[i] << " vs " << b.tfar[i] << ", normal (" << a.ng_x[i] << ", "
           << a.ng_y[i] << ", " << a.ng_z[i] << ") vs (" << b.ng_x[i] << ", " << b.ng_y[i] << ", "
           << b.ng_z[i] << ")";
  }
  return ::testing::AssertionSuccess();
}

// Few primitives are tested outside Embree, many go in as Embree user geometry: both routes give
// the same hits and occlusions (here 4 vs 4 + 6 primitives, the extra ones never hit).
TEST(RayCasterTest, PrimitivesOutsideEmbreeEqualUserGeometry) {
  const Scene few = MixedScene(0), many = MixedScene(6);
  const RayCaster direct(few), embree(many);
  std::mt19937 rng(5);
  int primitive_hits = 0, occluded = 0;
  for (int round = 0; round < 300; ++round) {
    RayPacket a = RandomPacket(rng, round);
    RayPacket b = a;
    direct.Intersect(a, TraceMode::kPacket16, true);
    embree.Intersect(b, TraceMode::kPacket16, true);
    // Shadow-like segments from the hits towards a point off to the side.
    RayPacket sa = a;
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!a.active[i] || a.object[i] < 0) {
        sa.active[i] = false;
        continue;
      }
      const Eigen::Vector3f hit = a.tfar[i] * Eigen::Vector3f(a.dir_x[i], a.dir_y[i], a.dir_z[i]);
      const Eigen::Vector3f to = Eigen::Vector3f(-100, 20, 0) - hit;
      const Eigen::Vector3f l = to.normalized();
      const Eigen::Vector3f o = hit + 0.01f * l;
      sa.org_x[i] = o.x(), sa.org_y[i] = o.y(), sa.org_z[i] = o.z();
      sa.dir_x[i] = l.x(), sa.dir_y[i] = l.y(), sa.dir_z[i] = l.z();
      sa.tnear[i] = 0;
      sa.tfar[i] = to.norm() - 0.02f;
    }
    RayPacket sb = sa;
    direct.Occluded(sa, TraceMode::kPacket16);
    embree.Occluded(sb, TraceMode::kSingleRay);
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!a.active[i]) continue;
      ASSERT_TRUE(SameHit(a, b, i)) << "lane " << i;
      if (a.object[i] < 0) continue;
      primitive_hits += a.object[i] >= 1 && a.object[i] <= 4;
      ASSERT_EQ(sa.occluded[i], sb.occluded[i]);
      occluded += sa.occluded[i];
    }
  }
  EXPECT_GT(primitive_hits, 100);
  EXPECT_GT(occluded, 50);
}

// The plane test of up to 8 primitives outside Embree runs four lanes per vector (closest hits
// and shadow rays); with more primitives the plane is Embree user geometry, tested ray by ray by
// the scalar code. Both against hand-made cases whose arithmetic is exact (identity pose): rays
// parallel to the plane (also lying in it), hits exactly at tfar and tnear (not hits: the open
// interval) and one float step inside them, hits exactly on the plane's edge (inside) and one
// step beyond (outside), from either side. Inactive lanes are left untouched.
TEST(RayCasterTest, VectorisedPlaneTestEqualsScalarOnEdgeCases) {
  Scene direct_scene, embree_scene;
  SceneObject plane = MakePrimitive(ObjectType::kPlane, Rigid3d());
  plane.size_mm = Eigen::Vector3d(100, 60, 0);  // |x| <= 50, |y| <= 30
  direct_scene.objects.push_back(plane);
  embree_scene.objects.push_back(plane);
  for (int k = 0; k < 8; ++k) {  // 9 primitives: all go to Embree; these are never reached
    SceneObject far =
        MakePrimitive(ObjectType::kSphere, Pose({0, 0, 0}, {5000.0 + 30 * k, 5000, -5000}));
    far.radius_mm = 10;
    embree_scene.objects.push_back(far);
  }
  const RayCaster direct(direct_scene), embree(embree_scene);
  const float up = std::nextafter(10.0f, 20.0f), down = std::nextafter(10.0f, 0.0f);
  const float edge_out = std::nextafter(50.0f, 60.0f);
  const float inf = std::numeric_limits<float>::infinity();
  struct Case {
    float ox, oy, oz, dx, dy, dz, tnear, tfar;
    bool hit;
  };
  const Case cases[RayPacket::kSize] = {
      {0, 0, 10, 0, 0, -1, 0, 10, false},               // hit exactly at tfar
      {0, 0, 10, 0, 0, -1, 0, up, true},                // one step inside tfar
      {0, 0, 10, 0, 0, -1, 10, 20, false},              // exactly at tnear
      {0, 0, 10, 0, 0, -1, down, 20, true},             // one step inside tnear
      {0, 0, 5, 1, 0, 0, 0, inf, false},                // parallel, above
      {0, 0, 0, 1, 0, 0, 0, inf, false},                // parallel, in the plane (t = NaN)
      {0, 0, 0, 0, 0, 1, 0, inf, false},                // from the plane: t = -0, not > tnear
      {50, 0, 10, 0, 0, -1, 0, inf, true},              // on the x edge
      {edge_out, 0, 10, 0, 0, -1, 0, inf, false},       // one step beyond it
      {-20, 30, 10, 0, 0, -1, 0, inf, true},            // on the y edge
      {0, -30.5f, 10, 0, 0, -1, 0, inf, false},         // beyond it
      {0, 0, -4, 0, 0, 2, 0, inf, true},                // from below: t = 2
      {-20, 10, 8, 0.5f, -0.25f, -0.5f, 0, inf, true},  // oblique: t = 16 at (-12, 6)
      {-20, 10, 8, 0.5f, -0.25f, -0.5f, 0, 16, false},  // the same, tfar at the hit
      {0, 0, 10, 0, 0, 1, 0, inf, false},               // pointing away
      {49, 29, 1, 0, 0, -1, 0, inf, true}};             // near the corner
  for (const TraceMode mode : {TraceMode::kPacket16, TraceMode::kSingleRay}) {
    for (int inactive = -1; inactive < RayPacket::kSize; inactive += 5) {
      RayPacket p;
      for (int i = 0; i < RayPacket::kSize; ++i) {
        const Case& c = cases[i];
        p.org_x[i] = c.ox, p.org_y[i] = c.oy, p.org_z[i] = c.oz;
        p.dir_x[i] = c.dx, p.dir_y[i] = c.dy, p.dir_z[i] = c.dz;
        p.tnear[i] = c.tnear, p.tfar[i] = c.tfar;
        p.active[i] = i != inactive;
        p.object[i] = 77;  // sentinels: inactive lanes keep them
        p.occluded[i] = 5;
      }
      RayPacket a = p, b = p, sa = p, sb = p;
      direct.Intersect(a, mode, true);
      embree.Intersect(b, mode, true);
      direct.Occluded(sa, mode);
      embree.Occluded(sb, mode);
      for (int i = 0; i < RayPacket::kSize; ++i) {
        SCOPED_TRACE(::testing::Message() << "lane " << i << ", inactive lane " << inactive);
        if (i == inactive) {
          EXPECT_EQ(a.object[i], 77);
          EXPECT_EQ(sa.occluded[i], 5);
          EXPECT_EQ(a.tfar[i], p.tfar[i]);
          continue;
        }
        EXPECT_EQ(a.object[i], cases[i].hit ? 0 : -1);
        EXPECT_EQ(sa.occluded[i], cases[i].hit ? 1 : 0);
        ASSERT_TRUE(SameHit(a, b, i));
        EXPECT_EQ(sa.occluded[i], sb.occluded[i]);
        if (cases[i].hit) {
          EXPECT_EQ(a.ng_z[i], 1.0f);
          EXPECT_EQ(a.tfar[i], std::abs(cases[i].oz / cases[i].dz));
        } else {
          EXPECT_EQ(a.tfar[i], p.tfar[i]) << "a miss keeps tfar";
        }
      }
    }
  }
}

// The packet path and the single-ray path give identical hits on a scene with every geometry
// type (triangles, discs, user primitives), for random rays.
TEST(RayCasterTest, PacketEqualsSingleRay) {
  const Scene scene = MixedScene();
  const RayCaster caster(scene);

  std::mt19937 rng(3);
  int hits_by_object[6] = {0, 0, 0, 0, 0, 0};
  for (int round = 0; round < 400; ++round) {
    RayPacket a = RandomPacket(rng, round);
    RayPacket b = a;
    caster.Intersect(a, TraceMode::kPacket16, true);
    caster.Intersect(b, TraceMode::kSingleRay, true);
    RayPacket sa = a, sb = b;
    caster.Occluded(sa, TraceMode::kPacket16);
    caster.Occluded(sb, TraceMode::kSingleRay);
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!a.active[i]) continue;
      ASSERT_TRUE(SameHit(a, b, i)) << "lane " << i;
      if (a.object[i] < 0) continue;
      ++hits_by_object[a.object[i]];
    }
    // Occlusion of the segment up to the hit (tfar = hit distance): never occluded before the
    // closest hit, by both paths.
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!a.active[i] || a.object[i] < 0) continue;
      EXPECT_EQ(sa.occluded[i], sb.occluded[i]);
    }
  }
  for (int k = 0; k < 6; ++k) EXPECT_GT(hits_by_object[k], 0) << "object " << k << " never hit";
}

}  // namespace
}  // namespace slshadow
