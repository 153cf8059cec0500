#include "core/mesh.h"

#include <algorithm>
#include <atomic>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>
#include <unordered_map>

#include <opencv2/core/utility.hpp>

#include "core/error.h"
#include "core/file_util.h"
#include "core/point_cloud.h"

namespace slshadow {
namespace fs = std::filesystem;

Eigen::Vector3d TriangleMesh::FaceNormal(size_t i) const {
  const auto& t = triangles[i];
  const Eigen::Vector3d n =
      (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]);
  const double len = n.norm();
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

double TriangleMesh::TriangleArea(size_t i) const {
  const auto& t = triangles[i];
  return 0.5 * (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]).norm();
}

double TriangleMesh::SurfaceArea() const {
  double a = 0;
  for (size_t i = 0; i < triangles.size(); ++i) a += TriangleArea(i);
  return a;
}

Eigen::Vector3d TriangleMesh::BoundsMin() const {
  Eigen::Vector3d m = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  for (const auto& v : vertices) m = m.cwiseMin(v);
  return m;
}

Eigen::Vector3d TriangleMesh::BoundsMax() const {
  Eigen::Vector3d m = Eigen::Vector3d::Constant(-std::numeric_limits<double>::infinity());
  for (const auto& v : vertices) m = m.cwiseMax(v);
  return m;
}

void TriangleMesh::Transform(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                             double scale) {
  for (auto& v : vertices) v = rotation * (scale * v) + translation;
}

void TriangleMesh::Append(const TriangleMesh& other) {
  const int offset = static_cast<int>(vertices.size());
  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  for (const auto& t : other.triangles) triangles.push_back(t + Eigen::Vector3i::Constant(offset));
}

void TriangleMesh::Check(const std::string& what, bool reject_degenerate) const {
  SLSHADOW_THROW_IF(triangles.empty(), what, ": mesh has no triangles");
  Eigen::Vector3d low = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity()),
                  high = -low;
  for (size_t i = 0; i < vertices.size(); ++i) {
    SLSHADOW_THROW_IF(!vertices[i].allFinite(), what, ": vertex ", i, " is not finite");
    low = low.cwiseMin(vertices[i]);
    high = high.cwiseMax(vertices[i]);
  }
  const int n = static_cast<int>(vertices.size());
  const double diag2 = (high - low).squaredNorm();
  const auto bad = [&](size_t i) {
    const auto& t = triangles[i];
    if (t[0] < 0 || t[0] >= n || t[1] < 0 || t[1] >= n || t[2] < 0 || t[2] >= n) return true;
    return reject_degenerate &&
           (t[0] == t[1] || t[1] == t[2] || t[0] == t[2] || TriangleArea(i) < 1e-12 * diag2);
  };
  // Triangles in parallel (a simulated scan checks its 1 M-triangle part every time); the
  // lowest-numbered bad triangle is reported, as a serial loop would.
  std::atomic<size_t> first_bad{triangles.size()};
  cv::parallel_for_(
      cv::Range(0, static_cast<int>(triangles.size())),
      [&](const cv::Range& r) {
        for (int i = r.start;
             i < r.end && static_cast<size_t>(i) < first_bad.load(std::memory_order_relaxed); ++i) {
          if (!bad(static_cast<size_t>(i))) continue;
          size_t seen = first_bad.load();
          while (static_cast<size_t>(i) < seen &&
                 !first_bad.compare_exchange_weak(seen, static_cast<size_t>(i))) {}
          return;
        }
      },
      64);
  const size_t i = first_bad.load();
  if (i == triangles.size()) return;
  const auto& t = triangles[i];
  for (int k = 0; k < 3; ++k) {
    SLSHADOW_THROW_IF(t[k] < 0 || t[k] >= n, what, ": triangle ", i, " refers to vertex ", t[k],
                      " of ", n);
  }
  SLSHADOW_THROW(what, ": triangle ", i, " is degenerate (zero area)");
}

size_t TriangleMesh::CountNonManifoldEdges() const {
  std::map<std::pair<int, int>, int> edges;
  for (const auto& t : triangles) {
    for (int k = 0; k < 3; ++k) {
      const int a = t[k], b = t[(k + 1) % 3];
      ++edges[{std::min(a, b), std::max(a, b)}];
    }
  }
  size_t count = 0;
  for (const auto& [edge, uses] : edges) count += uses > 2;
  return count;
}

