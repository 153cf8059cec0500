// TriangleMesh: indexed triangles (mm), read from STL (binary and ASCII), PLY and OBJ, written as
// binary PLY or binary STL. Used by sim/ (scene parts), compare/ (cloud-to-mesh) and tests.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace slshadow {

struct TriangleMesh {
  std::vector<Eigen::Vector3d> vertices;
  std::vector<Eigen::Vector3i> triangles;  // counter-clockwise seen from outside (normal outward)

  size_t NumTriangles() const { return triangles.size(); }
  bool empty() const { return triangles.empty(); }
  // Unit normal of triangle i by the right-hand rule; zero for a degenerate triangle.
  Eigen::Vector3d FaceNormal(size_t i) const;
  double TriangleArea(size_t i) const;
  double SurfaceArea() const;
  Eigen::Vector3d BoundsMin() const;
  Eigen::Vector3d BoundsMax() const;
  // Applies p -> rotation * p + translation (e.g. a scene pose) and a unit scale first.
  void Transform(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                 double scale = 1.0);
  void Append(const TriangleMesh& other);

  // Throws slshadow::Error naming `what` when the mesh is empty, an index is out of range, a
  // vertex is not finite, or (when reject_degenerate) a triangle has (near) zero area
  // (area < 1e-12 x the squared bounding-box diagonal).
  void Check(const std::string& what, bool reject_degenerate = true) const;
  // Number of edges shared by more than two triangles (non-manifold edges).
  size_t CountNonManifoldEdges() const;
};

// Reads by extension: .stl (binary or ASCII, detected from the content; duplicate vertices are
// merged exactly), .ply (vertex x/y/z + face vertex_indices / vertex_index; polygons are fanned
// into triangles), .obj (v and f lines; f accepts v, v/t, v/t/n, v//n and negative indices;
// polygons fanned). Throws slshadow::Error naming the file and the line or element on bad input.
TriangleMesh ReadMesh(const std::filesystem::path& path);
// Writes atomically by extension: .ply (binary little-endian, double vertices) or .stl (binary).
void WriteMesh(const std::filesystem::path& path, const TriangleMesh& mesh);

}  // namespace slshadow
