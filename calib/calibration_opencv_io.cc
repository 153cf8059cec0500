// OpenCV FileStorage calibration files: export of a rig, and the import of camera, stereo and
// camera + projector files (calib/calibration_io.h "OpenCV calibration files").
#include "calib/calibration_io.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <numbers>
#include <optional>
#include <set>
#include <utility>

#include <yaml-cpp/yaml.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"

namespace slshadow {
namespace {

// The top-level nodes of an OpenCV file, and which of them the import has read: operator[] looks
// at a node (to recognise a layout), Read marks it as read.
class Nodes {
 public:
  explicit Nodes(const cv::FileStorage& fs) : fs_(fs) {}
  cv::FileNode operator[](const std::string& key) const { return fs_[key]; }
  cv::FileNode Read(const std::string& key) {
    used_.insert(key);
    return fs_[key];
  }
  cv::FileNode root() const { return fs_.root(); }
  bool WasRead(const std::string& key) const { return used_.count(key) > 0; }

 private:
  const cv::FileStorage& fs_;
  std::set<std::string> used_;
};

// A matrix node (!!opencv-matrix) or a plain list of numbers (as a 1xN matrix), CV_64F; empty
// when the node is absent.
cv::Mat ReadAnyMat(Nodes& fs, const std::string& key, const std::filesystem::path& path) {
  const cv::FileNode node = fs.Read(key);
  cv::Mat m;
  if (node.empty()) return m;
  if (node.isSeq()) {
    std::vector<double> values;
    for (const cv::FileNode& v : node) {
      SLSHADOW_THROW_IF(!v.isReal() && !v.isInt(), path.string(), ": ", key,
                        ": expected numbers in the list");
      values.push_back(static_cast<double>(v));
    }
    return cv::Mat(values, true).reshape(1, 1);
  }
  if (node.isReal() || node.isInt())
    return cv::Mat(1, 1, CV_64F, cv::Scalar(static_cast<double>(node)));
  // OpenCV allocates rows x cols before reading the data: the claimed size is checked against the
  // values present first (a header claiming 10^5 x 10^5 is an error, not a 80 GB allocation).
  if (node.isMap()) {
    // A rows or cols that is not an integer is read by OpenCV as some other count (found by
    // fuzzing: fuzz/regressions/opencv_calibration/matrix-rows-not-an-integer.yml).
    SLSHADOW_THROW_IF(!node["rows"].isInt() || !node["cols"].isInt(), path.string(), ": ", key,
                      ": a matrix needs integer 'rows' and 'cols'");
    const int64_t rows = static_cast<int>(node["rows"]), cols = static_cast<int>(node["cols"]);
    const cv::FileNode data = node["data"];
    const int64_t values = data.isSeq() ? static_cast<int64_t>(data.size()) : 0;
    SLSHADOW_THROW_IF(rows < 0 || cols < 0 || rows * cols > values, path.string(), ": ", key,
                      ": matrix claims ", rows, " x ", cols, " but holds ", values, " values");
  }
  try {
    node >> m;
  } catch (const cv::Exception&) {
    SLSHADOW_THROW(path.string(), ": ", key, ": not a matrix or a list of numbers");
  }
  SLSHADOW_THROW_IF(m.empty() && !node.empty(), path.string(), ": ", key,
                    ": not a matrix or a list of numbers");
  m.convertTo(m, CV_64F);
  return m;
}

cv::Mat ReadMat(Nodes& fs, const std::string& key, const std::filesystem::path& path, int rows,
                int cols) {
  cv::Mat m = ReadAnyMat(fs, key, path);
  SLSHADOW_THROW_IF(m.empty(), path.string(), ": ", key, ": missing");
  m.convertTo(m, CV_64F);
  if (rows * cols == static_cast<int>(m.total()) && (m.rows != rows || m.cols != cols))
    m = m.reshape(1, rows);
  SLSHADOW_THROW_IF(m.rows != rows || m.cols != cols, path.string(), ": ", key, ": expected a ",
                    rows, "x", cols, " matrix (got ", m.rows, "x", m.cols, ")");
  return m;
}

CameraModel ModelFromMats(const cv::Mat& k, const cv::Mat& dist_in, int width, int height,
                          const std::string& what) {
  cv::Mat dist = dist_in.reshape(1, 1);
  SLSHADOW_THROW_IF(dist.total() < 4, what, ": distortion: needs at least 4 coefficients (got ",
                    dist.total(), ")");
  for (size_t i = 5; i < dist.total(); ++i) {
    SLSHADOW_THROW_IF(dist.at<double>(0, static_cast<int>(i)) != 0.0, what,
                      ": distortion: coefficient ", i,
                      " is not zero; slshadow's model has k1 k2 p1 p2 k3 only (OpenCV's "
                      "rational/thin-prism terms "
                      "cannot be imported)");
  }
  auto d = [&](int i) { return i < static_cast<int>(dist.total()) ? dist.at<double>(0, i) : 0.0; };
  CameraModel m(width, height, k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2),
                k.at<double>(1, 2), d(0), d(1), d(2), d(3), d(4));
  SLSHADOW_THROW_IF(std::abs(k.at<double>(0, 1)) > 1e-9, what, ": camera matrix has skew ",
                    k.at<double>(0, 1), "; slshadow's model has none");
  m.Check(what);
  return m;
}

cv::Mat KMat(const CameraModel& m) {
  return (cv::Mat_<double>(3, 3) << m.fx(), 0, m.cx(), 0, m.fy(), m.cy(), 0, 0, 1);
}
cv::Mat DMat(const CameraModel& m) {
  return (cv::Mat_<double>(1, 5) << m.k1(), m.k2(), m.p1(), m.p2(), m.k3());
}

Rigid3d PoseFromRT(const cv::Mat& r, const cv::Mat& t) {
  Eigen::Matrix3d rot;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) rot(i, j) = r.at<double>(i, j);
  }
  return Rigid3d(Eigen::Quaterniond(rot),
                 Eigen::Vector3d(t.at<double>(0), t.at<double>(1), t.at<double>(2)));
}

