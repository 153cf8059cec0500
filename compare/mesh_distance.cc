#include "compare/mesh_distance.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <unordered_map>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "core/error.h"

namespace slshadow::compare {
namespace {

// Float bounds that contain the double value.
float Down(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) > v) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}
float Up(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) < v) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

double Area(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  const Eigen::Vector3d d = (hi - lo).cwiseMax(0.0);
  return d.x() * d.y() + d.y() * d.z() + d.z() * d.x();
}

double AngleBetween(const Eigen::Vector3d& u, const Eigen::Vector3d& v) {
  return std::atan2(u.cross(v).norm(), u.dot(v));
}

}  // namespace

namespace {

// The closest-point routine, inlined into the traversal; ClosestPointOnTriangle is the same code.
inline Eigen::Vector3d ClosestPoint(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
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

}  // namespace

double MeshDistance::SignedDistance(const Eigen::Vector3d& point, const Eigen::Vector3d& closest,
                                    uint32_t triangle, int feature, double squared_distance) const {
  const TriNormals& t = normals_[triangle];
  const Eigen::Vector3d* n = nullptr;
  switch (feature) {
    case 0:
      n = &t.face;
      break;
    case 1:
    case 2:
    case 3:
      n = &t.vertex[feature - 1];
      break;
    default:
      n = &t.edge[feature - 4];
      break;
  }
  const double dist = std::sqrt(squared_distance);
  return (point - closest).dot(*n) < 0 ? -dist : dist;
}

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                                       int* feature) {
  return ClosestPoint(p, a, b, c, feature);
}

// Binary node of the build (double bounds); collapsed into 4-wide nodes afterwards.
struct MeshDistance::BuildNode {
  Eigen::Vector3d lo = Eigen::Vector3d::Zero(), hi = Eigen::Vector3d::Zero();
  uint32_t begin = 0, end = 0;  // triangles order[begin, end) (leaf)
  int left = -1, right = -1;    // children (inner)
};

namespace {

struct Builder {
  const std::vector<Eigen::Vector3d>& lo;  // per triangle
  const std::vector<Eigen::Vector3d>& hi;
  const std::vector<Eigen::Vector3d>& centroid;
  std::vector<uint32_t>& order;
};

constexpr uint32_t kLeafSize = 1;
constexpr int kBins = 16;
constexpr int kMaxSahDepth = 48;  // below this depth, median splits (bounded depth)

template <typename Node>
int BuildBinary(Builder& b, std::vector<Node>& nodes, uint32_t begin, uint32_t end, int depth) {
  const int index = static_cast<int>(nodes.size());
  nodes.push_back({});
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  Eigen::Vector3d clo = lo, chi = hi;
  for (uint32_t i = begin; i < end; ++i) {
    const uint32_t t = b.order[i];
    lo = lo.cwiseMin(b.lo[t]);
    hi = hi.cwiseMax(b.hi[t]);
    clo = clo.cwiseMin(b.centroid[t]);
    chi = chi.cwiseMax(b.centroid[t]);
  }
  nodes[static_cast<size_t>(index)].lo = lo;
  nodes[static_cast<size_t>(index)].hi = hi;
  nodes[static_cast<size_t>(index)].begin = begin;
  nodes[static_cast<size_t>(index)].end = end;
  if (end - begin <= kLeafSize) return index;
  int axis = 0;
  const double extent = (chi - clo).maxCoeff(&axis);
  uint32_t mid = begin + (end - begin) / 2;
  bool split = false;
  if (extent > 0 && depth < kMaxSahDepth) {
    // Binned SAH along the widest centroid axis.
    struct Bin {
      Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
      Eigen::Vector3d hi = -Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
      uint32_t n = 0;
    };
    Bin bins[kBins];
    const double scale = kBins / extent;
    auto bin_of = [&](uint32_t t) {
      return std::min(kBins - 1, static_cast<int>((b.centroid[t][axis] - clo[axis]) * scale));
    };
    for (uint32_t i = begin; i < end; ++i) {
      const uint32_t t = b.order[i];
      Bin& bin = bins[bin_of(t)];
      bin.lo = bin.lo.cwiseMin(b.lo[t]);
      bin.hi = bin.hi.cwiseMax(b.hi[t]);
      ++bin.n;
    }
    double right_area[kBins];
    uint32_t right_n[kBins];
    Bin acc;
    for (int k = kBins - 1; k > 0; --k) {
      acc.lo = acc.lo.cwiseMin(bins[k].lo);
      acc.hi = acc.hi.cwiseMax(bins[k].hi);
      acc.n += bins[k].n;
      right_area[k] = acc.n ? Area(acc.lo, acc.hi) : 0.0;
      right_n[k] = acc.n;
    }
    Bin left;
    double best_cost = std::numeric_limits<double>::infinity();
    int best_k = -1;
    for (int k = 1; k < kBins; ++k) {
      left.lo = left.lo.cwiseMin(bins[k - 1].lo);
      left.hi = left.hi.cwiseMax(bins[k - 1].hi);
      left.n += bins[k - 1].n;
      if (left.n == 0 || right_n[k] == 0) continue;
      const double cost = Area(left.lo, left.hi) * left.n + right_area[k] * right_n[k];
      if (cost < best_cost) {
        best_cost = cost;
        best_k = k;
      }
    }
    if (best_k > 0) {
      const auto it = std::partition(b.order.begin() + begin, b.order.begin() + end,
                                     [&](uint32_t t) { return bin_of(t) < best_k; });
      mid = static_cast<uint32_t>(it - b.order.begin());
      split = mid > begin && mid < end;
    }
  }
  if (!split) {
    mid = begin + (end - begin) / 2;
    std::nth_element(b.order.begin() + begin, b.order.begin() + mid, b.order.begin() + end,
                     [&](uint32_t x, uint32_t y) {
                       return b.centroid[x][axis] < b.centroid[y][axis] ||
                              (b.centroid[x][axis] == b.centroid[y][axis] && x < y);
                     });
  }
  const int l = BuildBinary(b, nodes, begin, mid, depth + 1);
  const int r = BuildBinary(b, nodes, mid, end, depth + 1);
  nodes[static_cast<size_t>(index)].left = l;
  nodes[static_cast<size_t>(index)].right = r;
  return index;
}

}  // namespace

