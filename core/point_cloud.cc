#include "core/point_cloud.h"

#include <algorithm>
#include <bit>
#include <cctype>
#include <cmath>
#include <cstring>
#include <fstream>
#include <functional>
#include <sstream>

#include "core/error.h"
#include "core/file_util.h"

namespace slshadow {
namespace fs = std::filesystem;

void PointCloud::SetScalar(const std::string& name, std::vector<float> values) {
  SLSHADOW_THROW_IF(values.size() != points.size(), "scalar field '", name, "': ", values.size(),
                    " values for ", points.size(), " points");
  for (auto& s : scalars) {
    if (s.name == name) {
      s.values = std::move(values);
      return;
    }
  }
  scalars.push_back({name, std::move(values)});
}

const std::vector<float>* PointCloud::Scalar(const std::string& name) const {
  for (const auto& s : scalars) {
    if (s.name == name) return &s.values;
  }
  return nullptr;
}

PointCloud PointCloud::Select(const std::vector<bool>& keep) const {
  SLSHADOW_CHECK(keep.size() == points.size());
  PointCloud out;
  for (const auto& s : scalars) out.scalars.push_back({s.name, {}});
  for (size_t i = 0; i < points.size(); ++i) {
    if (!keep[i]) continue;
    out.points.push_back(points[i]);
    if (HasNormals()) out.normals.push_back(normals[i]);
    if (HasColors()) out.colors.push_back(colors[i]);
    for (size_t k = 0; k < scalars.size(); ++k)
      out.scalars[k].values.push_back(scalars[k].values[i]);
  }
  return out;
}

void PointCloud::Append(const PointCloud& other) {
  if (empty()) {
    *this = other;
    return;
  }
  SLSHADOW_THROW_IF(HasNormals() != other.HasNormals() || HasColors() != other.HasColors() ||
                        scalars.size() != other.scalars.size(),
                    "cannot append point clouds with different attributes");
  points.insert(points.end(), other.points.begin(), other.points.end());
  normals.insert(normals.end(), other.normals.begin(), other.normals.end());
  colors.insert(colors.end(), other.colors.begin(), other.colors.end());
  for (size_t k = 0; k < scalars.size(); ++k) {
    SLSHADOW_THROW_IF(scalars[k].name != other.scalars[k].name,
                      "cannot append point clouds with different scalar fields");
    scalars[k].values.insert(scalars[k].values.end(), other.scalars[k].values.begin(),
                             other.scalars[k].values.end());
  }
}

void PointCloud::Check(const std::string& what) const {
  SLSHADOW_THROW_IF(!normals.empty() && normals.size() != points.size(), what, ": ", normals.size(),
                    " normals for ", points.size(), " points");
  SLSHADOW_THROW_IF(!colors.empty() && colors.size() != points.size(), what, ": ", colors.size(),
                    " colours for ", points.size(), " points");
  for (const auto& s : scalars) {
    SLSHADOW_THROW_IF(s.values.size() != points.size(), what, ": scalar field '", s.name, "' has ",
                      s.values.size(), " values for ", points.size(), " points");
    bool ok = !s.name.empty() && !std::isdigit(static_cast<unsigned char>(s.name[0]));
    for (char c : s.name) ok = ok && (std::isalnum(static_cast<unsigned char>(c)) || c == '_');
    SLSHADOW_THROW_IF(!ok, what, ": scalar field name '", s.name,
                      "' is not a valid PLY property name");
  }
}

// ---------------------------------------------------------------------------------------------
// Writing

namespace {

std::string FormatDouble(double v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.17g", v);
  return buf;
}
std::string FormatFloat(float v) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%.9g", static_cast<double>(v));
  return buf;
}

}  // namespace