cv::Mat RotationMatrixOrRvec(Nodes& fs, const std::string& key, const std::filesystem::path& path) {
  cv::Mat m = ReadAnyMat(fs, key, path);
  SLSHADOW_THROW_IF(m.empty(), path.string(), ": ", key, ": missing");
  if (m.total() == 9) m = m.reshape(1, 3);
  if (m.total() == 3) {
    cv::Mat r;
    cv::Rodrigues(m.reshape(1, 3), r);
    return r;
  }
  SLSHADOW_THROW_IF(m.rows != 3 || m.cols != 3, path.string(), ": ", key,
                    ": expected a 3x3 rotation matrix or a Rodrigues vector");
  const Eigen::Matrix3d e =
      Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(m.ptr<double>());
  SLSHADOW_THROW_IF(
      (e * e.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-5 || e.determinant() < 0,
      path.string(), ": ", key, ": not a rotation matrix");
  return m;
}

cv::Mat ReadDist(Nodes& fs, const std::string& key, const std::filesystem::path& path) {
  cv::Mat m = ReadAnyMat(fs, key, path);
  SLSHADOW_THROW_IF(m.empty(), path.string(), ": ", key, ": missing");
  return m;
}

// A size or count read as a double (FileStorage stores numbers as either), as an int: a value that
// is not finite, not whole or beyond +-10^6 is bad input (converting it would be undefined).
int CheckedInt(double v, const std::filesystem::path& path, const std::string& key) {
  SLSHADOW_THROW_IF(!(std::abs(v) <= 1e6) || v != std::floor(v), path.string(), ": ", key,
                    ": expected a whole number within +-1000000 (got ", v, ")");
  return static_cast<int>(v);
}

// An image size node: [width, height] (cv::Size) or a matrix of two numbers; nullopt if absent.
std::optional<std::pair<int, int>> ReadSize(Nodes& fs, const std::string& key,
                                            const std::filesystem::path& path) {
  if (key.empty() || fs[key].empty()) return std::nullopt;
  const cv::Mat m = ReadAnyMat(fs, key, path);
  SLSHADOW_THROW_IF(m.total() != 2, path.string(), ": ", key,
                    ": expected an image size [width, height] (got ", m.total(), " numbers)");
  return std::pair<int, int>(CheckedInt(m.at<double>(0), path, key),
                             CheckedInt(m.at<double>(1), path, key));
}

// "cam_K (3x3 matrix)", "S ([2 values])", "name (string)": a top-level node and its shape.
std::string DescribeNode(const cv::FileNode& n) {
  std::string what;
  if (n.isSeq()) {
    what = internal::Concat("[", n.size(), " values]");
  } else if (n.isMap()) {
    what = !n["rows"].empty() && !n["cols"].empty()
               ? internal::Concat(static_cast<int>(n["rows"]), "x", static_cast<int>(n["cols"]),
                                  " matrix")
               : std::string("mapping");
  } else {
    what = n.isString() ? "string" : "number";
  }
  return internal::Concat(n.name(), " (", what, ")");
}

// All top-level nodes, described: "cam_K (3x3 matrix), dist (1x5 matrix), ...".
std::string DescribeNodes(const Nodes& fs) {
  std::string out;
  for (const cv::FileNode& n : fs.root())
    out = internal::Concat(out, out.empty() ? "" : ", ", DescribeNode(n));
  return out.empty() ? "none" : out;
}

// The built-in two-camera layouts other than slshadow's / stereo_calib.cpp's.
OpenCvNodeMap StructuredLightSampleLayout(const Nodes& fs) {
  const std::string d1 = fs["cam1_distorsion"].empty() ? "cam1_distortion" : "cam1_distorsion";
  const std::string d2 = fs["cam2_distorsion"].empty() ? "cam2_distortion" : "cam2_distorsion";
  OpenCvNodeMap map;
  map.k1 = "cam1_intrinsics";
  map.d1 = d1;
  map.k2 = "cam2_intrinsics";
  map.d2 = d2;
  map.r = "R";
  map.t = "T";
  map.size1 = "cam1_size";
  map.size2 = "cam2_size";
  return map;
}

// The binocular layout: M1 D1, and M2 D2 with Rlr Tlr (left to right) when present, both cameras'
// size in S; with Rlp Tlp (left to projector), the projector is the one matrix M<k> (k = 2..9,
// with its D<k>) that is not a camera's. Throws, naming the candidates, when there are several.
OpenCvNodeMap BinocularLayout(const Nodes& fs, const std::filesystem::path& path) {
  OpenCvNodeMap map;
  map.k1 = "M1";
  map.d1 = "D1";
  map.size1 = "S";
  const bool second = !fs["Rlr"].empty();
  if (second) {
    map.k2 = "M2";
    map.d2 = "D2";
    map.r = "Rlr";
    map.t = "Tlr";
  }
  if (!fs["Rlp"].empty() && !fs["Tlp"].empty()) {
    std::vector<int> candidates;
    for (int k = second ? 3 : 2; k <= 9; ++k) {
      const std::string s = std::to_string(k);
      if (!fs["M" + s].empty() && !fs["D" + s].empty()) candidates.push_back(k);
    }
    std::string names;
    for (int k : candidates) names += internal::Concat(names.empty() ? "" : ", ", "M", k);
    SLSHADOW_THROW_IF(candidates.size() > 1, path.string(),
                      ": Rlp/Tlp give a projector pose, but which matrix is the projector's? (",
                      names, "); name it with --map KP=NODE,DP=NODE,RP=Rlp,TP=Tlp");
    if (candidates.size() == 1) {
      map.kp = "M" + std::to_string(candidates[0]);
      map.dp = "D" + std::to_string(candidates[0]);
      map.rp = "Rlp";
      map.tp = "Tlp";
    }
  }
  return map;
}

// One or two cameras, and a projector, from explicitly named nodes.
Rig ReadMappedLayout(Nodes& fs, const OpenCvNodeMap& map, const std::filesystem::path& path,
                     int default_width, int default_height, int projector_width,
                     int projector_height) {
  const std::string file = path.string();
  SLSHADOW_THROW_IF(map.k1.empty() || map.d1.empty(), file, ": the node map needs K1 and D1");
  SLSHADOW_THROW_IF(map.k2.empty() != map.d2.empty(), file,
                    ": the node map needs both K2 and D2, or neither");
  SLSHADOW_THROW_IF(!map.k2.empty() && (map.r.empty() || map.t.empty()), file,
                    ": the node map names a second camera (K2) but not its pose (R and T)");
  SLSHADOW_THROW_IF(map.kp.empty() != map.dp.empty(), file,
                    ": the node map needs both KP and DP (the projector), or neither");
  SLSHADOW_THROW_IF(!map.kp.empty() && (map.rp.empty() || map.tp.empty()), file,
                    ": the node map names a projector (KP) but not its pose (RP and TP)");
  for (const std::string* key : {&map.k1, &map.d1, &map.k2, &map.d2, &map.r, &map.t, &map.size1,
                                 &map.size2, &map.kp, &map.dp, &map.rp, &map.tp, &map.size_p}) {
    SLSHADOW_THROW_IF(!key->empty() && fs[*key].empty(), file, ": ", *key,
                      ": missing (nodes found: ", DescribeNodes(fs), ")");
  }
  const auto size1 = ReadSize(fs, map.size1, path);
  const auto size2 = ReadSize(fs, map.size2, path);
  const auto size_p = ReadSize(fs, map.size_p, path);
  Rig rig;
  rig.name = path.stem().string();
  const auto device = [&](const std::string& name, const std::string& k, const std::string& d,
                          const std::optional<std::pair<int, int>>& size, bool is_projector) {
    const int w = size ? size->first : is_projector ? projector_width : default_width;
    const int h = size ? size->second : is_projector ? projector_height : default_height;
    SLSHADOW_THROW_IF(w <= 0 || h <= 0, file, ": ", k,
                      is_projector ? ": no projector size in the file; give it (--projector-size)"
                                   : ": no image size in the file; give it (e.g. --image-size)");
    RigDevice dev;
    dev.name = name;
    dev.model =
        ModelFromMats(ReadMat(fs, k, path, 3, 3), ReadDist(fs, d, path), w, h, file + ": " + k);
    return dev;
  };
  rig.cameras.push_back(
      device(map.k2.empty() ? "camera" : "camera1", map.k1, map.d1, size1, false));
  if (!map.k2.empty()) {
    RigDevice second = device("camera2", map.k2, map.d2, size2 ? size2 : size1, false);
    second.cam_from_rig =
        PoseFromRT(RotationMatrixOrRvec(fs, map.r, path), ReadMat(fs, map.t, path, 3, 1));
    rig.cameras.push_back(second);
  }
  if (!map.kp.empty()) {
    RigDevice projector = device("projector", map.kp, map.dp, size_p, true);
    projector.cam_from_rig =
        PoseFromRT(RotationMatrixOrRvec(fs, map.rp, path), ReadMat(fs, map.tp, path, 3, 1));
    rig.projector = projector;
  }
  return rig;
}

int IntOr(Nodes& fs, const std::string& key, int fallback, const std::filesystem::path& path) {
  if (fs[key].empty()) return fallback;
  return CheckedInt(static_cast<double>(fs.Read(key)), path, key);
}

// The depth along the first camera's axis of the point where the rays through the image centres
// of the first camera and of the other device (the projector, else the second camera) come
// closest (the midpoint of the shortest segment between them); nullopt when the rig has one
// device, the rays are parallel within 0.01 degree, or they come closest behind either device.
std::optional<double> CentralRaysDepthMm(const Rig& rig) {
  if (rig.cameras.empty()) return std::nullopt;
  const RigDevice& a = rig.cameras[0];
  const RigDevice* b = rig.projector            ? &*rig.projector
                       : rig.cameras.size() > 1 ? &rig.cameras[1]
                                                : nullptr;
  if (b == nullptr) return std::nullopt;
  const auto central_ray = [](const RigDevice& d) -> std::optional<Eigen::Vector3d> {
    const auto ray =
        d.model.Unproject(Eigen::Vector2d(0.5 * (d.model.width - 1), 0.5 * (d.model.height - 1)));
    if (!ray) return std::nullopt;
    return (d.cam_from_rig.rotation.conjugate() * *ray).normalized();
  };
  const auto da = central_ray(a), db = central_ray(*b);
  if (!da || !db) return std::nullopt;
  const Eigen::Vector3d ca = a.CenterInRig(), cb = b->CenterInRig(), w = ca - cb;
  const double k = da->dot(*db), d = da->dot(w), e = db->dot(w);
  const double denom = 1 - k * k;
  if (denom < std::pow(std::sin(0.01 * std::numbers::pi / 180), 2)) return std::nullopt;
  const double s = (k * e - d) / denom, t = (e - k * d) / denom;
  if (!(s > 0) || !(t > 0)) return std::nullopt;
  const Eigen::Vector3d midpoint = 0.5 * ((ca + s * *da) + (cb + t * *db));
  const double depth = (a.cam_from_rig * midpoint).z();
  if (!(depth > 0) || !std::isfinite(depth)) return std::nullopt;
  return depth;
}

}  // namespace

