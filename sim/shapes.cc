#include "sim/shapes.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <unordered_map>

#include "core/error.h"

namespace slshadow {
namespace {

constexpr double kPi = 3.14159265358979323846;

// Grid of nu x nv quads spanning p0 + [0,1] eu + [0,1] ev, two triangles each, oriented so that
// the normal points along `outward`.
void AddQuadGrid(TriangleMesh& mesh, const Eigen::Vector3d& p0, Eigen::Vector3d eu,
                 Eigen::Vector3d ev, int nu, int nv, const Eigen::Vector3d& outward) {
  if (eu.cross(ev).dot(outward) < 0) {
    std::swap(eu, ev);
    std::swap(nu, nv);
  }
  const int base = static_cast<int>(mesh.vertices.size());
  for (int j = 0; j <= nv; ++j) {
    for (int i = 0; i <= nu; ++i) {
      mesh.vertices.push_back(p0 + eu * (static_cast<double>(i) / nu) +
                              ev * (static_cast<double>(j) / nv));
    }
  }
  for (int j = 0; j < nv; ++j) {
    for (int i = 0; i < nu; ++i) {
      const int a = base + j * (nu + 1) + i;
      const int b = a + 1;
      const int c = a + nu + 1;
      const int d = c + 1;
      mesh.triangles.emplace_back(a, b, d);
      mesh.triangles.emplace_back(a, d, c);
    }
  }
}

// Adds a strip surface given as a (rows + 1) x (cols + 1) grid of points (row-major), oriented
// along `outward_at` (a function of the quad's centre returning the desired normal direction).
template <typename Outward>
void AddPointGrid(TriangleMesh& mesh, const std::vector<Eigen::Vector3d>& grid, int rows, int cols,
                  Outward outward_at) {
  const int base = static_cast<int>(mesh.vertices.size());
  mesh.vertices.insert(mesh.vertices.end(), grid.begin(), grid.end());
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const int a = base + r * (cols + 1) + c;
      const int b = a + 1;
      const int d = a + cols + 1;
      const int e = d + 1;
      const Eigen::Vector3d center = (grid[a - base] + grid[e - base]) / 2;
      const Eigen::Vector3d n =
          (grid[b - base] - grid[a - base]).cross(grid[e - base] - grid[a - base]);
      const Eigen::Vector3d n2 =
          (grid[e - base] - grid[a - base]).cross(grid[d - base] - grid[a - base]);
      const bool flip = (n + n2).dot(outward_at(center)) < 0;
      // Skip triangles collapsed at poles (two equal points).
      auto add = [&](int p, int q, int s) {
        if (grid[p - base] == grid[q - base] || grid[q - base] == grid[s - base] ||
            grid[p - base] == grid[s - base])
          return;
        if (flip)
          mesh.triangles.emplace_back(p, s, q);
        else
          mesh.triangles.emplace_back(p, q, s);
      };
      add(a, b, e);
      add(a, e, d);
    }
  }
}

int Segments(double length_mm, double resolution_mm) {
  return std::max(1, static_cast<int>(std::ceil(length_mm / resolution_mm - 1e-9)));
}

constexpr double kTile = 20;
constexpr int kTilesX = 8;
constexpr int kTilesY = 5;
constexpr double kX0 = -80;
constexpr double kY0 = -50;
constexpr double kHoleRadius = 6;
constexpr double kHoleDepth = 15;
constexpr double kSphereRadius = 10;
constexpr double kSphereLift = 4;

double TileHeight(int i, int j) {
  if (i < 0 || j < 0 || i >= kTilesX || j >= kTilesY) return 0;
  if (i >= 1 && i <= 2 && j >= 1 && j <= 2) return 30 - 12;  // the pocket
  if (i <= 2) return 30;
  if (i <= 5) return 40;
  return 50;
}
bool IsHoleTile(int i, int j) {
  return (i == 3 && j == 1) || (i == 3 && j == 3) || (i == 6 && j == 3);
}

}  // namespace

