#include "compare/c2m_grid.h"

#include "core/error.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>

namespace slshadow::compare {
namespace {

constexpr int kBlockBits = 3;  // blocks of 8 x 8 x 8 cells
constexpr int kBlockSide = 1 << kBlockBits;
constexpr int kBlockCells = kBlockSide * kBlockSide * kBlockSide;
constexpr uint32_t kUnbuilt = 0xffffffffu;
constexpr uint32_t kFar = 0xfffffffeu;  // answered by MeshDistance
constexpr size_t kMaxCandidates = 128;
constexpr double kMaxReachCells = 4;  // cells farther from the surface: MeshDistance
constexpr int64_t kMaxBlocks = int64_t{1} << 22;

float Down(double v) {
  float f = static_cast<float>(v);
  if (static_cast<double>(f) > v) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}

}  // namespace

struct C2mGrid::Impl {
  struct Tri {
    Eigen::Vector3d a, b, c;
    // The plane (unit normal, offset) and the edges' outward in-plane planes, as MeshDistance's
    // float TriBound but in double; all zero for a degenerate triangle.
    double plane[4][4];
    Eigen::Vector3d lo, hi;
  };
  struct Candidate {
    uint32_t triangle;
    float bound;  // a lower bound of the distance from any point of the cell, rounded down
  };
  struct Block {
    uint32_t first[kBlockCells];  // into candidates; kUnbuilt, kFar
    uint16_t count[kBlockCells];
  };

  const compare::MeshDistance& distance;
  std::vector<Tri> tris;
  bool enabled = false;
  Eigen::Vector3d lo = Eigen::Vector3d::Zero();
  double cell = 1, inv = 1, eps = 0, reach = 0;
  int64_t nx = 0, ny = 0, nz = 0, bx = 0, by = 0, bz = 0;
  std::vector<uint32_t> block_start, block_tris;  // per block, the triangles near it
  std::vector<std::unique_ptr<Block>> blocks;
  std::vector<Candidate> candidates;
  size_t built = 0, far_cells = 0;
  // Cells SignedDistances found unbuilt (ids, unsorted, repeats), for BuildMissed.
  mutable std::mutex missed_mutex;
  mutable std::vector<int64_t> missed;

  // Builds the cells `wanted` (ids, sorted, unique, none built yet).
  void Build(const std::vector<int64_t>& wanted);

  explicit Impl(const compare::MeshDistance& d) : distance(d) {}

  void Split(int64_t id, int64_t* x, int64_t* y, int64_t* z) const {
    *x = id % nx;
    *y = id / nx % ny;
    *z = id / nx / ny;
  }
  // The block of cell (x, y, z), and the cell's slot in it.
  int64_t BlockOf(int64_t x, int64_t y, int64_t z, int* slot) const {
    *slot = static_cast<int>(((z & (kBlockSide - 1)) * kBlockSide + (y & (kBlockSide - 1))) *
                                 kBlockSide +
                             (x & (kBlockSide - 1)));
    return ((z >> kBlockBits) * by + (y >> kBlockBits)) * bx + (x >> kBlockBits);
  }
  int64_t BlockOf(int64_t id, int* slot) const {
    int64_t x, y, z;
    Split(id, &x, &y, &z);
    return BlockOf(x, y, z, slot);
  }
  // The cell of p as coordinates, false outside the grid (or not finite).
  bool CellXyz(const Eigen::Vector3d& p, int64_t* x, int64_t* y, int64_t* z) const {
    if (!enabled) return false;
    // floor(t) in [0, n) exactly when t is in [0, n) (n an integer; NaN fails), and then floor(t)
    // is t truncated: no call to floor.
    const Eigen::Vector3d t = (p - lo) * inv;
    if (!(t.x() >= 0 && t.y() >= 0 && t.z() >= 0 && t.x() < static_cast<double>(nx) &&
          t.y() < static_cast<double>(ny) && t.z() < static_cast<double>(nz))) {
      return false;
    }
    *x = static_cast<int64_t>(t.x());
    *y = static_cast<int64_t>(t.y());
    *z = static_cast<int64_t>(t.z());
    return true;
  }
  // The entry of cell (x, y, z): its first candidate (or kUnbuilt, kFar) and count.
  uint32_t EntryXyz(int64_t x, int64_t y, int64_t z, uint16_t* count) const {
    int slot = 0;
    const Block* b = blocks[static_cast<size_t>(BlockOf(x, y, z, &slot))].get();
    if (!b) return kUnbuilt;
    *count = b->count[slot];
    return b->first[slot];
  }

