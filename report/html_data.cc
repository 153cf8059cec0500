// The 3D view's data: clouds and meshes packed as base64 typed arrays
// (report/internal/html_page.h).
#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <limits>
#include <map>
#include <random>
#include <sstream>

#include "core/error.h"
#include "core/point_cloud.h"
#include "plot/plot.h"
#include "report/internal/html_page.h"

namespace slshadow::report::internal {
namespace fs = std::filesystem;

std::string Base64(const void* data, size_t bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  const auto* p = static_cast<const unsigned char*>(data);
  std::string out;
  out.reserve((bytes + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes; i += 3) {
    const uint32_t v = (uint32_t{p[i]} << 16) | (uint32_t{p[i + 1]} << 8) | p[i + 2];
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += kAlphabet[(v >> 6) & 63];
    out += kAlphabet[v & 63];
  }
  if (i < bytes) {
    const uint32_t v = (uint32_t{p[i]} << 16) | (i + 1 < bytes ? uint32_t{p[i + 1]} << 8 : 0u);
    out += kAlphabet[(v >> 18) & 63];
    out += kAlphabet[(v >> 12) & 63];
    out += i + 1 < bytes ? kAlphabet[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::vector<uint8_t> ColourLut() {
  std::vector<uint8_t> lut;
  for (int k = 0; k < 255; ++k) {
    const auto c = plot::HeatColor(k / 254.0);
    lut.insert(lut.end(), c.begin(), c.end());
  }
  lut.insert(lut.end(), {128, 128, 128});
  return lut;
}

size_t PlyVertexCount(const fs::path& ply) {
  std::ifstream in(ply, std::ios::binary);
  std::string line;
  while (in && std::getline(in, line)) {
    if (line.rfind("element vertex ", 0) == 0) return std::stoul(line.substr(15));
    if (line.rfind("end_header", 0) == 0) break;
  }
  return 0;
}

namespace {

template <typename T>
std::string Block(const std::vector<T>& v) {
  return Base64(v.data(), v.size() * sizeof(T));
}

// The vertex columns the page needs, read straight from a binary little-endian PLY (the format
// slshadow writes; core's ReadPly parses every property of every row generically, several
// seconds for the demo's clouds). Other files go through ReadPly. Returns false when the file
// is not binary little-endian or its vertex element is not the first.
bool ReadColumnsFast(const fs::path& path, const std::vector<std::string>& scalars,
                     PointCloud* cloud) {
  std::ifstream in(path, std::ios::binary);
  std::string line;
  if (!std::getline(in, line) || line != "ply") return false;
  struct Prop {
    std::string name;
    int size = 0;
    char kind = 'f';  // f: float, d: double, i/u: integers
  };
  std::vector<Prop> props;
  size_t count = 0;
  bool vertex = false, seen_vertex = false, binary_le = false;
  const std::map<std::string, std::pair<int, char>> types = {
      {"char", {1, 'i'}},  {"uchar", {1, 'u'}},  {"short", {2, 'i'}},   {"ushort", {2, 'u'}},
      {"int", {4, 'i'}},   {"uint", {4, 'u'}},   {"float", {4, 'f'}},   {"double", {8, 'd'}},
      {"int8", {1, 'i'}},  {"uint8", {1, 'u'}},  {"int16", {2, 'i'}},   {"uint16", {2, 'u'}},
      {"int32", {4, 'i'}}, {"uint32", {4, 'u'}}, {"float32", {4, 'f'}}, {"float64", {8, 'd'}}};
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string w, type, name;
    words >> w;
    if (w == "format") {
      words >> type;
      binary_le = type == "binary_little_endian";
    } else if (w == "element") {
      words >> name >> count;
      if (vertex || seen_vertex) {
        vertex = false;
      } else if (name != "vertex") {
        return false;
      } else {
        vertex = seen_vertex = true;
      }
    } else if (w == "property" && vertex) {
      words >> type >> name;
      const auto t = types.find(type);
      if (t == types.end()) return false;  // a list in the vertex element
      props.push_back({name, t->second.first, t->second.second});
    } else if (w == "end_header") {
      break;
    }
  }
  if (!binary_le || !seen_vertex || !in) return false;
  size_t stride = 0;
  std::map<std::string, std::pair<size_t, Prop>> at;
  for (const auto& p : props) {
    at[p.name] = {stride, p};
    stride += static_cast<size_t>(p.size);
  }
  for (const char* c : {"x", "y", "z"}) {
    if (!at.count(c)) return false;
  }
  std::string body(count * stride, '\0');
  in.read(body.data(), static_cast<std::streamsize>(body.size()));
  SLSHADOW_THROW_IF(static_cast<size_t>(in.gcount()) != body.size(), path.string(),
                    ": truncated: ", count, " vertices announced");
  const auto value = [&](size_t row, const std::pair<size_t, Prop>& col) -> double {
    const char* b = body.data() + row * stride + col.first;
    switch (col.second.kind) {
      case 'f': {
        float f;
        std::memcpy(&f, b, 4);
        return f;
      }
      case 'd': {
        double d;
        std::memcpy(&d, b, 8);
        return d;
      }
      default: {
        int64_t v = 0;
        uint64_t u = 0;
        std::memcpy(&u, b, static_cast<size_t>(col.second.size));
        if (col.second.kind == 'i' && col.second.size < 8 && (u >> (8 * col.second.size - 1)) & 1)
          u |= ~uint64_t{0} << (8 * col.second.size);
        std::memcpy(&v, &u, 8);
        return col.second.kind == 'i' ? static_cast<double>(v) : static_cast<double>(u);
      }
    }
  };
  cloud->points.resize(count);
  const auto &cx = at["x"], &cy = at["y"], &cz = at["z"];
  for (size_t r = 0; r < count; ++r)
    cloud->points[r] = Eigen::Vector3d(value(r, cx), value(r, cy), value(r, cz));
  for (const auto& s : scalars) {
    const auto it = at.find(s);
    if (it == at.end()) continue;
    std::vector<float> v(count);
    for (size_t r = 0; r < count; ++r) v[r] = static_cast<float>(value(r, it->second));
    cloud->SetScalar(s, std::move(v));
  }
  return true;
}

const ScalarField* Field(const PointCloud& cloud, const std::string& name) {
  for (const auto& s : cloud.scalars) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

}  // namespace

double AbsPercentile99(const std::vector<fs::path>& plys, const std::string& field) {
  std::vector<float> values;
  for (const auto& ply : plys) {
    std::error_code ec;
    if (!fs::exists(ply, ec)) continue;
    PointCloud cloud;
    if (!ReadColumnsFast(ply, {field}, &cloud)) cloud = ReadPly(ply);
    for (const auto& s : cloud.scalars) {
      if (s.name != field) continue;
      for (const float v : s.values) {
        if (std::isfinite(v)) values.push_back(std::abs(v));
      }
    }
  }
  if (values.empty()) return 0;
  const size_t rank = std::max<size_t>(
      1, static_cast<size_t>(std::ceil(0.99 * static_cast<double>(values.size()))));
  std::nth_element(values.begin(), values.begin() + static_cast<long>(rank - 1), values.end());
  return values[rank - 1];
}

CloudLayer PackCloud(const fs::path& ply, const std::string& source, const std::string& id,
                     const std::string& name, const std::string& deviation_field,
                     const ColourScale& scale, size_t budget) {
  CloudLayer layer;
  layer.id = id;
  layer.name = name;
  layer.source = source;
  layer.deviation_field = deviation_field;
  layer.scale = scale;
  std::error_code ec;
  PointCloud cloud;
  if (!fs::exists(ply, ec)) {
    layer.empty_reason = source + " is missing: no points to show";
  } else if (!ReadColumnsFast(ply, {deviation_field, "u", "v", "view"}, &cloud)) {
    cloud = ReadPly(ply);
  }
  layer.total_points = cloud.size();
  const ScalarField* dev = Field(cloud, deviation_field);
  const ScalarField* u = Field(cloud, "u");
  const ScalarField* v = Field(cloud, "v");
  const ScalarField* view = Field(cloud, "view");
  std::vector<uint32_t> ok;
  ok.reserve(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    if (dev && std::isfinite(dev->values[i]) && cloud.points[i].allFinite())
      ok.push_back(static_cast<uint32_t>(i));
  }
  layer.displayable = ok.size();
  layer.nonfinite_deviation = cloud.size() - ok.size();
  if (layer.empty_reason.empty()) {
    if (cloud.empty()) {
      layer.empty_reason = source + " has no points: nothing to show";
    } else if (!dev) {
      layer.empty_reason = source + " has no '" + deviation_field + "' field: nothing to colour";
    } else if (ok.empty()) {
      layer.empty_reason = "none of the " + std::to_string(cloud.size()) + " points of " + source +
                           " has a finite deviation (" + deviation_field +
                           " is NaN or infinite): nothing to show";
    }
  }
  // Selection sampling (Knuth's algorithm S): exactly `budget` of the points, order kept.
  if (ok.size() > budget) {
    std::mt19937_64 rng(20261207);
    std::uniform_real_distribution<double> uniform(0.0, 1.0);
    std::vector<uint32_t> kept;
    kept.reserve(budget);
    const size_t n = ok.size();
    for (size_t i = 0; i < n && kept.size() < budget; ++i) {
      if (static_cast<double>(n - i) * uniform(rng) < static_cast<double>(budget - kept.size()))
        kept.push_back(ok[i]);
    }
    ok.swap(kept);
  }
  layer.shown = ok.size();
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (const uint32_t i : ok) {
    lo = lo.cwiseMin(cloud.points[i]);
    hi = hi.cwiseMax(cloud.points[i]);
  }
  if (ok.empty()) lo = hi = Eigen::Vector3d::Zero();
  const Eigen::Vector3d step = ((hi - lo) / 65535.0).cwiseMax(1e-9);
  std::vector<uint16_t> pos(3 * ok.size());
  std::vector<float> deviation(ok.size());
  std::vector<uint16_t> uv;
  std::vector<uint16_t> views;
  // The camera pixel in 1/8 px (0 .. 8191.875 px; 65535: none): rounding <= 1/16 px.
  const auto eighths = [](float p) -> uint16_t {
    return std::isfinite(p) && p >= 0 && p < 8191.9375f ? static_cast<uint16_t>(std::lround(p * 8))
                                                        : uint16_t{65535};
  };
  for (size_t k = 0; k < ok.size(); ++k) {
    const uint32_t i = ok[k];
    for (int a = 0; a < 3; ++a) {
      const double q = std::round((cloud.points[i][a] - lo[a]) / step[a]);
      pos[3 * k + static_cast<size_t>(a)] = static_cast<uint16_t>(std::clamp(q, 0.0, 65535.0));
    }
    deviation[k] = dev->values[i];
    if (u && v) {
      uv.push_back(eighths(u->values[i]));
      uv.push_back(eighths(v->values[i]));
    }
    if (view) {
      const float w = view->values[i];
      views.push_back(std::isfinite(w) && w >= 0 && w < 65535 ? static_cast<uint16_t>(w) : 65535);
    }
  }
  nlohmann::json blocks;
  const auto add = [&](const std::string& key, std::string data) {
    blocks[key] = id + "-" + key;
    layer.blocks.emplace_back(id + "-" + key, std::move(data));
  };
  add("pos", Block(pos));
  add("dev", Block(deviation));
  if (u && v) add("uv", Block(uv));
  if (view) add("view", Block(views));
  layer.meta = {{"id", id},
                {"name", name},
                {"source", source},
                {"field", deviation_field},
                {"total", layer.total_points},
                {"displayable", layer.displayable},
                {"nonfinite", layer.nonfinite_deviation},
                {"shown", layer.shown},
                {"empty_reason", layer.empty_reason},
                {"min", {lo.x(), lo.y(), lo.z()}},
                {"step", {step.x(), step.y(), step.z()}},
                {"lo", scale.lo},
                {"hi", scale.hi},
                {"blocks", blocks}};
  return layer;
}

MeshLayer PackMesh(const TriangleMesh& mesh, const std::string& id, const std::string& name,
                   const std::string& source) {
  MeshLayer layer;
  layer.id = id;
  layer.name = name;
  layer.source = source;
  layer.triangles = mesh.NumTriangles();
  const Eigen::Vector3d lo = mesh.BoundsMin();
  const Eigen::Vector3d step = ((mesh.BoundsMax() - lo) / 65535.0).cwiseMax(1e-9);
  std::vector<uint16_t> vertices;
  vertices.reserve(3 * mesh.vertices.size());
  for (const auto& p : mesh.vertices) {
    for (int a = 0; a < 3; ++a)
      vertices.push_back(
          static_cast<uint16_t>(std::clamp(std::round((p[a] - lo[a]) / step[a]), 0.0, 65535.0)));
  }
  const bool short_indices = mesh.vertices.size() <= 65536;
  std::vector<uint32_t> indices;
  std::vector<uint16_t> short_ones;
  for (const auto& t : mesh.triangles) {
    for (int a = 0; a < 3; ++a) {
      if (short_indices) {
        short_ones.push_back(static_cast<uint16_t>(t[a]));
      } else {
        indices.push_back(static_cast<uint32_t>(t[a]));
      }
    }
  }
  layer.blocks = {{id + "-vertices", Block(vertices)},
                  {id + "-indices", short_indices ? Block(short_ones) : Block(indices)}};
  layer.meta = {{"id", id},
                {"name", name},
                {"source", source},
                {"triangles", layer.triangles},
                {"min", {lo.x(), lo.y(), lo.z()}},
                {"step", {step.x(), step.y(), step.z()}},
                {"index_bytes", short_indices ? 2 : 4},
                {"blocks", {{"vertices", id + "-vertices"}, {"indices", id + "-indices"}}}};
  return layer;
}

}  // namespace slshadow::report::internal