void WritePly(const fs::path& path, const PointCloud& cloud, const PlyWriteOptions& options) {
  cloud.Check(path.string());
  std::string out;
  out += "ply\nformat ";
  out += options.binary ? "binary_little_endian 1.0\n" : "ascii 1.0\n";
  out += "comment written by slshadow\n";
  out += "element vertex " + std::to_string(cloud.size()) + "\n";
  const char* pos_type = options.double_positions ? "double" : "float";
  for (const char* c : {"x", "y", "z"}) out += std::string("property ") + pos_type + " " + c + "\n";
  if (cloud.HasNormals()) out += "property float nx\nproperty float ny\nproperty float nz\n";
  if (cloud.HasColors()) out += "property uchar red\nproperty uchar green\nproperty uchar blue\n";
  for (const auto& s : cloud.scalars) out += "property float " + s.name + "\n";
  out += "end_header\n";
  const size_t n = cloud.size();
  // Binary records are encoded into a buffer of at most kChunk records at a time and written
  // as they are (a 2 M-point cloud would otherwise need a second copy of ~100 MB in memory).
  static constexpr size_t kChunk = 16384;
  std::function<void(std::ofstream&)> write_records;
  if (options.binary) {
    // Fixed-size records written with memcpy (little-endian host assumed, as x86-64 and AArch64
    // Linux are; checked at compile time).
    static_assert(std::endian::native == std::endian::little,
                  "binary PLY writer assumes a little-endian host");
    const size_t pos_size = options.double_positions ? 24 : 12;
    const size_t stride = pos_size + (cloud.HasNormals() ? 12 : 0) + (cloud.HasColors() ? 3 : 0) +
                          4 * cloud.scalars.size();
    write_records = [&cloud, &options, n, pos_size, stride](std::ofstream& f) {
      std::string buffer(std::min(n, kChunk) * stride, '\0');
      for (size_t first = 0; first < n; first += kChunk) {
        const size_t last = std::min(n, first + kChunk);
        char* rec = buffer.data();
        for (size_t i = first; i < last; ++i) {
          if (options.double_positions) {
            std::memcpy(rec, cloud.points[i].data(), 24);
          } else {
            const Eigen::Vector3f p = cloud.points[i].cast<float>();
            std::memcpy(rec, p.data(), 12);
          }
          rec += pos_size;
          if (cloud.HasNormals()) {
            std::memcpy(rec, cloud.normals[i].data(), 12);
            rec += 12;
          }
          if (cloud.HasColors()) {
            std::memcpy(rec, cloud.colors[i].data(), 3);
            rec += 3;
          }
          for (const auto& sf : cloud.scalars) {
            std::memcpy(rec, &sf.values[i], 4);
            rec += 4;
          }
        }
        f.write(buffer.data(), static_cast<std::streamsize>((last - first) * stride));
      }
    };
  } else {
    // Appending piecewise (GCC 12 warns falsely about "literal" + std::string under -O2).
    auto put = [&out](const std::string& value, bool first) {
      if (!first) out.push_back(' ');
      out.append(value);
    };
    for (size_t i = 0; i < n; ++i) {
      for (int k = 0; k < 3; ++k) {
        put(options.double_positions ? FormatDouble(cloud.points[i][k])
                                     : FormatFloat(static_cast<float>(cloud.points[i][k])),
            k == 0);
      }
      if (cloud.HasNormals())
        for (int k = 0; k < 3; ++k) put(FormatFloat(cloud.normals[i][k]), false);
      if (cloud.HasColors())
        for (int k = 0; k < 3; ++k) put(std::to_string(cloud.colors[i][k]), false);
      for (const auto& s : cloud.scalars) put(FormatFloat(s.values[i]), false);
      out.push_back('\n');
    }
  }
  WriteFileAtomically(path, [&](const fs::path& tmp) {
    std::ofstream f(tmp, std::ios::binary);
    SLSHADOW_THROW_IF(!f, path.string(), ": cannot open for writing");
    f.write(out.data(), static_cast<std::streamsize>(out.size()));
    if (write_records) write_records(f);
    f.close();
    SLSHADOW_THROW_IF(!f, path.string(), ": write failed (disk full?)");
  });
}

// ---------------------------------------------------------------------------------------------
// Reading