DemoPartFeatures DemoPartDescription() {
  DemoPartFeatures f;
  constexpr int kSphereI = 5, kSphereJ = 2;  // the tile the dome sits on
  f.sphere_center_mm =
      Eigen::Vector3d(kX0 + (kSphereI + 0.5) * kTile, kY0 + (kSphereJ + 0.5) * kTile,
                      TileHeight(kSphereI, kSphereJ) + kSphereLift);
  f.sphere_radius_mm = kSphereRadius;
  for (int i = 0; i < kTilesX; ++i) {
    for (int j = 0; j < kTilesY; ++j) {
      if (IsHoleTile(i, j)) {
        f.hole_top_centers_mm.emplace_back(kX0 + (i + 0.5) * kTile, kY0 + (j + 0.5) * kTile,
                                           TileHeight(i, j));
      }
    }
  }
  f.hole_radius_mm = kHoleRadius;
  f.hole_depth_mm = kHoleDepth;
  return f;
}

TriangleMesh MakeOcclusionPart(double resolution_mm) {
  SLSHADOW_THROW_IF(!(resolution_mm > 0.05 && resolution_mm <= 5),
                    "occlusion part: resolution_mm must be in (0.05, 5] (got ", resolution_mm, ")");
  constexpr double kCell = 5;                  // voxel edge, mm
  constexpr int kNx = 24, kNy = 16, kNz = 12;  // x from -60, y from -40, z from 0
  const auto inside = [](int i, int j, int k) {
    if (i < 0 || j < 0 || k < 0 || i >= kNx || j >= kNy || k >= kNz) return false;
    const double x = -60 + kCell * (i + 0.5), y = -40 + kCell * (j + 0.5), z = kCell * (k + 0.5);
    if (x > -40 && x < -30 && y > -5 && y < 5 && z > 10) return false;  // the deep hole
    if (z < 20) return true;                                            // base slab
    if (x < -10) return z < 60;                                         // tower
    return x < 30 && z > 50 && z < 60;                                  // overhang
  };
  const int m = static_cast<int>(std::ceil(kCell / resolution_mm - 1e-9));
  const double h = kCell / m;
  TriangleMesh mesh;
  // Vertices welded on the lattice of step h: key from integer lattice coordinates.
  std::unordered_map<int64_t, int> index;
  const auto vertex = [&](int a, int b, int c) {
    const int64_t key = (static_cast<int64_t>(a) * 4096 + b) * 4096 + c;
    const auto [it, added] = index.emplace(key, static_cast<int>(mesh.vertices.size()));
    if (added) mesh.vertices.emplace_back(-60 + a * h, -40 + b * h, c * h);
    return it->second;
  };
  for (int k = 0; k < kNz; ++k) {
    for (int j = 0; j < kNy; ++j) {
      for (int i = 0; i < kNx; ++i) {
        if (!inside(i, j, k)) continue;
        const int cell[3] = {i, j, k};
        for (int d = 0; d < 3; ++d) {
          for (const int side : {-1, 1}) {
            int n[3] = {i, j, k};
            n[d] += side;
            if (inside(n[0], n[1], n[2])) continue;
            // The face's lattice square: axis d fixed, u = d + 1, v = d + 2 (cyclic), so
            // e_u x e_v = e_d; counter-clockwise (u, v) order for the +d side, reversed for -d.
            const int u = (d + 1) % 3, v = (d + 2) % 3;
            for (int b = 0; b < m; ++b) {
              for (int a = 0; a < m; ++a) {
                int q[4][3];
                const int du[4] = {0, 1, 1, 0}, dv[4] = {0, 0, 1, 1};
                for (int c = 0; c < 4; ++c) {
                  q[c][d] = (cell[d] + (side > 0 ? 1 : 0)) * m;
                  q[c][u] = cell[u] * m + a + du[c];
                  q[c][v] = cell[v] * m + b + dv[c];
                }
                int id[4];
                for (int c = 0; c < 4; ++c) id[c] = vertex(q[c][0], q[c][1], q[c][2]);
                if (side > 0) {
                  mesh.triangles.emplace_back(id[0], id[1], id[2]);
                  mesh.triangles.emplace_back(id[0], id[2], id[3]);
                } else {
                  mesh.triangles.emplace_back(id[0], id[2], id[1]);
                  mesh.triangles.emplace_back(id[0], id[3], id[2]);
                }
              }
            }
          }
        }
      }
    }
  }
  return mesh;
}

