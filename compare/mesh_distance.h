// Signed distance from points to a triangle mesh: exact closest point on the nearest triangle,
// found through a bounding-volume hierarchy (axis-aligned boxes, median splits, leaves of <= 4
// triangles, nearest-box-first traversal with pruning), so a query costs O(log n) triangles.
//
// Sign: positive on the side the outward normals point to (outside a closed mesh whose
// triangles are counter-clockwise seen from outside). The sign is taken from the angle-weighted
// pseudo-normal of the closest feature (face, edge or vertex; Baerentzen & Aanaes, "Signed
// distance computation using the angle weighted pseudonormal", IEEE TVCG 2005), which is exact
// for closed manifold meshes, also where the closest point lies on an edge or a vertex. Where
// the closest point is inside a face this is the face normal, as in CloudCompare's C2M.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"

namespace slshadow::compare {

struct MeshHit {
  double signed_distance_mm = 0.0;  // |p - closest|, signed by the pseudo-normal
  Eigen::Vector3d closest = Eigen::Vector3d::Zero();  // closest point on the mesh
  uint32_t triangle = 0;                               // index of the closest triangle
};

class MeshDistance {
 public:
  // Builds the hierarchy; the mesh is copied (vertices and triangles).
  explicit MeshDistance(const TriangleMesh& mesh);

  MeshHit Closest(const Eigen::Vector3d& point) const;
  // The same distance, warm-started with triangle `hint` (e.g. the previous query's hit when
  // queries run in spatially coherent order): its distance bounds the search from the start, so
  // fewer boxes are opened. On exact ties the hint may be the triangle returned.
  MeshHit Closest(const Eigen::Vector3d& point, uint32_t hint) const;
  size_t NumTriangles() const { return tris_.size(); }

 private:
  struct Node {
    Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
    uint32_t first = 0;   // leaf: first triangle in order_; inner: index of the left child
    uint32_t count = 0;   // leaf: number of triangles; inner: 0
    uint32_t right = 0;   // inner: index of the right child
  };
  struct Tri {
    Eigen::Vector3d a, b, c;
    Eigen::Vector3d face_normal;       // unit
    Eigen::Vector3d vertex_normal[3];  // angle-weighted pseudo-normals of a, b, c
    Eigen::Vector3d edge_normal[3];    // ab, bc, ca: sum of the adjacent face normals
  };
  uint32_t Build(uint32_t begin, uint32_t end, std::vector<Eigen::Vector3d>& centroids);

  std::vector<Tri> tris_;
  std::vector<uint32_t> order_;
  std::vector<Node> nodes_;
};

// Closest point on triangle (a, b, c) to p (Ericson, "Real-Time Collision Detection", 5.1.5).
// feature: 0 = face interior, 1..3 = vertex a, b, c, 4..6 = edge ab, bc, ca.
Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                       int* feature);

}  // namespace slshadow::compare