namespace {

struct VertexKeyHash {
  size_t operator()(const Eigen::Vector3f& v) const {
    uint32_t h[3];
    std::memcpy(h, v.data(), sizeof(h));
    return (static_cast<size_t>(h[0]) * 73856093u) ^ (static_cast<size_t>(h[1]) * 19349663u) ^
           (static_cast<size_t>(h[2]) * 83492791u);
  }
};

// STL stores each triangle's corners; merge exactly equal corners into shared vertices.
class VertexWelder {
 public:
  int Add(const Eigen::Vector3f& v, TriangleMesh& mesh) {
    auto [it, inserted] = index_.emplace(v, static_cast<int>(mesh.vertices.size()));
    if (inserted) mesh.vertices.push_back(v.cast<double>());
    return it->second;
  }

 private:
  std::unordered_map<Eigen::Vector3f, int, VertexKeyHash> index_;
};

TriangleMesh ReadStl(const fs::path& path, const std::string& data) {
  const std::string file = path.string();
  TriangleMesh mesh;
  VertexWelder welder;
  // Binary STL: 80-byte header, uint32 count, 50 bytes per triangle. Some binary files start with
  // "solid", so decide by the size first.
  if (data.size() >= 84) {
    uint32_t count;
    std::memcpy(&count, data.data() + 80, 4);
    if (data.size() == 84 + static_cast<size_t>(count) * 50) {
      for (uint32_t i = 0; i < count; ++i) {
        const char* rec = data.data() + 84 + static_cast<size_t>(i) * 50;
        Eigen::Vector3i tri;
        for (int k = 0; k < 3; ++k) {
          float v[3];
          std::memcpy(v, rec + 12 + 12 * k, 12);
          const Eigen::Vector3f p(v[0], v[1], v[2]);
          SLSHADOW_THROW_IF(!p.allFinite(), file, ": triangle ", i, " has a non-finite vertex");
          tri[k] = welder.Add(p, mesh);
        }
        mesh.triangles.push_back(tri);
      }
      return mesh;
    }
  }
  SLSHADOW_THROW_IF(
      data.compare(0, 5, "solid") != 0, file,
      ": not an STL file (binary size does not match its triangle count, and no 'solid' header)");
  std::istringstream in(data);
  std::string line;
  int line_no = 0;
  std::vector<int> corners;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream words(line);
    std::string key;
    words >> key;
    if (key == "vertex") {
      float x, y, z;
      SLSHADOW_THROW_IF(!(words >> x >> y >> z), file, ": line ", line_no, ": bad vertex line '",
                        line, "'");
      corners.push_back(welder.Add(Eigen::Vector3f(x, y, z), mesh));
    } else if (key == "endfacet") {
      SLSHADOW_THROW_IF(corners.size() != 3, file, ": line ", line_no, ": facet with ",
                        corners.size(), " vertices, expected 3");
      mesh.triangles.emplace_back(corners[0], corners[1], corners[2]);
      corners.clear();
    }
  }
  return mesh;
}

void AddPolygon(const std::vector<int>& polygon, TriangleMesh& mesh) {
  for (size_t k = 2; k < polygon.size(); ++k)
    mesh.triangles.emplace_back(polygon[0], polygon[k - 1], polygon[k]);
}

TriangleMesh ReadObj(const fs::path& path, const std::string& data) {
  const std::string file = path.string();
  TriangleMesh mesh;
  std::istringstream in(data);
  std::string line;
  int line_no = 0;
  while (std::getline(in, line)) {
    ++line_no;
    std::istringstream words(line);
    std::string key;
    words >> key;
    if (key == "v") {
      double x, y, z;
      SLSHADOW_THROW_IF(!(words >> x >> y >> z), file, ": line ", line_no, ": bad vertex line '",
                        line, "'");
      mesh.vertices.emplace_back(x, y, z);
    } else if (key == "f") {
      std::vector<int> polygon;
      std::string token;
      while (words >> token) {
        const long idx = std::strtol(token.c_str(), nullptr, 10);
        const long n = static_cast<long>(mesh.vertices.size());
        const long resolved = idx > 0 ? idx - 1 : n + idx;
        SLSHADOW_THROW_IF(idx == 0 || resolved < 0 || resolved >= n, file, ": line ", line_no,
                          ": face refers to vertex ", token, " of ", n);
        polygon.push_back(static_cast<int>(resolved));
      }
      SLSHADOW_THROW_IF(polygon.size() < 3, file, ": line ", line_no,
                        ": face with fewer than 3 vertices");
      AddPolygon(polygon, mesh);
    }
  }
  return mesh;
}

