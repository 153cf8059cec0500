// PointCloud: positions (mm, in the frame the producer states), optional normals and colours, and
// named per-point scalar fields (quality, source pixel, distance, ...). Stored as PLY, binary
// little-endian or ASCII, which CloudCompare, MeshLab and Open3D read; scalar fields become extra
// vertex properties that CloudCompare shows as scalar fields (docs/formats.md "PLY").
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>

namespace slshadow {

struct ScalarField {
  std::string name;           // PLY property name: letters, digits and '_' only
  std::vector<float> values;  // one per point
};

struct PointCloud {
  std::vector<Eigen::Vector3d> points;
  std::vector<Eigen::Vector3f> normals;        // empty, or one unit vector per point
  std::vector<std::array<uint8_t, 3>> colors;  // empty, or one RGB per point
  std::vector<ScalarField> scalars;            // each with one value per point

  size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
  bool HasNormals() const { return !normals.empty(); }
  bool HasColors() const { return !colors.empty(); }

  // Adds or replaces a scalar field; `values` must have one entry per point.
  void SetScalar(const std::string& name, std::vector<float> values);
  // The field's values, or nullptr when there is no field of that name.
  const std::vector<float>* Scalar(const std::string& name) const;

  // Keeps the points whose flag is true (all attributes follow).
  PointCloud Select(const std::vector<bool>& keep) const;
  void Append(const PointCloud& other);  // attribute sets must match

  // Throws slshadow::Error naming `what` when attribute lengths differ from the point count or a
  // scalar field name is not a valid PLY property name.
  void Check(const std::string& what) const;
};

struct PlyWriteOptions {
  bool binary = true;            // binary_little_endian 1.0, else ascii 1.0
  bool double_positions = true;  // x, y, z as double (bit-exact round trip), else float
};

void WritePly(const std::filesystem::path& path, const PointCloud& cloud,
              const PlyWriteOptions& options = {});
// Reads the vertex element: x, y, z (float or double), optional nx, ny, nz, red, green, blue;
// every other scalar vertex property becomes a scalar field. Faces, if any, are ignored.
PointCloud ReadPly(const std::filesystem::path& path);

// The generic PLY reader underneath ReadPly (also used for meshes). Values of scalar properties
// are widened to double; list properties (e.g. vertex_indices) are kept as offsets + values.
struct PlyProperty {
  std::string name;
  std::string type;  // PLY type name of the value, normalised: char uchar short ushort int uint
                     // float double
  bool is_list = false;
  std::string count_type;  // for lists
};
struct PlyElement {
  std::string name;
  size_t count = 0;
  std::vector<PlyProperty> properties;
  std::vector<std::vector<double>> columns;  // per scalar property (empty for list properties)
  std::vector<std::vector<uint32_t>> list_offsets;   // per list property: count + 1 offsets
  std::vector<std::vector<int64_t>> list_values;     // per list property: concatenated values
  int PropertyIndex(const std::string& name) const;  // -1 when absent
};
struct PlyData {
  std::string format;  // "ascii", "binary_little_endian" or "binary_big_endian"
  std::vector<std::string> comments;
  std::vector<PlyElement> elements;
  const PlyElement* Find(const std::string& name) const;
};
// Throws slshadow::Error naming the file and what is wrong (bad header, truncated data, bad value).
PlyData ReadPlyData(const std::filesystem::path& path);

}  // namespace slshadow