void WriteOpenCvCalibration(const Rig& rig, const std::filesystem::path& path) {
  std::vector<const RigDevice*> devices;
  for (const auto& c : rig.cameras) devices.push_back(&c);
  if (rig.projector) devices.push_back(&*rig.projector);
  SLSHADOW_THROW_IF(devices.empty(), path.string(), ": rig has no devices to write");
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    // FileStorage picks the format from the extension: keep it on the temporary name.
    const std::filesystem::path tmp_ext = tmp.string() + path.extension().string();
    {
      cv::FileStorage fs(tmp_ext.string(), cv::FileStorage::WRITE);
      SLSHADOW_THROW_IF(!fs.isOpened(), path.string(), ": cannot open for writing");
      if (devices.size() == 1) {
        fs << "image_width" << devices[0]->model.width << "image_height"
           << devices[0]->model.height;
        fs << "camera_matrix" << KMat(devices[0]->model) << "distortion_coefficients"
           << DMat(devices[0]->model);
        fs << "device_name" << devices[0]->name;
      } else {
        const Rigid3d rig_from_1 = devices[0]->cam_from_rig.Inverse();
        for (size_t i = 0; i < devices.size(); ++i) {
          const std::string s = std::to_string(i + 1);
          fs << "M" + s << KMat(devices[i]->model) << "D" + s << DMat(devices[i]->model);
          fs << "image_width_" + s << devices[i]->model.width << "image_height_" + s
             << devices[i]->model.height;
          fs << "device_name_" + s << devices[i]->name;
          if (i == 0) continue;
          const Rigid3d i_from_1 = devices[i]->cam_from_rig * rig_from_1;
          const Eigen::Matrix3d r = i_from_1.rotation.toRotationMatrix();
          cv::Mat rm(3, 3, CV_64F), tm(3, 1, CV_64F);
          for (int a = 0; a < 3; ++a) {
            for (int b = 0; b < 3; ++b) rm.at<double>(a, b) = r(a, b);
            tm.at<double>(a) = i_from_1.translation(a);
          }
          const std::string suffix = i == 1 ? "" : s;
          fs << "R" + suffix << rm << "T" + suffix << tm;
        }
        fs << "num_devices" << static_cast<int>(devices.size()) << "has_projector"
           << static_cast<int>(rig.projector.has_value());
      }
      fs.release();
    }
    std::filesystem::rename(tmp_ext, tmp);
  });
}