TriangleMesh ReadPlyMesh(const fs::path& path) {
  const PlyData ply = ReadPlyData(path);
  const PlyElement* v = ply.Find("vertex");
  const PlyElement* f = ply.Find("face");
  SLSHADOW_THROW_IF(v == nullptr, path.string(), ": PLY has no 'vertex' element");
  SLSHADOW_THROW_IF(f == nullptr, path.string(),
                    ": PLY has no 'face' element (a point cloud, not a mesh)");
  const int ix = v->PropertyIndex("x"), iy = v->PropertyIndex("y"), iz = v->PropertyIndex("z");
  SLSHADOW_THROW_IF(ix < 0 || iy < 0 || iz < 0, path.string(),
                    ": PLY vertex element lacks x, y or z");
  SLSHADOW_THROW_IF(
      v->properties[ix].is_list || v->properties[iy].is_list || v->properties[iz].is_list,
      path.string(), ": PLY vertex x, y and z must be numbers, not lists");
  int ilist = f->PropertyIndex("vertex_indices");
  if (ilist < 0) ilist = f->PropertyIndex("vertex_index");
  SLSHADOW_THROW_IF(ilist < 0 || !f->properties[ilist].is_list, path.string(),
                    ": PLY face element lacks a vertex_indices list");
  TriangleMesh mesh;
  mesh.vertices.resize(v->count);
  for (size_t i = 0; i < v->count; ++i)
    mesh.vertices[i] = {v->columns[ix][i], v->columns[iy][i], v->columns[iz][i]};
  const auto& offsets = f->list_offsets[ilist];
  const auto& values = f->list_values[ilist];
  for (size_t i = 0; i < f->count; ++i) {
    std::vector<int> polygon;
    for (uint32_t k = offsets[i]; k < offsets[i + 1]; ++k) {
      SLSHADOW_THROW_IF(values[k] < 0 || values[k] >= static_cast<int64_t>(v->count), path.string(),
                        ": face ", i, " refers to vertex ", values[k], " of ", v->count);
      polygon.push_back(static_cast<int>(values[k]));
    }
    SLSHADOW_THROW_IF(polygon.size() < 3, path.string(), ": face ", i,
                      " has fewer than 3 vertices");
    AddPolygon(polygon, mesh);
  }
  return mesh;
}

}  // namespace

TriangleMesh ReadMesh(const fs::path& path) {
  std::string ext = path.extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(),
                 [](unsigned char c) { return std::tolower(c); });
  TriangleMesh mesh;
  if (ext == ".ply") {
    mesh = ReadPlyMesh(path);
  } else if (ext == ".stl") {
    mesh = ReadStl(path, ReadTextFile(path));
  } else if (ext == ".obj") {
    mesh = ReadObj(path, ReadTextFile(path));
  } else {
    SLSHADOW_THROW(path.string(), ": unknown mesh format '", ext, "' (known: .stl, .ply, .obj)");
  }
  SLSHADOW_THROW_IF(mesh.triangles.empty(), path.string(), ": mesh has no triangles");
  return mesh;
}

void WriteMesh(const fs::path& path, const TriangleMesh& mesh) {
  mesh.Check(path.string(), false);
  const std::string ext = path.extension().string();
  std::string out;
  if (ext == ".ply") {
    out = "ply\nformat binary_little_endian 1.0\ncomment written by slshadow\nelement vertex " +
          std::to_string(mesh.vertices.size()) +
          "\nproperty double x\nproperty double y\nproperty double z\nelement face " +
          std::to_string(mesh.triangles.size()) +
          "\nproperty list uchar int vertex_indices\nend_header\n";
    out.reserve(out.size() + mesh.vertices.size() * 24 + mesh.triangles.size() * 13);
    for (const auto& v : mesh.vertices) out.append(reinterpret_cast<const char*>(v.data()), 24);
    for (const auto& t : mesh.triangles) {
      out.push_back(3);
      out.append(reinterpret_cast<const char*>(t.data()), 12);
    }
  } else if (ext == ".stl") {
    out.assign(80, '\0');
    std::memcpy(out.data(), "binary STL written by slshadow", 30);
    const uint32_t count = static_cast<uint32_t>(mesh.triangles.size());
    out.append(reinterpret_cast<const char*>(&count), 4);
    for (size_t i = 0; i < mesh.triangles.size(); ++i) {
      const Eigen::Vector3f n = mesh.FaceNormal(i).cast<float>();
      out.append(reinterpret_cast<const char*>(n.data()), 12);
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3f p = mesh.vertices[mesh.triangles[i][k]].cast<float>();
        out.append(reinterpret_cast<const char*>(p.data()), 12);
      }
      out.append(2, '\0');
    }
  } else {
    SLSHADOW_THROW(path.string(), ": unknown mesh format '", ext, "' (writable: .ply, .stl)");
  }
  WriteFileAtomically(path, [&](const fs::path& tmp) {
    std::ofstream f(tmp, std::ios::binary);
    SLSHADOW_THROW_IF(!f, path.string(), ": cannot open for writing");
    f.write(out.data(), static_cast<std::streamsize>(out.size()));
    f.close();
    SLSHADOW_THROW_IF(!f, path.string(), ": write failed (disk full?)");
  });
}

}  // namespace slshadow