  // A lower bound of the distance from the box centre +- half to triangle t.
  double BoxBound(const Tri& t, const Eigen::Vector3d& c, const Eigen::Vector3d& half) const {
    const Eigen::Vector3d blo = c - half, bhi = c + half;
    const Eigen::Vector3d gap = (t.lo - bhi).cwiseMax(blo - t.hi).cwiseMax(0.0);
    const double box = gap.norm();
    const auto plane = [&](int k) {
      const double* q = t.plane[k];
      return q[0] * c.x() + q[1] * c.y() + q[2] * c.z() - q[3] -
             (std::abs(q[0]) * half.x() + std::abs(q[1]) * half.y() + std::abs(q[2]) * half.z());
    };
    const double* n = t.plane[0];
    const double hn =
        std::abs(n[0] * c.x() + n[1] * c.y() + n[2] * c.z() - n[3]) -
        (std::abs(n[0]) * half.x() + std::abs(n[1]) * half.y() + std::abs(n[2]) * half.z());
    const double h = std::max(hn, 0.0);
    const double e = std::max({plane(1), plane(2), plane(3), 0.0});
    return std::max(box, std::sqrt(h * h + e * e));
  }

  // The candidates of cell `id` (empty and *far when it is answered by MeshDistance).
  void BuildCell(int64_t id, std::vector<Candidate>* out, bool* far) const {
    out->clear();
    *far = true;
    int64_t x, y, z;
    Split(id, &x, &y, &z);
    const Eigen::Vector3d c =
        lo + cell * Eigen::Vector3d(static_cast<double>(x) + 0.5, static_cast<double>(y) + 0.5,
                                    static_cast<double>(z) + 0.5);
    const Eigen::Vector3d half = Eigen::Vector3d::Constant(0.5 * cell + eps);
    const compare::MeshHit hit = distance.Closest(c);
    const double u = ((c - hit.closest).norm() + half.norm()) * (1 + 1e-9) + eps;
    if (!(u <= reach)) return;
    int slot = 0;
    const auto block = static_cast<size_t>(BlockOf(id, &slot));
    for (uint32_t k = block_start[block]; k < block_start[block + 1]; ++k) {
      const uint32_t t = block_tris[k];
      const double bound = BoxBound(tris[t], c, half) - eps;
      if (bound > u) continue;
      out->push_back({t, Down(std::max(bound, 0.0))});
      if (out->size() > kMaxCandidates) return;
    }
    if (out->empty()) return;  // (cannot happen: the centre's own triangle is one)
    std::sort(out->begin(), out->end(), [](const Candidate& a, const Candidate& b) {
      return a.bound < b.bound || (a.bound == b.bound && a.triangle < b.triangle);
    });
    *far = false;
  }