double DemoPartResolutionFor(double triangles) {
  SLSHADOW_THROW_IF(!(triangles > 0), "demo part: triangle count must be > 0 (got ", triangles,
                    ")");
  return std::sqrt(86696.0 / triangles);
}

TriangleMesh MakeDemoPart(double resolution_mm) {
  SLSHADOW_THROW_IF(!(resolution_mm > 0.01 && resolution_mm <= 20),
                    "demo part: resolution_mm must be in (0.01, 20] (got ", resolution_mm, ")");
  TriangleMesh mesh;
  const int n_tile = Segments(kTile, resolution_mm);
  // Circle segments: a multiple of 8 so the square's corners are sampled.
  const int n_circle =
      std::max(16, 8 * static_cast<int>(std::ceil(2 * kPi * kHoleRadius / resolution_mm / 8)));
  const Eigen::Vector3d ux = Eigen::Vector3d::UnitX(), uy = Eigen::Vector3d::UnitY(),
                        uz = Eigen::Vector3d::UnitZ();

  for (int i = 0; i < kTilesX; ++i) {
    for (int j = 0; j < kTilesY; ++j) {
      const double h = TileHeight(i, j);
      const double x0 = kX0 + i * kTile, y0 = kY0 + j * kTile;
      const Eigen::Vector3d corner(x0, y0, h);
      if (!IsHoleTile(i, j)) {
        AddQuadGrid(mesh, corner, ux * kTile, uy * kTile, n_tile, n_tile, uz);
      } else {
        // Square minus disc: rings between the circle and the square along the same angles.
        const Eigen::Vector3d c(x0 + kTile / 2, y0 + kTile / 2, h);
        const int rings = std::max(1, Segments(kTile / 2 - kHoleRadius, resolution_mm));
        std::vector<Eigen::Vector3d> grid;
        for (int r = 0; r <= rings; ++r) {
          for (int k = 0; k <= n_circle; ++k) {
            const double a = 2 * kPi * k / n_circle;
            const Eigen::Vector3d dir(std::cos(a), std::sin(a), 0);
            const Eigen::Vector3d on_circle = c + kHoleRadius * dir;
            const Eigen::Vector3d on_square =
                c + (kTile / 2) / std::max(std::abs(dir.x()), std::abs(dir.y())) * dir;
            grid.push_back(on_circle + (on_square - on_circle) * (static_cast<double>(r) / rings));
          }
        }
        AddPointGrid(mesh, grid, rings, n_circle, [&](const Eigen::Vector3d&) { return uz; });
        // Hole wall (normal towards the axis: out of the solid) and bottom.
        const int n_depth = Segments(kHoleDepth, resolution_mm);
        grid.clear();
        for (int r = 0; r <= n_depth; ++r) {
          for (int k = 0; k <= n_circle; ++k) {
            const double a = 2 * kPi * k / n_circle;
            grid.push_back(c + Eigen::Vector3d(kHoleRadius * std::cos(a), kHoleRadius * std::sin(a),
                                               -kHoleDepth * r / n_depth));
          }
        }
        AddPointGrid(mesh, grid, n_depth, n_circle, [&](const Eigen::Vector3d& p) {
          return Eigen::Vector3d(c.x() - p.x(), c.y() - p.y(), 0);
        });
        const int n_radial = Segments(kHoleRadius, resolution_mm);
        grid.clear();
        for (int r = 0; r <= n_radial; ++r) {
          for (int k = 0; k <= n_circle; ++k) {
            const double a = 2 * kPi * k / n_circle;
            const double rad = kHoleRadius * r / n_radial;
            grid.push_back(c + Eigen::Vector3d(rad * std::cos(a), rad * std::sin(a), -kHoleDepth));
          }
        }
        AddPointGrid(mesh, grid, n_radial, n_circle, [&](const Eigen::Vector3d&) { return uz; });
      }
      // Walls towards lower neighbours (and the outside, height 0) on the four sides.
      struct Side {
        int di, dj;
        Eigen::Vector3d start, along, outward;
      };
      const std::array<Side, 4> sides = {{
          {-1, 0, Eigen::Vector3d(x0, y0, 0), uy, -ux},
          {1, 0, Eigen::Vector3d(x0 + kTile, y0, 0), uy, ux},
          {0, -1, Eigen::Vector3d(x0, y0, 0), ux, -uy},
          {0, 1, Eigen::Vector3d(x0, y0 + kTile, 0), ux, uy},
      }};
      for (const Side& s : sides) {
        const double lo = TileHeight(i + s.di, j + s.dj);
        if (lo >= h) continue;
        const Eigen::Vector3d p0 = s.start + uz * lo;
        AddQuadGrid(mesh, p0, s.along * kTile, uz * (h - lo), n_tile,
                    Segments(h - lo, resolution_mm), s.outward);
      }
    }
  }
  // Bottom.
  AddQuadGrid(mesh, Eigen::Vector3d(kX0, kY0, 0), ux * kTile * kTilesX, uy * kTile * kTilesY,
              kTilesX, kTilesY, -uz);

  // Dome: the sphere's part above the top face (the rest is inside the block and not needed).
  const DemoPartFeatures f = DemoPartDescription();
  const int n_sphere =
      std::max(16, 8 * static_cast<int>(std::ceil(2 * kPi * kSphereRadius / resolution_mm / 8)));
  // Polar angle from the top down to where the sphere meets the face z = h (cos = -lift / r).
  const double theta_max = std::acos(-kSphereLift / kSphereRadius);
  const int n_theta =
      std::max(4, static_cast<int>(std::ceil(theta_max * kSphereRadius / resolution_mm)));
  std::vector<Eigen::Vector3d> grid;
  for (int r = 0; r <= n_theta; ++r) {
    const double theta = theta_max * r / n_theta;
    for (int k = 0; k <= n_sphere; ++k) {
      const double a = 2 * kPi * k / n_sphere;
      grid.push_back(f.sphere_center_mm +
                     kSphereRadius * Eigen::Vector3d(std::sin(theta) * std::cos(a),
                                                     std::sin(theta) * std::sin(a),
                                                     std::cos(theta)));
    }
  }
  AddPointGrid(mesh, grid, n_theta, n_sphere,
               [&](const Eigen::Vector3d& p) { return p - f.sphere_center_mm; });
  return mesh;
}