void OpenCvImportOptions::Check() const {
  SLSHADOW_THROW_IF((image_width > 0) != (image_height > 0) || image_width < 0 || image_height < 0,
                    "OpenCV import: image size: both positive or both 0 (got ", image_width, "x",
                    image_height, ")");
  SLSHADOW_THROW_IF((projector_width > 0) != (projector_height > 0) || projector_width < 0 ||
                        projector_height < 0,
                    "OpenCV import: projector size: both positive or both 0 (got ", projector_width,
                    "x", projector_height, ")");
  SLSHADOW_THROW_IF(!std::isfinite(working_distance_mm) || working_distance_mm < 0,
                    "OpenCV import: working distance: must be > 0 mm, or 0 to derive it (got ",
                    working_distance_mm, ")");
}

OpenCvNodeMap ParseOpenCvNodeMap(const std::string& text) {
  constexpr const char* kKeys = "K1 D1 K2 D2 R T size1 size2 KP DP RP TP sizeP";
  OpenCvNodeMap map;
  size_t start = 0;
  while (start <= text.size()) {
    const size_t end = std::min(text.find(',', start), text.size());
    const std::string entry = text.substr(start, end - start);
    start = end + 1;
    if (entry.empty()) continue;
    const size_t eq = entry.find('=');
    SLSHADOW_THROW_IF(eq == std::string::npos || eq == 0 || eq + 1 == entry.size(),
                      "node map: entry '", entry, "' is not KEY=NODE (keys: ", kKeys, ")");
    const std::string key = entry.substr(0, eq), node = entry.substr(eq + 1);
    std::string* slot = key == "K1"      ? &map.k1
                        : key == "D1"    ? &map.d1
                        : key == "K2"    ? &map.k2
                        : key == "D2"    ? &map.d2
                        : key == "R"     ? &map.r
                        : key == "T"     ? &map.t
                        : key == "size1" ? &map.size1
                        : key == "size2" ? &map.size2
                        : key == "KP"    ? &map.kp
                        : key == "DP"    ? &map.dp
                        : key == "RP"    ? &map.rp
                        : key == "TP"    ? &map.tp
                        : key == "sizeP" ? &map.size_p
                                         : nullptr;
    SLSHADOW_THROW_IF(slot == nullptr, "node map: unknown key '", key, "' in '", entry,
                      "' (keys: ", kKeys, ")");
    *slot = node;
  }
  SLSHADOW_THROW_IF(map.k1.empty() || map.d1.empty(), "node map: '", text,
                    "' must name at least K1 and D1");
  return map;
}