namespace {

int TypeSize(const std::string& t) {
  if (t == "char" || t == "uchar") return 1;
  if (t == "short" || t == "ushort") return 2;
  if (t == "int" || t == "uint" || t == "float") return 4;
  if (t == "double") return 8;
  return 0;
}

std::string NormaliseType(const std::string& t) {
  if (t == "int8") return "char";
  if (t == "uint8") return "uchar";
  if (t == "int16") return "short";
  if (t == "uint16") return "ushort";
  if (t == "int32") return "int";
  if (t == "uint32") return "uint";
  if (t == "float32") return "float";
  if (t == "float64") return "double";
  return t;
}

class BinaryCursor {
 public:
  BinaryCursor(const std::string& data, size_t pos, bool big_endian, const std::string& file)
      : data_(data), pos_(pos), big_(big_endian), file_(file) {}
  double Read(const std::string& type, const std::string& element, size_t row) {
    const int size = TypeSize(type);
    if (pos_ + size > data_.size()) {
      SLSHADOW_THROW(file_, ": truncated binary PLY: data ends in element '", element, "' row ",
                     row);
    }
    char b[8];
    std::memcpy(b, data_.data() + pos_, size);
    pos_ += size;
    if (big_ != (std::endian::native == std::endian::big)) std::reverse(b, b + size);
    if (type == "char") {
      int8_t v;
      std::memcpy(&v, b, 1);
      return v;
    }
    if (type == "uchar") {
      uint8_t v;
      std::memcpy(&v, b, 1);
      return v;
    }
    if (type == "short") {
      int16_t v;
      std::memcpy(&v, b, 2);
      return v;
    }
    if (type == "ushort") {
      uint16_t v;
      std::memcpy(&v, b, 2);
      return v;
    }
    if (type == "int") {
      int32_t v;
      std::memcpy(&v, b, 4);
      return v;
    }
    if (type == "uint") {
      uint32_t v;
      std::memcpy(&v, b, 4);
      return v;
    }
    if (type == "float") {
      float v;
      std::memcpy(&v, b, 4);
      return v;
    }
    double v;
    std::memcpy(&v, b, 8);
    return v;
  }

 private:
  const std::string& data_;
  size_t pos_;
  bool big_;
  const std::string& file_;
};

// A list entry (e.g. a vertex index) as an integer; a non-integral, non-finite or huge value
// (a float list type allows them) is bad input, not a conversion with undefined behaviour.
int64_t ListValue(double v, const std::string& file, const std::string& element, size_t row,
                  const std::string& name) {
  SLSHADOW_THROW_IF(!(std::abs(v) <= 9.0e15) || v != std::floor(v), file, ": element '", element,
                    "' row ", row, " property '", name, "': list value ", v, " is not an integer");
  return static_cast<int64_t>(v);
}

void PushListOffset(std::vector<uint32_t>& offsets, size_t end, const std::string& file,
                    const std::string& element) {
  SLSHADOW_THROW_IF(end > UINT32_MAX, file, ": element '", element,
                    "': more than 2^32 list values");
  offsets.push_back(static_cast<uint32_t>(end));
}

}  // namespace

int PlyElement::PropertyIndex(const std::string& n) const {
  for (size_t i = 0; i < properties.size(); ++i) {
    if (properties[i].name == n) return static_cast<int>(i);
  }
  return -1;
}

const PlyElement* PlyData::Find(const std::string& n) const {
  for (const auto& e : elements) {
    if (e.name == n) return &e;
  }
  return nullptr;
}