MeshDistance::MeshDistance(const TriangleMesh& mesh) {
  mesh.Check("reference mesh", /*reject_degenerate=*/false);
  const size_t nt = mesh.triangles.size();
  SLSHADOW_THROW_IF(nt == 0, "reference mesh: no triangles");
  SLSHADOW_THROW_IF(nt >= std::numeric_limits<uint32_t>::max() / 2,
                    "reference mesh: too many triangles");
  // Pseudo-normals: angle-weighted vertex normals, and per undirected edge the sum of the
  // adjacent face normals.
  std::vector<Eigen::Vector3d> vnormal(mesh.vertices.size(), Eigen::Vector3d::Zero());
  std::unordered_map<uint64_t, Eigen::Vector3d> enormal;
  enormal.reserve(nt * 2);
  auto edge_key = [](int i, int j) {
    const auto lo = static_cast<uint64_t>(std::min(i, j)),
               hi = static_cast<uint64_t>(std::max(i, j));
    return (lo << 32) | hi;
  };
  normals_.resize(nt);
  std::vector<Eigen::Vector3d> tlo(nt), thi(nt), centroids(nt);
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(f[2])];
    const Eigen::Vector3d n = (b - a).cross(c - a);
    const double len = n.norm();
    normals_[t].face = len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
    const Eigen::Vector3d* v[3] = {&a, &b, &c};
    for (int k = 0; k < 3; ++k) {
      const double angle = AngleBetween(*v[(k + 1) % 3] - *v[k], *v[(k + 2) % 3] - *v[k]);
      vnormal[static_cast<size_t>(f[k])] += angle * normals_[t].face;
      auto [it, inserted] =
          enormal.try_emplace(edge_key(f[k], f[(k + 1) % 3]), Eigen::Vector3d::Zero());
      it->second += normals_[t].face;
    }
    tlo[t] = a.cwiseMin(b).cwiseMin(c);
    thi[t] = a.cwiseMax(b).cwiseMax(c);
    centroids[t] = (a + b + c) / 3.0;
    max_abs_ = std::max({max_abs_, tlo[t].cwiseAbs().maxCoeff(), thi[t].cwiseAbs().maxCoeff()});
  }
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    for (int k = 0; k < 3; ++k) {
      normals_[t].vertex[k] = vnormal[static_cast<size_t>(f[k])];
      normals_[t].edge[k] = enormal[edge_key(f[k], f[(k + 1) % 3])];
    }
  }

  // Binary SAH tree over the triangles; its leaves fix the triangles' slots.
  index_.resize(nt);
  for (size_t t = 0; t < nt; ++t) index_[t] = static_cast<uint32_t>(t);
  std::vector<BuildNode> binary;
  binary.reserve(2 * nt);
  Builder builder{tlo, thi, centroids, index_};
  BuildBinary(builder, binary, 0, static_cast<uint32_t>(nt), 0);
  slot_.resize(nt);
  geom_.resize(nt);
  bound_.resize(nt);
  for (size_t s = 0; s < nt; ++s) {
    const uint32_t t = index_[s];
    slot_[t] = static_cast<uint32_t>(s);
    const Eigen::Vector3i& f = mesh.triangles[t];
    geom_[s] = {mesh.vertices[static_cast<size_t>(f[0])], mesh.vertices[static_cast<size_t>(f[1])],
                mesh.vertices[static_cast<size_t>(f[2])]};
    const TriGeom& g = geom_[s];
    const Eigen::Vector3d n = normals_[t].face;  // zero for a degenerate triangle: no bound
    const Eigen::Vector3d* v[3] = {&g.a, &g.b, &g.c};
    Eigen::Vector3d u[4] = {n, Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero(),
                            Eigen::Vector3d::Zero()};
    double offset[4] = {n.dot(g.a), 0, 0, 0};
    if (n.squaredNorm() > 0) {
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d w = (*v[(k + 1) % 3] - *v[k]).cross(n);
        const double len = w.norm();
        if (len > 0) u[k + 1] = w / len;
        offset[k + 1] = u[k + 1].dot(*v[k]);
      }
    }
    for (int k = 0; k < 4; ++k) {
      for (int axis = 0; axis < 3; ++axis)
        bound_[s].plane[k][axis] = static_cast<float>(u[k][axis]);
      bound_[s].plane[k][3] = static_cast<float>(offset[k]);
    }
  }

  // Collapse into 4-wide nodes: a node takes the binary node's children, then repeatedly opens
  // the inner child of largest surface area until it has four.
  nodes_.reserve(binary.size() / 2 + 1);
  const auto collapse = [&](auto&& self, int b) -> uint32_t {
    const auto index = static_cast<uint32_t>(nodes_.size());
    nodes_.emplace_back();
    int kids[4];
    int n = 0;
    const BuildNode& root = binary[static_cast<size_t>(b)];
    if (root.left < 0) {
      kids[n++] = b;  // a single leaf (a one-triangle mesh)
    } else {
      kids[n++] = root.left;
      kids[n++] = root.right;
    }
    while (n < 4) {
      int open = -1;
      double open_area = -1;
      for (int k = 0; k < n; ++k) {
        const BuildNode& c = binary[static_cast<size_t>(kids[k])];
        if (c.left >= 0 && Area(c.lo, c.hi) > open_area) {
          open_area = Area(c.lo, c.hi);
          open = k;
        }
      }
      if (open < 0) break;
      const BuildNode& c = binary[static_cast<size_t>(kids[open])];
      kids[open] = c.left;
      kids[n++] = c.right;
    }
    uint32_t child[4];
    uint32_t count[4];
    for (int k = 0; k < 4; ++k) {
      if (k >= n) {
        child[k] = 0;
        count[k] = kEmpty;
        continue;
      }
      const BuildNode& c = binary[static_cast<size_t>(kids[k])];
      if (c.left < 0) {
        child[k] = c.begin;
        count[k] = c.end - c.begin;
      } else {
        child[k] = self(self, kids[k]);
        count[k] = 0;
      }
    }
    Node& node = nodes_[index];
    for (int k = 0; k < 4; ++k) {
      node.child[k] = child[k];
      node.count[k] = count[k];
      for (int axis = 0; axis < 3; ++axis) {
        if (k < n) {
          const BuildNode& c = binary[static_cast<size_t>(kids[k])];
          node.lo[axis][k] = Down(c.lo[axis]);
          node.hi[axis][k] = Up(c.hi[axis]);
        } else {
          node.lo[axis][k] = std::numeric_limits<float>::infinity();
          node.hi[axis][k] = -std::numeric_limits<float>::infinity();
        }
      }
    }
    return index;
  };
  collapse(collapse, 0);
}