  // MeshDistance::Closest(p).signed_distance_mm from the cell's candidates.
  // `hint` (the previous point's triangle, or out of range): evaluated first, its distance bounds
  // the search from the start. The minimum and its ties do not depend on it: every triangle within
  // the cell's U is a candidate, so a triangle tied with the best is one.
  double FromCandidates(const Eigen::Vector3d& p, const Candidate* cand, uint16_t count,
                        uint32_t* hint) const {
    double best = std::numeric_limits<double>::infinity();
    uint32_t best_tri = 0;
    int best_feature = 0;
    Eigen::Vector3d best_q = Eigen::Vector3d::Zero();
    if (*hint < tris.size()) {
      const Tri& tri = tris[*hint];
      best_q = compare::ClosestPointOnTriangle(p, tri.a, tri.b, tri.c, &best_feature);
      best = (p - best_q).squaredNorm();
      best_tri = *hint;
    }
    for (uint16_t k = 0; k < count; ++k) {
      const double b = static_cast<double>(cand[k].bound);
      if (b * b > best) break;  // this and every later triangle is farther than the best
      const uint32_t t = cand[k].triangle;
      if (t == *hint) continue;  // evaluated above
      const Tri& tri = tris[t];
      const double* n = tri.plane[0];
      const double h = std::abs(n[0] * p.x() + n[1] * p.y() + n[2] * p.z() - n[3]) - eps;
      double e = -eps;
      for (int j = 1; j < 4; ++j) {
        const double* q = tri.plane[j];
        e = std::max(e, q[0] * p.x() + q[1] * p.y() + q[2] * p.z() - q[3] - eps);
      }
      const double hh = std::max(h, 0.0), ee = std::max(e, 0.0);
      if (hh * hh + ee * ee > best) continue;
      int feature = 0;
      const Eigen::Vector3d q = compare::ClosestPointOnTriangle(p, tri.a, tri.b, tri.c, &feature);
      const double d2 = (p - q).squaredNorm();
      if (d2 < best || (d2 == best && t < best_tri)) {
        best = d2;
        best_tri = t;
        best_feature = feature;
        best_q = q;
      }
    }
    *hint = best_tri;
    return distance.SignedDistance(p, best_q, best_tri, best_feature, best);
  }
};

C2mGrid::C2mGrid(const TriangleMesh& mesh, const compare::MeshDistance& distance,
                 double point_spacing_mm)
    : impl_(std::make_unique<Impl>(distance)) {
  Impl& g = *impl_;
  const size_t nt = mesh.triangles.size();
  SLSHADOW_CHECK(nt == distance.NumTriangles());
  if (nt == 0) return;
  // Cells of the median longest edge (smaller ones, half or 0.3 of it, cost more to build and
  // were no faster per point on the demo, 0.195 mm point spacing, 1.41 mm edges). Clouds sparser
  // than a third of it: no grid (the quarter-size demo rig's 0.77 mm spacing made the quick noise
  // study's comparison slower with one).
  std::vector<double> edges(nt);
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(f[2])];
    edges[t] = std::max({(b - a).norm(), (c - b).norm(), (a - c).norm()});
  }
  std::nth_element(edges.begin(), edges.begin() + static_cast<std::ptrdiff_t>(nt / 2), edges.end());
  const double median_edge = edges[nt / 2];
  if (!(3 * point_spacing_mm <= median_edge)) return;
  g.tris.resize(nt);
  double max_abs = 0;
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    const Eigen::Vector3d& a = mesh.vertices[static_cast<size_t>(f[0])];
    const Eigen::Vector3d& b = mesh.vertices[static_cast<size_t>(f[1])];
    const Eigen::Vector3d& c = mesh.vertices[static_cast<size_t>(f[2])];
    const Eigen::Vector3d& u0 = distance.FaceNormal(static_cast<uint32_t>(t));
    const Eigen::Vector3d* v[3] = {&a, &b, &c};
    Impl::Tri& tri = g.tris[t];
    tri.a = a;
    tri.b = b;
    tri.c = c;
    tri.lo = a.cwiseMin(b).cwiseMin(c);
    tri.hi = a.cwiseMax(b).cwiseMax(c);
    max_abs = std::max({max_abs, tri.lo.cwiseAbs().maxCoeff(), tri.hi.cwiseAbs().maxCoeff()});
    std::fill(&tri.plane[0][0], &tri.plane[0][0] + 16, 0.0);
    if (u0.squaredNorm() > 0) {
      for (int axis = 0; axis < 3; ++axis) tri.plane[0][axis] = u0[axis];
      tri.plane[0][3] = u0.dot(a);
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d w = (*v[(k + 1) % 3] - *v[k]).cross(u0);
        const double wl = w.norm();
        if (!(wl > 0)) continue;
        const Eigen::Vector3d u = w / wl;
        for (int axis = 0; axis < 3; ++axis) tri.plane[k + 1][axis] = u[axis];
        tri.plane[k + 1][3] = u.dot(*v[k]);
      }
    }
  }
  if (!(max_abs < 1e12)) return;
  Eigen::Vector3d lo = g.tris[0].lo, hi = g.tris[0].hi;
  for (const Impl::Tri& t : g.tris) {
    lo = lo.cwiseMin(t.lo);
    hi = hi.cwiseMax(t.hi);
  }
  double cell = std::max(median_edge, (hi - lo).maxCoeff() / 4096);
  if (!(cell > 0) || !std::isfinite(cell)) return;
  for (;; cell *= 2) {
    g.cell = cell;
    g.inv = 1 / cell;
    g.reach = kMaxReachCells * cell;
    g.lo = lo - Eigen::Vector3d::Constant(g.reach + cell);
    const Eigen::Vector3d extent = hi - lo + Eigen::Vector3d::Constant(2 * (g.reach + cell));
    g.nx = static_cast<int64_t>(std::ceil(extent.x() * g.inv)) + 1;
    g.ny = static_cast<int64_t>(std::ceil(extent.y() * g.inv)) + 1;
    g.nz = static_cast<int64_t>(std::ceil(extent.z() * g.inv)) + 1;
    g.bx = (g.nx + kBlockSide - 1) / kBlockSide;
    g.by = (g.ny + kBlockSide - 1) / kBlockSide;
    g.bz = (g.nz + kBlockSide - 1) / kBlockSide;
    if (g.bx * g.by * g.bz <= kMaxBlocks) break;
  }
  // Rounding: a point's computed cell may miss it by ~1e-16 of its coordinates; every bound
  // allows for far more.
  g.eps = std::max(1e-6 * g.cell, 1e-12 * (max_abs + g.reach));
  const auto num_blocks = static_cast<size_t>(g.bx * g.by * g.bz);
  g.blocks.resize(num_blocks);

  // Per block, every triangle within `reach` of it (its box gap and its plane's distance).
  const double block_side = kBlockSide * g.cell;
  const Eigen::Vector3d block_half = Eigen::Vector3d::Constant(0.5 * block_side + g.eps);
  std::vector<std::pair<uint32_t, uint32_t>> pairs;  // (block, triangle)
  for (size_t t = 0; t < nt; ++t) {
    const Impl::Tri& tri = g.tris[t];
    const Eigen::Vector3d a = (tri.lo - g.lo).array() - g.reach - g.eps;
    const Eigen::Vector3d b = (tri.hi - g.lo).array() + g.reach + g.eps;
    const auto first = [&](double v, int64_t n) {
      return std::clamp<int64_t>(static_cast<int64_t>(std::floor(v / block_side)), 0, n - 1);
    };
    for (int64_t z = first(a.z(), g.bz); z <= first(b.z(), g.bz); ++z) {
      for (int64_t y = first(a.y(), g.by); y <= first(b.y(), g.by); ++y) {
        for (int64_t x = first(a.x(), g.bx); x <= first(b.x(), g.bx); ++x) {
          const Eigen::Vector3d center =
              g.lo + block_side * Eigen::Vector3d(static_cast<double>(x) + 0.5,
                                                  static_cast<double>(y) + 0.5,
                                                  static_cast<double>(z) + 0.5);
          if (g.BoxBound(tri, center, block_half) - g.eps > g.reach) continue;
          pairs.emplace_back(static_cast<uint32_t>((z * g.by + y) * g.bx + x),
                             static_cast<uint32_t>(t));
        }
      }
    }
  }
  g.block_start.assign(num_blocks + 1, 0);
  for (const auto& [block, t] : pairs) ++g.block_start[block + 1];
  for (size_t b = 1; b <= num_blocks; ++b) g.block_start[b] += g.block_start[b - 1];
  g.block_tris.resize(pairs.size());
  std::vector<uint32_t> fill(g.block_start.begin(), g.block_start.end() - 1);
  for (const auto& [block, t] : pairs) g.block_tris[fill[block]++] = t;
  g.enabled = true;
}

