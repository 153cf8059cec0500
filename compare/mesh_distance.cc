#include "compare/mesh_distance.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#include "core/error.h"

namespace slshadow::compare {
namespace {

double BoxDistanceSq(const Eigen::Vector3d& p, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  double d = 0.0;
  for (int k = 0; k < 3; ++k) {
    const double v = p[k] < lo[k] ? lo[k] - p[k] : (p[k] > hi[k] ? p[k] - hi[k] : 0.0);
    d += v * v;
  }
  return d;
}

double AngleBetween(const Eigen::Vector3d& u, const Eigen::Vector3d& v) {
  return std::atan2(u.cross(v).norm(), u.dot(v));
}

}  // namespace

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                       int* feature) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) {
    *feature = 1;
    return a;
  }
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) {
    *feature = 2;
    return b;
  }
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    *feature = 4;
    return a + (d1 / (d1 - d3)) * ab;
  }
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) {
    *feature = 3;
    return c;
  }
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    *feature = 6;
    return a + (d2 / (d2 - d6)) * ac;
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    *feature = 5;
    return b + ((d4 - d3) / ((d4 - d3) + (d5 - d6))) * (c - b);
  }
  const double denom = 1.0 / (va + vb + vc);
  *feature = 0;
  return a + ab * (vb * denom) + ac * (vc * denom);
}

MeshDistance::MeshDistance(const TriangleMesh& mesh) {
  mesh.Check("reference mesh", /*reject_degenerate=*/false);
  const size_t nt = mesh.triangles.size();
  SLSHADOW_THROW_IF(nt >= std::numeric_limits<uint32_t>::max(), "reference mesh: too many triangles");
  // Pseudo-normals: angle-weighted vertex normals, and per undirected edge the sum of the
  // adjacent face normals.
  std::vector<Eigen::Vector3d> vnormal(mesh.vertices.size(), Eigen::Vector3d::Zero());
  std::unordered_map<uint64_t, Eigen::Vector3d> enormal;
  enormal.reserve(nt * 2);
  auto edge_key = [](int i, int j) {
    const auto lo = static_cast<uint64_t>(std::min(i, j)), hi = static_cast<uint64_t>(std::max(i, j));
    return (lo << 32) | hi;
  };
  tris_.resize(nt);
  std::vector<Eigen::Vector3d> centroids(nt);
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    Tri& tri = tris_[t];
    tri.a = mesh.vertices[static_cast<size_t>(f[0])];
    tri.b = mesh.vertices[static_cast<size_t>(f[1])];
    tri.c = mesh.vertices[static_cast<size_t>(f[2])];
    const Eigen::Vector3d n = (tri.b - tri.a).cross(tri.c - tri.a);
    const double len = n.norm();
    tri.face_normal = len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
    const Eigen::Vector3d* v[3] = {&tri.a, &tri.b, &tri.c};
    for (int k = 0; k < 3; ++k) {
      const double angle = AngleBetween(*v[(k + 1) % 3] - *v[k], *v[(k + 2) % 3] - *v[k]);
      vnormal[static_cast<size_t>(f[k])] += angle * tri.face_normal;
      auto [it, inserted] = enormal.try_emplace(edge_key(f[k], f[(k + 1) % 3]), Eigen::Vector3d::Zero());
      it->second += tri.face_normal;
    }
    centroids[t] = (tri.a + tri.b + tri.c) / 3.0;
  }
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) {
      tris_[t].vertex_normal[k] = vnormal[static_cast<size_t>(f[k])];
      tris_[t].edge_normal[k] = enormal[edge_key(f[k], f[(k + 1) % 3])];
    }
  }
  order_.resize(nt);
  for (size_t t = 0; t < nt; ++t) order_[t] = static_cast<uint32_t>(t);
  nodes_.reserve(2 * nt / 4 + 2);
  Build(0, static_cast<uint32_t>(nt), centroids);
}