TriangleMesh MakeSphereMesh(double radius_mm, int segments) {
  SLSHADOW_THROW_IF(!(radius_mm > 0) || segments < 4,
                    "sphere mesh: need radius_mm > 0 and segments >= 4 (got ", radius_mm, ", ",
                    segments, ")");
  TriangleMesh mesh;
  const int rings = std::max(2, segments / 2);
  std::vector<Eigen::Vector3d> grid;
  for (int r = 0; r <= rings; ++r) {
    const double theta = kPi * r / rings;
    for (int k = 0; k <= segments; ++k) {
      const double a = 2 * kPi * k / segments;
      // Exact poles so the collapsed triangles there are recognised and skipped.
      const double s = (r == 0 || r == rings) ? 0.0 : std::sin(theta);
      const double c = r == 0 ? 1.0 : (r == rings ? -1.0 : std::cos(theta));
      grid.emplace_back(radius_mm * s * std::cos(a), radius_mm * s * std::sin(a), radius_mm * c);
    }
  }
  AddPointGrid(mesh, grid, rings, segments, [](const Eigen::Vector3d& p) { return p; });
  return mesh;
}

BoardScene MakeCheckerboardScene(int inner_corners_x, int inner_corners_y, double square_mm,
                                 const Rigid3d& rig_from_board, double dark, double light) {
  SLSHADOW_THROW_IF(inner_corners_x < 2 || inner_corners_y < 2 || !(square_mm > 0),
                    "checkerboard: need >= 2 x 2 inner corners and square_mm > 0 (got ",
                    inner_corners_x, " x ", inner_corners_y, ", ", square_mm, ")");
  BoardScene out;
  out.scene.name = "checkerboard";
  SceneObject board;
  board.name = "board";
  board.type = ObjectType::kPlane;
  board.albedo.kind = Albedo::Kind::kCheckerboard;
  board.albedo.square_mm = square_mm;
  board.albedo.squares_x = inner_corners_x + 1;
  board.albedo.squares_y = inner_corners_y + 1;
  board.albedo.dark = dark;
  board.albedo.light = light;
  // The plane primitive is centred at its origin: shift it under the board's squares plus a
  // one-square margin, and keep the board frame for the albedo (Albedo uses object coordinates,
  // so the object frame is the board frame and the plane is offset inside it).
  const double width = (inner_corners_x + 3) * square_mm,
               height = (inner_corners_y + 3) * square_mm;
  board.size_mm = Eigen::Vector3d(width, height, 0);
  // Plane centre in the board frame.
  const Eigen::Vector3d center_in_board((inner_corners_x - 1) * square_mm / 2,
                                        (inner_corners_y - 1) * square_mm / 2, 0);
  board.rig_from_object = rig_from_board * Rigid3d(Eigen::Quaterniond::Identity(), center_in_board);
  board.albedo_offset_mm = Eigen::Vector2d(center_in_board.x(), center_in_board.y());
  out.scene.objects.push_back(board);
  for (int j = 0; j < inner_corners_y; ++j) {
    for (int i = 0; i < inner_corners_x; ++i) {
      const Eigen::Vector3d p(i * square_mm, j * square_mm, 0);
      out.corners_in_board.push_back(p);
      out.corners_in_rig.push_back(rig_from_board * p);
    }
  }
  nlohmann::json corners = nlohmann::json::array();
  for (const auto& p : out.corners_in_rig) corners.push_back({p.x(), p.y(), p.z()});
  out.scene.artefacts["board"] = {{"type", "checkerboard"},
                                  {"inner_corners", {inner_corners_x, inner_corners_y}},
                                  {"square_mm", square_mm},
                                  {"corners_in_rig_mm", corners}};
  return out;
}