C2mGrid::~C2mGrid() = default;

bool C2mGrid::enabled() const { return impl_->enabled; }
size_t C2mGrid::built_cells() const { return impl_->built; }
size_t C2mGrid::far_cells() const { return impl_->far_cells; }
double C2mGrid::cell_mm() const { return impl_->cell; }

void C2mGrid::Prepare(const std::vector<Eigen::Vector3d>& points) {
  Impl& g = *impl_;
  if (!g.enabled) return;
  std::vector<int64_t> wanted(points.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 16384),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        int64_t x = 0, y = 0, z = 0;
                        uint16_t count = 0;
                        wanted[i] = g.CellXyz(points[i], &x, &y, &z) &&
                                            g.EntryXyz(x, y, z, &count) == kUnbuilt
                                        ? (z * g.ny + y) * g.nx + x
                                        : -1;
                      }
                    });
  wanted.erase(std::remove(wanted.begin(), wanted.end(), int64_t{-1}), wanted.end());
  std::sort(wanted.begin(), wanted.end());
  wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
  g.Build(wanted);
}

void C2mGrid::BuildMissed() {
  Impl& g = *impl_;
  std::vector<int64_t> wanted;
  {
    const std::lock_guard<std::mutex> lock(g.missed_mutex);
    wanted.swap(g.missed);
  }
  std::sort(wanted.begin(), wanted.end());
  wanted.erase(std::unique(wanted.begin(), wanted.end()), wanted.end());
  // A cell may have been built since (by Prepare).
  wanted.erase(std::remove_if(wanted.begin(), wanted.end(),
                              [&](int64_t id) {
                                int slot = 0;
                                const Impl::Block* b =
                                    g.blocks[static_cast<size_t>(g.BlockOf(id, &slot))].get();
                                return b && b->first[slot] != kUnbuilt;
                              }),
               wanted.end());
  g.Build(wanted);
}