PlyData ReadPlyData(const fs::path& path) {
  const std::string file = path.string();
  const std::string data = ReadTextFile(path);
  SLSHADOW_THROW_IF(data.compare(0, 3, "ply") != 0, file, ": not a PLY file (no 'ply' magic)");
  const size_t header_end = data.find("end_header");
  SLSHADOW_THROW_IF(header_end == std::string::npos, file, ": PLY header has no end_header");
  size_t body = data.find('\n', header_end);
  SLSHADOW_THROW_IF(body == std::string::npos, file, ": PLY header has no end_header line");
  ++body;
  PlyData ply;
  std::istringstream header(data.substr(0, header_end));
  std::string line;
  int line_no = 0;
  while (std::getline(header, line)) {
    ++line_no;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string key;
    words >> key;
    if (key.empty() || key == "ply" || key == "obj_info") continue;
    if (key == "comment") {
      ply.comments.push_back(line.size() > 8 ? line.substr(8) : "");
    } else if (key == "format") {
      std::string version;
      words >> ply.format >> version;
      SLSHADOW_THROW_IF(ply.format != "ascii" && ply.format != "binary_little_endian" &&
                            ply.format != "binary_big_endian",
                        file, ": PLY header line ", line_no, ": unknown format '", ply.format, "'");
    } else if (key == "element") {
      PlyElement e;
      long long count = -1;
      SLSHADOW_THROW_IF(!(words >> e.name >> count) || count < 0, file, ": PLY header line ",
                        line_no, ": bad element line '", line, "'");
      e.count = static_cast<size_t>(count);
      ply.elements.push_back(std::move(e));
    } else if (key == "property") {
      SLSHADOW_THROW_IF(ply.elements.empty(), file, ": PLY header line ", line_no,
                        ": property before any element");
      PlyProperty p;
      std::string type;
      words >> type;
      if (type == "list") {
        p.is_list = true;
        std::string count_type, value_type;
        words >> count_type >> value_type >> p.name;
        p.count_type = NormaliseType(count_type);
        p.type = NormaliseType(value_type);
        SLSHADOW_THROW_IF(
            TypeSize(p.count_type) == 0 || p.count_type == "float" || p.count_type == "double",
            file, ": PLY header line ", line_no, ": bad list count type '", count_type, "'");
      } else {
        p.type = NormaliseType(type);
        words >> p.name;
      }
      SLSHADOW_THROW_IF(TypeSize(p.type) == 0 || p.name.empty(), file, ": PLY header line ",
                        line_no, ": bad property line '", line, "'");
      ply.elements.back().properties.push_back(p);
    } else {
      SLSHADOW_THROW(file, ": PLY header line ", line_no, ": unknown keyword '", key, "'");
    }
  }
  SLSHADOW_THROW_IF(ply.format.empty(), file, ": PLY header has no format line");
  // Element counts come from the header: bound them by the data actually present before
  // anything is allocated. A binary row takes at least the sizes of its scalar properties and
  // list counts; an ASCII value at least two characters (a digit and a separator).
  {
    const bool ascii = ply.format == "ascii";
    uint64_t left = data.size() - body;
    for (const auto& e : ply.elements) {
      uint64_t row = 0;
      for (const auto& p : e.properties)
        row += ascii ? 2 : TypeSize(p.is_list ? p.count_type : p.type);
      row = std::max<uint64_t>(row, 1);
      // The last ASCII value may end the file without a separator.
      const uint64_t room = left + (ascii ? 1 : 0);
      SLSHADOW_THROW_IF(e.count > room / row, file, ": PLY header: element '", e.name, "' claims ",
                        e.count, " rows, but the file has only ", data.size() - body,
                        " bytes of data (at least ", row, " bytes per row)");
      left -= std::min<uint64_t>(left, e.count * row);
    }
  }
  for (auto& e : ply.elements) {
    e.columns.assign(e.properties.size(), {});
    e.list_offsets.assign(e.properties.size(), {});
    e.list_values.assign(e.properties.size(), {});
    for (size_t k = 0; k < e.properties.size(); ++k) {
      if (e.properties[k].is_list) {
        e.list_offsets[k].reserve(e.count + 1);
        e.list_offsets[k].push_back(0);
      } else {
        e.columns[k].reserve(e.count);
      }
    }
  }
  if (ply.format == "ascii") {
    std::istringstream in(data.substr(body));
    for (auto& e : ply.elements) {
      for (size_t row = 0; row < e.count; ++row) {
        for (size_t k = 0; k < e.properties.size(); ++k) {
          const auto& p = e.properties[k];
          auto read_value = [&]() {
            std::string token;
            SLSHADOW_THROW_IF(!(in >> token), file, ": truncated ASCII PLY: data ends in element '",
                              e.name, "' row ", row);
            char* end = nullptr;
            const double v = std::strtod(token.c_str(), &end);
            SLSHADOW_THROW_IF(end == token.c_str() || *end != '\0', file, ": element '", e.name,
                              "' row ", row, " property '", p.name, "': not a number (got \"",
                              token, "\")");
            return v;
          };
          if (p.is_list) {
            const double n = read_value();
            // Each value takes at least one byte, which bounds a sane length.
            SLSHADOW_THROW_IF(
                !(n >= 0 && n <= static_cast<double>(data.size())) || n != std::floor(n), file,
                ": element '", e.name, "' row ", row, " property '", p.name, "': bad list length ",
                n);
            for (size_t i = 0; i < static_cast<size_t>(n); ++i) {
              e.list_values[k].push_back(ListValue(read_value(), file, e.name, row, p.name));
            }
            PushListOffset(e.list_offsets[k], e.list_values[k].size(), file, e.name);
          } else {
            e.columns[k].push_back(read_value());
          }
        }
      }
    }
  } else {
    BinaryCursor cursor(data, body, ply.format == "binary_big_endian", file);
    for (auto& e : ply.elements) {
      for (size_t row = 0; row < e.count; ++row) {
        for (size_t k = 0; k < e.properties.size(); ++k) {
          const auto& p = e.properties[k];
          if (p.is_list) {
            const double n = cursor.Read(p.count_type, e.name, row);
            SLSHADOW_THROW_IF(n < 0, file, ": element '", e.name, "' row ", row, " property '",
                              p.name, "': bad list length ", n);
            // n <= 2^32 - 1 (an integer count type); a value beyond the data throws 'truncated'.
            for (size_t i = 0; i < static_cast<size_t>(n); ++i) {
              e.list_values[k].push_back(
                  ListValue(cursor.Read(p.type, e.name, row), file, e.name, row, p.name));
            }
            PushListOffset(e.list_offsets[k], e.list_values[k].size(), file, e.name);
          } else {
            e.columns[k].push_back(cursor.Read(p.type, e.name, row));
          }
        }
      }
    }
  }
  return ply;
}