namespace {

// The YAML tree (read by yaml-cpp) as JSON for OpenCV's JSON reader, read as OpenCV would have read
// the YAML: keys in file order, a mapping with rows, cols, dt and data is an opencv-matrix (the
// tag yaml-cpp drops). Values JSON cannot hold (empty, not finite) are refused, naming the node.
nlohmann::ordered_json YamlToOpenCvJson(const YAML::Node& node, const std::string& file,
                                        const std::string& where) {
  const std::string name = where.empty() ? std::string("(top level)") : where;
  switch (node.Type()) {
    case YAML::NodeType::Sequence: {
      nlohmann::ordered_json out = nlohmann::ordered_json::array();
      for (size_t i = 0; i < node.size(); ++i) {
        out.push_back(YamlToOpenCvJson(node[i], file, where + "[" + std::to_string(i) + "]"));
      }
      return out;
    }
    case YAML::NodeType::Map: {
      nlohmann::ordered_json out = nlohmann::ordered_json::object();
      for (const auto& kv : node) {
        SLSHADOW_THROW_IF(!kv.first.IsScalar(), file, ": ", name, ": a key that is not a name");
        const std::string key = kv.first.Scalar();
        out[key] = YamlToOpenCvJson(kv.second, file, where.empty() ? key : where + "." + key);
      }
      if (out.contains("rows") && out.contains("cols") && out.contains("dt") &&
          out.contains("data")) {
        out["type_id"] = "opencv-matrix";
      }
      return out;
    }
    case YAML::NodeType::Scalar: {
      const std::string& s = node.Scalar();
      if (node.Tag() == "!") return s;  // quoted
      char* end = nullptr;
      errno = 0;
      const long long i = std::strtoll(s.c_str(), &end, 10);
      if (!s.empty() && *end == '\0' && errno == 0 && i >= INT32_MIN && i <= INT32_MAX) return i;
      const double d = std::strtod(s.c_str(), &end);
      if (!s.empty() && end != s.c_str() && *end == '\0') {
        SLSHADOW_THROW_IF(!std::isfinite(d), file, ": ", name, ": not a finite number (", s, ")");
        return d;
      }
      SLSHADOW_THROW_IF(
          s == ".nan" || s == ".NaN" || s == ".inf" || s == "-.inf" || s == ".Inf" || s == "-.Inf",
          file, ": ", name, ": not a finite number (", s, ")");
      return s;
    }
    case YAML::NodeType::Null:
    case YAML::NodeType::Undefined:
      break;
  }
  SLSHADOW_THROW(file, ": ", name, ": empty value");
}

// The rig of one of the known layouts (or of `node_map`), read from `fs`.
Rig ReadLayout(Nodes& fs, const std::filesystem::path& path, int default_width, int default_height,
               int projector_width, int projector_height, const OpenCvNodeMap& node_map);

// Opens `path` as ReadOpenCvCalibration describes and reads its rig; `unused` gets the top-level
// nodes the rig was not read from.
Rig ReadOpenCvCalibrationNodes(const std::filesystem::path& path, int default_width,
                               int default_height, int projector_width, int projector_height,
                               const OpenCvNodeMap& node_map, std::vector<std::string>* unused) {
  SLSHADOW_THROW_IF(!std::filesystem::exists(path), path.string(), ": file not found");
  cv::FileStorage storage;
  cv::FileStorage& fs = storage;
  bool read_as_yaml = false;
  {
    // OpenCV 4.6's readers can loop forever on a bare carriage return and crash on a NUL byte
    // (found by fuzzing: fuzz/regressions/opencv_calibration/), so files that are not plain text
    // in that sense are refused before OpenCV sees them.
    const std::string text = ReadTextFile(path);
    for (size_t i = 0; i < text.size(); ++i) {
      SLSHADOW_THROW_IF(text[i] == '\0', path.string(), ": NUL byte at byte ", i,
                        " (not a text file)");
      SLSHADOW_THROW_IF(text[i] == '\r' && (i + 1 == text.size() || text[i + 1] != '\n'),
                        path.string(), ": bare carriage return at byte ", i,
                        " (old Mac line endings); convert the file to LF or CR LF line endings");
    }
    read_as_yaml = text.rfind("%YAML", 0) == 0;
    if (read_as_yaml) {
      // OpenCV 4.6's YAML reader loops forever on several kinds of malformed YAML (found by
      // fuzzing: fuzz/regressions/opencv_calibration/yaml-hang-*), and each fix of one shape
      // left another. So OpenCV never reads YAML text: yaml-cpp parses it (after OpenCV's
      // "%YAML:1.0" line, which is not a standard directive) and OpenCV reads the same tree as
      // JSON written here, which is well formed by construction.
      const size_t eol = text.find('\n');
      const std::string body = eol == std::string::npos ? std::string() : text.substr(eol + 1);
      ConfigNode::ParseYaml(body, path.string());  // the checks and messages of every YAML input
      const YAML::Node root = YAML::Load(body);
      SLSHADOW_THROW_IF(!root.IsMap(), path.string(),
                        ": the top level is not a mapping of named nodes");
      const nlohmann::ordered_json tree = YamlToOpenCvJson(root, path.string(), "");
      try {
        fs.open(tree.dump(),
                cv::FileStorage::READ | cv::FileStorage::MEMORY | cv::FileStorage::FORMAT_JSON);
      } catch (const cv::Exception& e) {
        SLSHADOW_THROW(path.string(), ": cannot read as an OpenCV FileStorage file (", e.what(),
                       ")");
      }
    }
  }
  if (!read_as_yaml) {
    try {
      fs.open(path.string(), cv::FileStorage::READ);
    } catch (const cv::Exception& e) {
      SLSHADOW_THROW(path.string(), ": cannot parse as an OpenCV FileStorage file (", e.what(),
                     ")");
    }
  }
  SLSHADOW_THROW_IF(!fs.isOpened(), path.string(), ": cannot open as an OpenCV FileStorage file");
  Nodes nodes(storage);
  Rig rig = ReadLayout(nodes, path, default_width, default_height, projector_width,
                       projector_height, node_map);
  if (const auto depth = CentralRaysDepthMm(rig)) rig.working_distance_mm = *depth;
  if (unused != nullptr) {
    for (const cv::FileNode& n : nodes.root()) {
      if (!nodes.WasRead(n.name())) unused->push_back(DescribeNode(n));
    }
  }
  return rig;
}

Rig ReadLayout(Nodes& fs, const std::filesystem::path& path, int default_width, int default_height,
               int projector_width, int projector_height, const OpenCvNodeMap& node_map) {
  const std::string file = path.string();
  Rig rig;
  rig.name = path.stem().string();
  if (!node_map.Empty()) {
    return ReadMappedLayout(fs, node_map, path, default_width, default_height, projector_width,
                            projector_height);
  }
  auto size_or_throw = [&](int w, int h, const std::string& what) {
    SLSHADOW_THROW_IF(w <= 0 || h <= 0, file, ": ", what,
                      ": no image size in the file; give it (e.g. --image-size)");
    return std::pair<int, int>(w, h);
  };
  if (!fs["camera_matrix"].empty()) {
    const auto [w, h] =
        size_or_throw(IntOr(fs, "image_width", default_width, path),
                      IntOr(fs, "image_height", default_height, path), "camera_matrix");
    RigDevice d;
    d.name =
        fs["device_name"].empty() ? "camera" : static_cast<std::string>(fs.Read("device_name"));
    d.model = ModelFromMats(ReadMat(fs, "camera_matrix", path, 3, 3),
                            ReadDist(fs, "distortion_coefficients", path), w, h,
                            file + ": camera_matrix");
    rig.cameras.push_back(d);
    return rig;
  }
  if (!fs["cam_int"].empty()) {  // kamino410/procam-calibration
    int cam_w = default_width, cam_h = default_height;
    if (!fs["img_shape"].empty()) {
      cv::Mat shape;
      fs.Read("img_shape") >> shape;
      shape.convertTo(shape, CV_64F);
      if (shape.total() >= 2) {
        cam_h = CheckedInt(shape.at<double>(0), path, "img_shape");
        cam_w = CheckedInt(shape.at<double>(1), path, "img_shape");
      }
    }
    const auto [w, h] = size_or_throw(cam_w, cam_h, "cam_int");
    const auto [pw, ph] =
        size_or_throw(projector_width, projector_height, "proj_int (projector size)");
    RigDevice cam, proj;
    cam.name = "camera";
    auto dist = [&](const std::string& key) { return ReadDist(fs, key, path); };
    cam.model = ModelFromMats(ReadMat(fs, "cam_int", path, 3, 3), dist("cam_dist"), w, h,
                              file + ": cam_int");
    proj.name = "projector";
    proj.model = ModelFromMats(ReadMat(fs, "proj_int", path, 3, 3), dist("proj_dist"), pw, ph,
                               file + ": proj_int");
    const std::string rkey = fs["rotation"].empty() ? "roration" : "rotation";
    proj.cam_from_rig =
        PoseFromRT(RotationMatrixOrRvec(fs, rkey, path), ReadMat(fs, "translation", path, 3, 1));
    rig.cameras.push_back(cam);
    rig.projector = proj;
    return rig;
  }
  if (!fs["cam1_intrinsics"].empty()) {
    return ReadMappedLayout(fs, StructuredLightSampleLayout(fs), path, default_width,
                            default_height, projector_width, projector_height);
  }
  if (!fs["M1"].empty() && fs["R"].empty() && (!fs["Rlr"].empty() || !fs["Rlp"].empty())) {
    return ReadMappedLayout(fs, BinocularLayout(fs, path), path, default_width, default_height,
                            projector_width, projector_height);
  }
  SLSHADOW_THROW_IF(
      fs["M1"].empty(), file,
      ": no known calibration layout among the nodes found: ", DescribeNodes(fs),
      ". Known: camera_matrix (OpenCV calibration sample), M1/D1/M2/D2/R/T (stereo_calib), "
      "M1/D1/M2/D2/Rlr/Tlr/S, M1/D1/M<k>/D<k>/Rlp/Tlp/S (camera, projector), "
      "cam1_intrinsics/cam1_distorsion/cam2_*/R/T, cam_int/proj_int (procam); "
      "name the nodes of another layout with --map "
      "K1=NODE,D1=NODE[,K2=..,D2=..,R=..,T=..,size1=..,KP=..,DP=..,RP=..,TP=..,sizeP=..]");
  const int num = IntOr(fs, "num_devices", fs["M2"].empty() ? 1 : 2, path);
  const bool has_projector = IntOr(fs, "has_projector", 0, path) != 0;
  // A camera without image_width_<i> / image_height_<i> takes the size in S, when the file has one.
  const auto s_size = ReadSize(fs, "S", path);
  for (int i = 1; i <= num; ++i) {
    const std::string s = std::to_string(i);
    const bool is_proj = has_projector && i == num;
    const int fallback_w = is_proj ? projector_width : s_size ? s_size->first : default_width;
    const int fallback_h = is_proj ? projector_height : s_size ? s_size->second : default_height;
    const auto [w, h] = size_or_throw(IntOr(fs, "image_width_" + s, fallback_w, path),
                                      IntOr(fs, "image_height_" + s, fallback_h, path), "M" + s);
    RigDevice d;
    d.name = fs["device_name_" + s].empty() ? (is_proj ? "projector" : "camera" + s)
                                            : static_cast<std::string>(fs.Read("device_name_" + s));
    d.model = ModelFromMats(ReadMat(fs, "M" + s, path, 3, 3), ReadDist(fs, "D" + s, path), w, h,
                            file + ": M" + s);
    if (i > 1) {
      const std::string suffix = i == 2 ? "" : s;
      d.cam_from_rig = PoseFromRT(RotationMatrixOrRvec(fs, "R" + suffix, path),
                                  ReadMat(fs, "T" + suffix, path, 3, 1));
    }
    if (is_proj) {
      rig.projector = d;
    } else {
      rig.cameras.push_back(d);
    }
  }
  return rig;
}

}  // namespace