void C2mGrid::Impl::Build(const std::vector<int64_t>& wanted) {
  Impl& g = *this;
  if (wanted.empty()) return;
  std::vector<std::vector<Impl::Candidate>> lists(wanted.size());
  std::vector<uint8_t> far(wanted.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, wanted.size(), 64),
                    [&](const tbb::blocked_range<size_t>& r) {
                      for (size_t k = r.begin(); k < r.end(); ++k) {
                        bool f = true;
                        g.BuildCell(wanted[k], &lists[k], &f);
                        far[k] = f ? 1 : 0;
                      }
                    });
  for (size_t k = 0; k < wanted.size(); ++k) {
    int slot = 0;
    std::unique_ptr<Impl::Block>& block =
        g.blocks[static_cast<size_t>(g.BlockOf(wanted[k], &slot))];
    if (!block) {
      block = std::make_unique<Impl::Block>();
      std::fill(std::begin(block->first), std::end(block->first), kUnbuilt);
      std::fill(std::begin(block->count), std::end(block->count), uint16_t{0});
    }
    if (far[k] || g.candidates.size() + lists[k].size() >= kFar) {
      block->first[slot] = kFar;
      ++g.far_cells;
    } else {
      block->first[slot] = static_cast<uint32_t>(g.candidates.size());
      block->count[slot] = static_cast<uint16_t>(lists[k].size());
      g.candidates.insert(g.candidates.end(), lists[k].begin(), lists[k].end());
    }
    ++g.built;
  }
}

void C2mGrid::SignedDistances(const std::vector<Eigen::Vector3d>& points,
                              std::vector<double>* out) const {
  const Impl& g = *impl_;
  out->resize(points.size());
  double* d = out->data();
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096),
                    [&](const tbb::blocked_range<size_t>& r) {
                      uint32_t hint = std::numeric_limits<uint32_t>::max();
                      std::vector<int64_t> missed;
                      for (size_t i = r.begin(); i < r.end(); ++i) {
                        const Eigen::Vector3d& p = points[i];
                        int64_t x = 0, y = 0, z = 0;
                        uint16_t count = 0;
                        const bool inside = g.CellXyz(p, &x, &y, &z);
                        const uint32_t first = inside ? g.EntryXyz(x, y, z, &count) : kUnbuilt;
                        if (first < kFar) {
                          d[i] = g.FromCandidates(p, g.candidates.data() + first, count, &hint);
                          continue;
                        }
                        if (inside && first == kUnbuilt) {
                          const int64_t id = (z * g.ny + y) * g.nx + x;
                          if (missed.empty() || missed.back() != id) missed.push_back(id);
                        }
                        const compare::MeshHit hit = g.distance.Closest(p, hint);
                        d[i] = hit.signed_distance_mm;
                        hint = hit.triangle;
                      }
                      if (!missed.empty()) {
                        const std::lock_guard<std::mutex> lock(g.missed_mutex);
                        g.missed.insert(g.missed.end(), missed.begin(), missed.end());
                      }
                    });
}

}  // namespace slshadow::compare