PointCloud ReadPly(const fs::path& path) {
  const PlyData ply = ReadPlyData(path);
  const PlyElement* v = ply.Find("vertex");
  SLSHADOW_THROW_IF(v == nullptr, path.string(), ": PLY has no 'vertex' element");
  // Index of a scalar vertex property, -1 when absent; a list of that name is bad input.
  const auto scalar = [&](const char* name) {
    const int i = v->PropertyIndex(name);
    SLSHADOW_THROW_IF(i >= 0 && v->properties[i].is_list, path.string(), ": PLY vertex property '",
                      name, "' is a list, expected a number");
    return i;
  };
  const int ix = scalar("x"), iy = scalar("y"), iz = scalar("z");
  SLSHADOW_THROW_IF(ix < 0 || iy < 0 || iz < 0, path.string(),
                    ": PLY vertex element lacks x, y or z");
  PointCloud cloud;
  cloud.points.resize(v->count);
  for (size_t i = 0; i < v->count; ++i) {
    cloud.points[i] = {v->columns[ix][i], v->columns[iy][i], v->columns[iz][i]};
    SLSHADOW_THROW_IF(!cloud.points[i].allFinite(), path.string(), ": vertex ", i,
                      " has a non-finite coordinate");
  }
  std::vector<bool> used(v->properties.size(), false);
  used[ix] = used[iy] = used[iz] = true;
  const int inx = scalar("nx"), iny = scalar("ny"), inz = scalar("nz");
  if (inx >= 0 && iny >= 0 && inz >= 0) {
    cloud.normals.resize(v->count);
    for (size_t i = 0; i < v->count; ++i) {
      cloud.normals[i] =
          Eigen::Vector3d(v->columns[inx][i], v->columns[iny][i], v->columns[inz][i]).cast<float>();
    }
    used[inx] = used[iny] = used[inz] = true;
  }
  const int ir = scalar("red"), ig = scalar("green"), ib = scalar("blue");
  if (ir >= 0 && ig >= 0 && ib >= 0) {
    cloud.colors.resize(v->count);
    const bool is_float = v->properties[ir].type == "float" || v->properties[ir].type == "double";
    for (size_t i = 0; i < v->count; ++i) {
      for (int k = 0; k < 3; ++k) {
        double c = v->columns[k == 0 ? ir : k == 1 ? ig : ib][i];
        if (is_float) c *= 255.0;
        cloud.colors[i][k] =
            std::isnan(c) ? 0 : static_cast<uint8_t>(std::lround(std::clamp(c, 0.0, 255.0)));
      }
    }
    used[ir] = used[ig] = used[ib] = true;
  }
  for (size_t k = 0; k < v->properties.size(); ++k) {
    if (used[k] || v->properties[k].is_list) continue;
    std::vector<float> values(v->columns[k].begin(), v->columns[k].end());
    cloud.scalars.push_back({v->properties[k].name, std::move(values)});
  }
  return cloud;
}

}  // namespace slshadow