MeshHit MeshDistance::Closest(const Eigen::Vector3d& p) const {
  return Closest(p, std::numeric_limits<uint32_t>::max());
}

MeshHit MeshDistance::Closest(const Eigen::Vector3d& p, uint32_t hint) const {
  // Start from the hint (or the first triangle): the search then only ever improves on a finite
  // squared distance. Ties go to the lowest triangle index.
  const uint32_t start_slot = hint < slot_.size() ? slot_[hint] : 0;
  int best_feature = 0;
  Eigen::Vector3d best_q;
  {
    const TriGeom& g = geom_[start_slot];
    best_q = ClosestPoint(p, g.a, g.b, g.c, &best_feature);
  }
  double best = (p - best_q).squaredNorm();
  uint32_t best_tri = index_[start_slot];

  // Float lower bounds of the box distances. |float(p) - p| <= 2^-24 |p| and each float
  // subtraction adds at most 2^-24 (|lo| + |p|), so per axis the float gap exceeds the true one
  // by at most 3 * 2^-24 * m with m = max(|mesh|, |p|); shrinking every gap by 4 * 2^-24 * m keeps
  // it below, and the remaining relative rounding of squares and sums (< 8 * 2^-24) is covered
  // by the factor applied before comparing with `best`.
  const double m = std::max(max_abs_, p.cwiseAbs().maxCoeff());
  const bool prune = m < 1e30;
  const float slack = static_cast<float>(4.0 * std::ldexp(m, -24));
  constexpr double kShrink = 1.0 - 1e-6;
  const float px = static_cast<float>(p.x()), py = static_cast<float>(p.y()),
              pz = static_cast<float>(p.z());
#if defined(__SSE2__)
  const __m128 vx = _mm_set1_ps(px), vy = _mm_set1_ps(py), vz = _mm_set1_ps(pz),
               vslack = _mm_set1_ps(slack);
#endif

  // Triangle bound: with h the distance to the triangle's plane and e the largest outside distance
  // to its edges' in-plane planes, the distance is at least sqrt(h^2 + e^2). The float normals,
  // offsets and products are off by less than 32 * 2^-24 * m in each of h and e (unit vectors
  // rounded to float, |p|, |offset| <= m), so both are shrunk by twice that.
  const float tri_slack = static_cast<float>(64.0 * std::ldexp(m, -24));
  // Float threshold for the float bounds: a bound b may prune only when b * kShrink > best, so
  // anything up to best / kShrink (rounded up to float) is visited.
  const auto threshold = [&](double b2) {
    const double t = b2 / kShrink;
    return !prune || t >= static_cast<double>(std::numeric_limits<float>::max())
               ? std::numeric_limits<float>::infinity()
               : Up(t);
  };
  float bestf = threshold(best);
  auto visit_triangles = [&](uint32_t first, uint32_t count) {
    for (uint32_t s = first; s < first + count; ++s) {
      if (prune) {
        const auto& b = bound_[s].plane;
        const float h = std::abs(b[0][0] * px + b[0][1] * py + b[0][2] * pz - b[0][3]);
        const float e0 = b[1][0] * px + b[1][1] * py + b[1][2] * pz - b[1][3];
        const float e1 = b[2][0] * px + b[2][1] * py + b[2][2] * pz - b[2][3];
        const float e2 = b[3][0] * px + b[3][1] * py + b[3][2] * pz - b[3][3];
        const float hh = std::max(h - tri_slack, 0.0f);
        const float ee = std::max(std::max(std::max(e0, e1), e2) - tri_slack, 0.0f);
        if (hh * hh + ee * ee > bestf) continue;
      }
      const TriGeom& g = geom_[s];
      int feature = 0;
      const Eigen::Vector3d q = ClosestPoint(p, g.a, g.b, g.c, &feature);
      const double d2 = (p - q).squaredNorm();
      const uint32_t t = index_[s];
      if (d2 < best || (d2 == best && t < best_tri)) {
        best = d2;
        best_feature = feature;
        best_tri = t;
        best_q = q;
        bestf = threshold(best);
      }
    }
  };

  struct Entry {
    uint32_t node;
    float lb;
  };
  constexpr int kStack = 4 * 64;
  Entry stack[kStack];
  int top = 0;
  stack[top++] = {0, 0.0f};
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.lb > bestf) continue;
    const Node& node = nodes_[e.node];
    alignas(16) float d[4];
    unsigned mask = 0;  // lanes whose bound does not exceed the best
