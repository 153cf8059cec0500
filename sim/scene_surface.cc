#include "sim/scene_surface.h"

#include <cmath>
#include <cstdint>
#include <utility>

#include "core/error.h"
#include "sim/shapes.h"

namespace slshadow {
namespace {

TriangleMesh ObjectSurfaceInRig(const SceneObject& object, TriangleMesh part) {
  part.Transform(object.rig_from_object.rotation.toRotationMatrix(),
                 object.rig_from_object.translation);
  return part;
}

}  // namespace

TriangleMesh SceneSurface(const Scene& scene, const std::string& what, int plane_cells) {
  SLSHADOW_CHECK(plane_cells >= 1);
  TriangleMesh surface;
  for (const auto& object : scene.objects) {
    TriangleMesh part;
    const double hx = object.size_mm.x() / 2, hy = object.size_mm.y() / 2;
    if (object.type == ObjectType::kMesh) {
      part = *object.mesh;
    } else if (object.type == ObjectType::kPlane && plane_cells == 1) {
      part.vertices = {{-hx, -hy, 0}, {hx, -hy, 0}, {hx, hy, 0}, {-hx, hy, 0}};
      part.triangles = {{0, 1, 2}, {0, 2, 3}};
    } else if (object.type == ObjectType::kPlane) {
      const int n = plane_cells;
      for (int j = 0; j <= n; ++j) {
        for (int i = 0; i <= n; ++i)
          part.vertices.emplace_back(-hx + 2 * hx * i / n, -hy + 2 * hy * j / n, 0);
      }
      for (int j = 0; j < n; ++j) {
        for (int i = 0; i < n; ++i) {
          const int a = j * (n + 1) + i;
          part.triangles.emplace_back(a, a + 1, a + n + 2);
          part.triangles.emplace_back(a, a + n + 2, a + n + 1);
        }
      }
    } else {
      SLSHADOW_THROW(what, ": object '", object.name, "' is a ", ToString(object.type),
                     "; only meshes and planes have a surface to compare against");
    }
    surface.Append(ObjectSurfaceInRig(object, std::move(part)));
  }
  return surface;
}

TriangleMesh SceneMeshSurface(const Scene& scene) {
  TriangleMesh surface;
  for (const auto& object : scene.objects) {
    if (object.type == ObjectType::kMesh) surface.Append(ObjectSurfaceInRig(object, *object.mesh));
  }
  return surface;
}

std::vector<Eigen::Vector3d> LitVisibleSurface(const GeometryBuffer& geometry) {
  std::vector<Eigen::Vector3d> points;
  for (int y = 0; y < geometry.height; y += 2) {
    const uint8_t* vis = geometry.visibility.ptr<uint8_t>(y);
    const cv::Vec3f* p = geometry.point_in_rig.ptr<cv::Vec3f>(y);
    for (int x = 0; x < geometry.width; x += 2) {
      if (vis[x] == 2) points.emplace_back(p[x][0], p[x][1], p[x][2]);
    }
  }
  return points;
}

namespace {

constexpr int kSegments = 512;

// The box |x|, |y|, |z| <= size / 2: exact, 12 triangles with outward normals.
TriangleMesh BoxMesh(const Eigen::Vector3d& size) {
  TriangleMesh m;
  const Eigen::Vector3d h = size / 2;
  for (int k = 0; k < 8; ++k) {
    m.vertices.emplace_back(k & 1 ? h.x() : -h.x(), k & 2 ? h.y() : -h.y(), k & 4 ? h.z() : -h.z());
  }
  // Two triangles per face, counter-clockwise seen from outside.
  m.triangles = {{0, 2, 3}, {0, 3, 1}, {4, 5, 7}, {4, 7, 6},   // z = -h, z = +h
                 {0, 1, 5}, {0, 5, 4}, {2, 6, 7}, {2, 7, 3},   // y = -h, y = +h
                 {0, 4, 6}, {0, 6, 2}, {1, 3, 7}, {1, 7, 5}};  // x = -h, x = +h
  return m;
}

// A closed cylinder of radius r along z, from z = -h/2 to h/2: `sides` facets and two capped ends.
TriangleMesh CylinderMesh(double r, double h, int sides) {
  TriangleMesh m;
  for (int k = 0; k < sides; ++k) {
    const double a = 2 * M_PI * k / sides;
    m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), -h / 2);
    m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), h / 2);
  }
  const int bottom = static_cast<int>(m.vertices.size());
  m.vertices.emplace_back(0, 0, -h / 2);
  m.vertices.emplace_back(0, 0, h / 2);
  for (int k = 0; k < sides; ++k) {
    const int a0 = 2 * k, a1 = 2 * k + 1, b0 = 2 * ((k + 1) % sides), b1 = b0 + 1;
    m.triangles.emplace_back(a0, b0, b1);  // outward (counter-clockwise seen from outside)
    m.triangles.emplace_back(a0, b1, a1);
    m.triangles.emplace_back(bottom, b0, a0);
    m.triangles.emplace_back(bottom + 1, a1, b1);
  }
  return m;
}

}  // namespace

TriangleMesh GroundTruthSurface(const Scene& scene, const std::string& what) {
  TriangleMesh surface;
  for (const SceneObject& object : scene.objects) {
    TriangleMesh part;
    if (object.type == ObjectType::kSphere) {
      part = MakeSphereMesh(object.radius_mm, kSegments);
    } else if (object.type == ObjectType::kCylinder) {
      part = CylinderMesh(object.radius_mm, object.height_mm, kSegments);
    } else if (object.type == ObjectType::kBox) {
      part = BoxMesh(object.size_mm);
    } else {
      Scene one;
      one.objects = {object};
      surface.Append(SceneSurface(one, what));
      continue;
    }
    part.Transform(object.rig_from_object.rotation.toRotationMatrix(),
                   object.rig_from_object.translation);
    surface.Append(part);
  }
  return surface;
}

}  // namespace slshadow