uint32_t MeshDistance::Build(uint32_t begin, uint32_t end, std::vector<Eigen::Vector3d>& centroids) {
  const auto node_index = static_cast<uint32_t>(nodes_.size());
  nodes_.push_back({});
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  Eigen::Vector3d clo = lo, chi = hi;
  for (uint32_t i = begin; i < end; ++i) {
    const Tri& t = tris_[order_[i]];
    lo = lo.cwiseMin(t.a).cwiseMin(t.b).cwiseMin(t.c);
    hi = hi.cwiseMax(t.a).cwiseMax(t.b).cwiseMax(t.c);
    clo = clo.cwiseMin(centroids[order_[i]]);
    chi = chi.cwiseMax(centroids[order_[i]]);
  }
  nodes_[node_index].lo = lo;
  nodes_[node_index].hi = hi;
  if (end - begin <= 4) {
    nodes_[node_index].first = begin;
    nodes_[node_index].count = end - begin;
    return node_index;
  }
  int axis = 0;
  (chi - clo).maxCoeff(&axis);
  const uint32_t mid = begin + (end - begin) / 2;
  std::nth_element(order_.begin() + begin, order_.begin() + mid, order_.begin() + end,
                   [&](uint32_t x, uint32_t y) { return centroids[x][axis] < centroids[y][axis]; });
  const uint32_t left = Build(begin, mid, centroids);
  const uint32_t right = Build(mid, end, centroids);
  nodes_[node_index].first = left;
  nodes_[node_index].right = right;
  nodes_[node_index].count = 0;
  return node_index;
}

MeshHit MeshDistance::Closest(const Eigen::Vector3d& p) const {
  return Closest(p, std::numeric_limits<uint32_t>::max());
}

MeshHit MeshDistance::Closest(const Eigen::Vector3d& p, uint32_t hint) const {
  MeshHit hit;
  double best = std::numeric_limits<double>::infinity();
  int best_feature = 0;
  uint32_t best_tri = 0;
  if (hint < tris_.size()) {
    const Tri& t = tris_[hint];
    hit.closest = ClosestPointOnTriangle(p, t.a, t.b, t.c, &best_feature);
    best = (p - hit.closest).squaredNorm();
    best_tri = hint;
  }
  // Stack of (node, box distance); children visited nearest first.
  struct Entry {
    uint32_t node;
    double d2;
  };
  Entry stack[128];
  int top = 0;
  stack[top++] = {0, BoxDistanceSq(p, nodes_[0].lo, nodes_[0].hi)};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.d2 >= best) continue;
    const Node& node = nodes_[e.node];
    if (node.count > 0) {
      for (uint32_t i = node.first; i < node.first + node.count; ++i) {
        const Tri& t = tris_[order_[i]];
        int feature = 0;
        const Eigen::Vector3d q = ClosestPointOnTriangle(p, t.a, t.b, t.c, &feature);
        const double d2 = (p - q).squaredNorm();
        if (d2 < best) {
          best = d2;
          best_feature = feature;
          best_tri = order_[i];
          hit.closest = q;
        }
      }
      continue;
    }
    const uint32_t l = node.first;
    const uint32_t r = node.right;
    const double dl = BoxDistanceSq(p, nodes_[l].lo, nodes_[l].hi);
    const double dr = BoxDistanceSq(p, nodes_[r].lo, nodes_[r].hi);
    SLSHADOW_CHECK(top + 2 <= 128);
    if (dl < dr) {
      stack[top++] = {r, dr};
      stack[top++] = {l, dl};
    } else {
      stack[top++] = {l, dl};
      stack[top++] = {r, dr};
    }
  }
  const Tri& t = tris_[best_tri];
  Eigen::Vector3d n;
  switch (best_feature) {
    case 0: n = t.face_normal; break;
    case 1: case 2: case 3: n = t.vertex_normal[best_feature - 1]; break;
    default: n = t.edge_normal[best_feature - 4]; break;
  }
  const double dist = std::sqrt(best);
  hit.signed_distance_mm = (p - hit.closest).dot(n) < 0 ? -dist : dist;
  hit.triangle = best_tri;
  return hit;
}

}  // namespace slshadow::compare