#if defined(__SSE2__)
    {
      const __m128 zero = _mm_setzero_ps();
      const __m128 gx = _mm_max_ps(_mm_sub_ps(_mm_max_ps(_mm_sub_ps(_mm_load_ps(node.lo[0]), vx),
                                                         _mm_sub_ps(vx, _mm_load_ps(node.hi[0]))),
                                              vslack),
                                   zero);
      const __m128 gy = _mm_max_ps(_mm_sub_ps(_mm_max_ps(_mm_sub_ps(_mm_load_ps(node.lo[1]), vy),
                                                         _mm_sub_ps(vy, _mm_load_ps(node.hi[1]))),
                                              vslack),
                                   zero);
      const __m128 gz = _mm_max_ps(_mm_sub_ps(_mm_max_ps(_mm_sub_ps(_mm_load_ps(node.lo[2]), vz),
                                                         _mm_sub_ps(vz, _mm_load_ps(node.hi[2]))),
                                              vslack),
                                   zero);
      const __m128 vd =
          _mm_add_ps(_mm_add_ps(_mm_mul_ps(gx, gx), _mm_mul_ps(gy, gy)), _mm_mul_ps(gz, gz));
      _mm_store_ps(d, vd);
      mask = static_cast<unsigned>(_mm_movemask_ps(_mm_cmple_ps(vd, _mm_set1_ps(bestf))));
    }