Rig ReadOpenCvCalibration(const std::filesystem::path& path, int default_width, int default_height,
                          int projector_width, int projector_height,
                          const OpenCvNodeMap& node_map) {
  // cv::FileNode throws cv::Exception on content of an unexpected shape (the top level not a
  // mapping, a string read as a matrix, ...): bad input, reported as such in one line.
  try {
    return ReadOpenCvCalibrationNodes(path, default_width, default_height, projector_width,
                                      projector_height, node_map, nullptr);
  } catch (const cv::Exception& e) {
    SLSHADOW_THROW(path.string(), ": malformed OpenCV FileStorage content (", e.err, " in ", e.func,
                   ")");
  }
}

OpenCvImport ImportOpenCvCalibration(const std::filesystem::path& path,
                                     const OpenCvImportOptions& options) {
  options.Check();
  const std::string file = path.string();
  OpenCvImport out;
  try {
    out.rig = ReadOpenCvCalibrationNodes(path, options.image_width, options.image_height,
                                         options.projector_width, options.projector_height,
                                         options.node_map, &out.unused_nodes);
  } catch (const cv::Exception& e) {
    SLSHADOW_THROW(file, ": malformed OpenCV FileStorage content (", e.err, " in ", e.func, ")");
  }
  std::string unused;
  for (const std::string& n : out.unused_nodes) unused += (unused.empty() ? "" : ", ") + n;
  // A size option that the file contradicts, or a projector size with no projector, is refused:
  // it would otherwise be ignored without a word. (A device whose size differs from the option
  // took it from the file: the option is only the fallback.)
  if (options.image_width > 0) {
    for (const RigDevice& c : out.rig.cameras) {
      SLSHADOW_THROW_IF(
          c.model.width != options.image_width || c.model.height != options.image_height, file,
          ": camera '", c.name, "' is ", c.model.width, "x", c.model.height,
          " px in the file, but --image-size says ", options.image_width, "x",
          options.image_height);
    }
  }
  if (options.projector_width > 0) {
    SLSHADOW_THROW_IF(!out.rig.projector, file, ": --projector-size ", options.projector_width, "x",
                      options.projector_height,
                      " given, but no projector was imported (nodes not "
                      "read: ",
                      unused.empty() ? std::string("none") : unused,
                      "); name the projector's nodes with --map KP=..,DP=..,RP=..,TP=..");
    const CameraModel& m = out.rig.projector->model;
    SLSHADOW_THROW_IF(m.width != options.projector_width || m.height != options.projector_height,
                      file, ": the projector is ", m.width, "x", m.height,
                      " px in the file, but --projector-size says ", options.projector_width, "x",
                      options.projector_height);
  }
  if (options.working_distance_mm > 0) {
    out.rig.working_distance_mm = options.working_distance_mm;
    out.working_distance_source = "given (--working-distance-mm)";
  } else if (const auto depth = CentralRaysDepthMm(out.rig)) {
    out.working_distance_source = internal::Concat(
        "where the rays through the image centres of '", out.rig.cameras[0].name, "' and '",
        out.rig.projector ? out.rig.projector->name : out.rig.cameras[1].name, "' come closest");
  } else {
    out.working_distance_source = "the default";
    if (out.rig.projector || out.rig.cameras.size() > 1) {
      out.warnings.push_back(internal::Concat(
          "warning: working distance: the rays through the image centres of the first camera and ",
          out.rig.projector ? "the projector" : "the second camera",
          " are parallel or meet behind a device; ", out.rig.working_distance_mm,
          " mm assumed (rig show reports overlap there): give --working-distance-mm"));
    }
  }
  if (!out.unused_nodes.empty()) {
    out.warnings.push_back(internal::Concat(
        "warning: ", file, ": ", out.unused_nodes.size(), " node",
        out.unused_nodes.size() == 1 ? "" : "s", " not imported: ", unused,
        " (name a node with --map if it belongs to the rig: keys K1 D1 K2 D2 R T size1 size2 KP "
        "DP RP TP sizeP)"));
  }
  out.rig.Check(file);
  return out;
}

}  // namespace slshadow