Scene MakeImageBoardScene(const cv::Mat& image, double pixel_mm, const Rigid3d& rig_from_board,
                          double margin_mm, double light) {
  SLSHADOW_THROW_IF(image.empty() || image.type() != CV_8UC1,
                    "image board: need a non-empty 8-bit grey image (got type ", image.type(), ")");
  SLSHADOW_THROW_IF(!(pixel_mm > 0) || !(margin_mm >= 0),
                    "image board: need pixel_mm > 0 and margin_mm >= 0 (got ", pixel_mm, ", ",
                    margin_mm, ")");
  Scene scene;
  scene.name = "image_board";
  SceneObject board;
  board.name = "board";
  board.type = ObjectType::kPlane;
  board.albedo.kind = Albedo::Kind::kImage;
  board.albedo.image = image.clone();
  board.albedo.pixel_mm = pixel_mm;
  board.albedo.light = light;
  const double w = image.cols * pixel_mm, h = image.rows * pixel_mm;
  board.size_mm = Eigen::Vector3d(w + 2 * margin_mm, h + 2 * margin_mm, 0);
  const Eigen::Vector3d center_in_board(w / 2, h / 2, 0);
  board.rig_from_object = rig_from_board * Rigid3d(Eigen::Quaterniond::Identity(), center_in_board);
  board.albedo_offset_mm = Eigen::Vector2d(center_in_board.x(), center_in_board.y());
  scene.objects.push_back(board);
  return scene;
}

}  // namespace slshadow