#else
    for (int k = 0; k < 4; ++k) {
      const float gx = std::max(std::max(node.lo[0][k] - px, px - node.hi[0][k]) - slack, 0.0f);
      const float gy = std::max(std::max(node.lo[1][k] - py, py - node.hi[1][k]) - slack, 0.0f);
      const float gz = std::max(std::max(node.lo[2][k] - pz, pz - node.hi[2][k]) - slack, 0.0f);
      d[k] = gx * gx + gy * gy + gz * gz;
      if (d[k] <= bestf) mask |= 1u << k;
    }
#endif
    if (!prune) {
      mask = 0xf;
      for (float& x : d) x = 0.0f;
    }
    // The passing children nearest first: leaves are evaluated at once, inner children pushed
    // farthest first.
    int lane[4];
    int n = 0;
    for (int k = 0; k < 4; ++k) {
      if ((mask >> k) & 1u) {
        if (node.count[k] == kEmpty) continue;
        int j = n++;
        for (; j > 0 && d[k] < d[lane[j - 1]]; --j) lane[j] = lane[j - 1];
        lane[j] = k;
      }
    }
    int inner[4];
    int n_inner = 0;
    for (int i = 0; i < n; ++i) {
      const int k = lane[i];
      if (d[k] > bestf) break;
      if (node.count[k] > 0) {
        visit_triangles(node.child[k], node.count[k]);
      } else {
        inner[n_inner++] = k;
      }
    }
    SLSHADOW_CHECK(top + n_inner <= kStack);
    for (int i = n_inner - 1; i >= 0; --i) stack[top++] = {node.child[inner[i]], d[inner[i]]};
  }

  MeshHit hit;
  hit.signed_distance_mm = SignedDistance(p, best_q, best_tri, best_feature, best);
  hit.closest = best_q;
  hit.triangle = best_tri;
  return hit;
}

}  // namespace slshadow::compare
