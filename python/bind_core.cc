// Rig, CameraModel, Device, PointCloud, Scene, ImageSet: the core types of slshadow in Python.
#include <filesystem>
#include <optional>

#include "core/camera_model.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "python/bindings.h"
#include "python/convert.h"
#include "sim/scene.h"

namespace slshadow::python {

namespace {

using Points = py::array_t<double, py::array::c_style | py::array::forcecast>;

// (N, k) or (k,) -> rows of k doubles; `single` says the input was one row.
std::vector<double> Rows(const py::handle& object, int k, const std::string& what, size_t* n,
                         bool* single) {
  const Points a = Points::ensure(object);
  SLSHADOW_THROW_IF(!a, what, ": expected an array of shape (N, ", k, ") or (", k, ",)");
  *single = a.ndim() == 1;
  SLSHADOW_THROW_IF(!((a.ndim() == 2 && a.shape(1) == k) || (a.ndim() == 1 && a.shape(0) == k)),
                    what, ": expected an array of shape (N, ", k, ") or (", k, ",) (got shape ",
                    std::string(py::str(py::tuple(a.attr("shape")))), ")");
  *n = *single ? 1 : static_cast<size_t>(a.shape(0));
  return std::vector<double>(a.data(), a.data() + *n * static_cast<size_t>(k));
}

py::array Shaped(std::vector<double>&& values, size_t n, size_t k, bool single) {
  py::array out = VectorToArray<double>(std::move(values), 0);
  if (single) return out.attr("reshape")(py::make_tuple(k));
  return out.attr("reshape")(py::make_tuple(n, k));
}

// Pixels of points in the device frame: (pixels with NaN where behind, valid).
py::tuple ProjectPoints(const CameraModel& model, const py::handle& points, const Rigid3d* from) {
  size_t n = 0;
  bool single = false;
  const std::vector<double> p = Rows(points, 3, "points", &n, &single);
  std::vector<double> px(2 * n, std::numeric_limits<double>::quiet_NaN());
  std::vector<uint8_t> valid(n, 0);
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector3d x(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
    if (from) x = *from * x;
    if (const auto pixel = model.Project(x)) {
      px[2 * i] = pixel->x();
      px[2 * i + 1] = pixel->y();
      valid[i] = 1;
    }
  }
  py::object mask = VectorToArray<uint8_t>(std::move(valid), 0).attr("astype")("bool");
  if (single) mask = mask[py::int_(0)];
  return py::make_tuple(Shaped(std::move(px), n, 2, single), mask);
}

// Unit rays of pixels (rotated by `to` when given): (rays with NaN where none, valid).
py::tuple UnprojectPixels(const CameraModel& model, const py::handle& pixels,
                          const Eigen::Quaterniond* to) {
  size_t n = 0;
  bool single = false;
  const std::vector<double> q = Rows(pixels, 2, "pixels", &n, &single);
  std::vector<double> rays(3 * n, std::numeric_limits<double>::quiet_NaN());
  std::vector<uint8_t> valid(n, 0);
  for (size_t i = 0; i < n; ++i) {
    if (auto ray = model.Unproject(Eigen::Vector2d(q[2 * i], q[2 * i + 1]))) {
      if (to) *ray = *to * *ray;
      for (int c = 0; c < 3; ++c) rays[3 * i + static_cast<size_t>(c)] = (*ray)[c];
      valid[i] = 1;
    }
  }
  py::object mask = VectorToArray<uint8_t>(std::move(valid), 0).attr("astype")("bool");
  if (single) mask = mask[py::int_(0)];
  return py::make_tuple(Shaped(std::move(rays), n, 3, single), mask);
}

py::array Vector3(const Eigen::Vector3d& v) {
  py::array_t<double> out(3);
  auto w = out.mutable_unchecked<1>();
  for (int i = 0; i < 3; ++i) w(i) = v[i];
  return out;
}

// A PointCloud from arrays (copied).
std::shared_ptr<PointCloud> CloudFromArrays(const py::handle& points, const py::handle& normals,
                                            const py::handle& colors, const py::handle& scalars) {
  auto cloud = std::make_shared<PointCloud>();
  size_t n = 0;
  bool single = false;
  const std::vector<double> p = Rows(points, 3, "points", &n, &single);
  cloud->points.resize(n);
  for (size_t i = 0; i < n; ++i) cloud->points[i] = {p[3 * i], p[3 * i + 1], p[3 * i + 2]};
  if (!normals.is_none()) {
    size_t m = 0;
    const std::vector<double> v = Rows(normals, 3, "normals", &m, &single);
    SLSHADOW_THROW_IF(m != n, "normals: ", m, " rows for ", n, " points");
    cloud->normals.resize(n);
    for (size_t i = 0; i < n; ++i)
      cloud->normals[i] = Eigen::Vector3d(v[3 * i], v[3 * i + 1], v[3 * i + 2]).cast<float>();
  }
  if (!colors.is_none()) {
    const auto c = py::array_t<uint8_t, py::array::c_style | py::array::forcecast>::ensure(colors);
    SLSHADOW_THROW_IF(
        !c || c.ndim() != 2 || c.shape(1) != 3 || static_cast<size_t>(c.shape(0)) != n,
        "colors: expected a uint8 array of shape (", n, ", 3)");
    cloud->colors.resize(n);
    for (size_t i = 0; i < n; ++i)
      for (size_t k = 0; k < 3; ++k) cloud->colors[i][k] = c.data()[3 * i + k];
  }
  if (!scalars.is_none()) {
    for (const auto& [key, value] : py::cast<py::dict>(scalars)) {
      const auto v = py::array_t<float, py::array::c_style | py::array::forcecast>::ensure(value);
      const std::string name = py::str(key);
      SLSHADOW_THROW_IF(!v || v.ndim() != 1 || static_cast<size_t>(v.shape(0)) != n, "scalars['",
                        name, "']: expected ", n, " values");
      cloud->SetScalar(name, std::vector<float>(v.data(), v.data() + n));
    }
  }
  cloud->Check("PointCloud");
  return cloud;
}

}  // namespace

PatternSpec PatternSpecFromObject(const py::handle& object, const std::string& what) {
  if (py::isinstance<PatternSpec>(object)) return object.cast<PatternSpec>();
  if (py::isinstance<py::dict>(object))
    return PatternSpecFromConfig(ConfigNode::FromJson(ToJson(object, what), what));
  if (py::isinstance<py::str>(object) || py::hasattr(object, "__fspath__")) {
    const std::string path = py::str(py::module_::import("os").attr("fspath")(object));
    return LoadPatternSpec(path);
  }
  SLSHADOW_THROW(what, ": expected a PatternSpec, a dict or a path (got ",
                 std::string(py::str(py::type::of(object))), ")");
}

void BindCore(py::module_& m) {
  py::class_<CameraModel>(m, "CameraModel",
                          "A camera or projector model: pinhole + Brown-Conrady distortion "
                          "(OpenCV's k1, k2, p1, p2, k3). Pixel (0, 0) is the centre of the "
                          "top-left pixel; camera frame x right, y down, z forward; mm.")
      .def(py::init<int, int, double, double, double, double, double, double, double, double,
                    double>(),
           py::arg("width"), py::arg("height"), py::arg("fx"), py::arg("fy"), py::arg("cx"),
           py::arg("cy"), py::arg("k1") = 0.0, py::arg("k2") = 0.0, py::arg("p1") = 0.0,
           py::arg("p2") = 0.0, py::arg("k3") = 0.0)
      .def_readonly("width", &CameraModel::width)
      .def_readonly("height", &CameraModel::height)
      .def_property_readonly(
          "params",
          [](const CameraModel& c) {
            return py::array_t<double>(CameraModel::kNumParams, c.params.data());
          },
          "fx, fy, cx, cy, k1, k2, p1, p2, k3 (a copy)")
      .def_property_readonly("K",
                             [](const CameraModel& c) {
                               py::array_t<double> k({3, 3});
                               auto v = k.mutable_unchecked<2>();
                               for (int r = 0; r < 3; ++r)
                                 for (int col = 0; col < 3; ++col) v(r, col) = 0;
                               v(0, 0) = c.fx();
                               v(1, 1) = c.fy();
                               v(0, 2) = c.cx();
                               v(1, 2) = c.cy();
                               v(2, 2) = 1;
                               return k;
                             })
      .def_property_readonly("dist_coeffs",
                             [](const CameraModel& c) {
                               return py::array_t<double>(5, c.params.data() + CameraModel::kK1);
                             })
      .def(
          "project",
          [](const CameraModel& c, const py::handle& points) {
            return ProjectPoints(c, points, nullptr);
          },
          py::arg("points_in_cam"),
          "Camera-frame points (N, 3) or (3,), mm -> (pixels (N, 2), valid (N,)); NaN pixels "
          "where a point is not in front of the camera.")
      .def(
          "unproject",
          [](const CameraModel& c, const py::handle& pixels) {
            return UnprojectPixels(c, pixels, nullptr);
          },
          py::arg("pixels"),
          "Pixels (N, 2) or (2,) -> (unit viewing rays in the camera frame (N, 3), valid (N,)); "
          "NaN where undistortion does not converge.")
      .def("__repr__", [](const CameraModel& c) {
        return "<slshadow.CameraModel " + std::to_string(c.width) + "x" + std::to_string(c.height) +
               " fx=" + std::to_string(c.fx()) + ">";
      });

  py::class_<RigDevice>(m, "Device", "A camera or the projector of a rig, with its pose.")
      .def_readonly("name", &RigDevice::name)
      .def_readonly("model", &RigDevice::model)
      .def_property_readonly(
          "cam_from_rig", [](const RigDevice& d) { return Matrix4(d.cam_from_rig); },
          "4x4 matrix mapping rig-frame points (mm) into this device's frame")
      .def_property_readonly("center_in_rig",
                             [](const RigDevice& d) { return Vector3(d.CenterInRig()); })
      .def_property_readonly("axis_in_rig",
                             [](const RigDevice& d) { return Vector3(d.AxisInRig()); })
      .def(
          "project",
          [](const RigDevice& d, const py::handle& points) {
            return ProjectPoints(d.model, points, &d.cam_from_rig);
          },
          py::arg("points_in_rig"),
          "Rig-frame points (N, 3), mm -> (pixels (N, 2), valid (N,)) of this device.")
      .def(
          "unproject",
          [](const RigDevice& d, const py::handle& pixels) {
            const Eigen::Quaterniond rig_from_cam = d.cam_from_rig.rotation.conjugate();
            return UnprojectPixels(d.model, pixels, &rig_from_cam);
          },
          py::arg("pixels"),
          "Pixels (N, 2) -> (unit rays in the rig frame (N, 3), valid (N,)); the rays start at "
          "center_in_rig.")
      .def("__repr__", [](const RigDevice& d) { return "<slshadow.Device '" + d.name + "'>"; });

  py::class_<Rig>(m, "Rig",
                  "A structured-light rig: named cameras and at most one projector "
                  "(docs/formats.md \"Rig YAML\"). The rig frame is the first camera's frame.")
      .def_static(
          "load", [](const std::filesystem::path& path) { return LoadRig(path); }, py::arg("path"),
          "Reads a rig file (.yaml/.yml/.json).")
      .def_static(
          "from_dict",
          [](const py::dict& tree) {
            return RigFromConfig(ConfigNode::FromJson(ToJson(tree, "Rig.from_dict"), "Rig"));
          },
          py::arg("tree"), "A rig from the tree of a rig file (what to_dict() returns).")
      .def(
          "save", [](const Rig& rig, const std::filesystem::path& path) { SaveRig(rig, path); },
          py::arg("path"), "Writes the rig atomically: YAML, or JSON for a .json path.")
      .def("describe", &DescribeRig, "What `slshadow rig show` prints.")
      .def("to_dict", [](const Rig& rig) { return FromJson(RigToJson(rig)); })
      .def_readonly("name", &Rig::name)
      .def_readonly("working_distance_mm", &Rig::working_distance_mm)
      .def_readonly("cameras", &Rig::cameras)
      .def_property_readonly("projector",
                             [](const Rig& rig) -> py::object {
                               if (!rig.projector) return py::none();
                               return py::cast(*rig.projector);
                             })
      .def_property_readonly("camera_names",
                             [](const Rig& rig) {
                               std::vector<std::string> names;
                               for (const auto& c : rig.cameras) names.push_back(c.name);
                               return names;
                             })
      .def("camera", &Rig::Camera, py::arg("name"), py::return_value_policy::copy)
      .def("device", &Rig::Device, py::arg("name"), py::return_value_policy::copy)
      .def("__repr__", [](const Rig& rig) {
        return "<slshadow.Rig '" + rig.name + "': " + std::to_string(rig.cameras.size()) +
               " camera(s)" + (rig.projector ? ", a projector>" : ", no projector>");
      });

  py::class_<PointCloud, std::shared_ptr<PointCloud>>(
      m, "PointCloud",
      "Points (mm), optional normals, colours and named per-point scalar fields. The array "
      "properties are read-only views of the cloud's memory (no copy); the constructor copies.")
      .def(py::init(&CloudFromArrays), py::arg("points"), py::arg("normals") = py::none(),
           py::arg("colors") = py::none(), py::arg("scalars") = py::none())
      .def("__len__", [](const PointCloud& c) { return c.size(); })
      .def_property_readonly("points",
                             [](py::object self) {
                               const auto& c = self.cast<const PointCloud&>();
                               return ViewArray(reinterpret_cast<const double*>(c.points.data()),
                                                c.size(), 3, self);
                             })
      .def_property_readonly("normals",
                             [](py::object self) -> py::object {
                               const auto& c = self.cast<const PointCloud&>();
                               if (!c.HasNormals()) return py::none();
                               return ViewArray(reinterpret_cast<const float*>(c.normals.data()),
                                                c.size(), 3, self);
                             })
      .def_property_readonly("colors",
                             [](py::object self) -> py::object {
                               const auto& c = self.cast<const PointCloud&>();
                               if (!c.HasColors()) return py::none();
                               return ViewArray(reinterpret_cast<const uint8_t*>(c.colors.data()),
                                                c.size(), 3, self);
                             })
      .def_property_readonly("scalar_names",
                             [](const PointCloud& c) {
                               std::vector<std::string> names;
                               for (const auto& s : c.scalars) names.push_back(s.name);
                               return names;
                             })
      .def(
          "scalar",
          [](py::object self, const std::string& name) {
            const auto& c = self.cast<const PointCloud&>();
            const std::vector<float>* values = c.Scalar(name);
            SLSHADOW_THROW_IF(!values, "PointCloud: no scalar field '", name, "'");
            return ViewArray(values->data(), values->size(), 0, self);
          },
          py::arg("name"))
      .def(
          "write_ply",
          [](const PointCloud& c, const std::filesystem::path& path, bool binary) {
            PlyWriteOptions options;
            options.binary = binary;
            WritePly(path, c, options);
          },
          py::arg("path"), py::arg("binary") = true,
          "Writes a PLY file (x, y, z as double: bit-exact round trip).")
      .def("__repr__", [](const PointCloud& c) {
        return "<slshadow.PointCloud " + std::to_string(c.size()) + " points>";
      });
  m.def(
      "read_ply",
      [](const std::filesystem::path& path) { return std::make_shared<PointCloud>(ReadPly(path)); },
      py::arg("path"), "Reads a PLY point cloud (faces ignored).");

  py::class_<Scene, std::shared_ptr<Scene>>(
      m, "Scene", "What the simulator scans (docs/formats.md \"Scene YAML\").")
      .def_static(
          "load",
          [](const std::filesystem::path& path) {
            return std::make_shared<Scene>(LoadScene(path));
          },
          py::arg("path"))
      .def_readonly("name", &Scene::name)
      .def("to_dict", [](const Scene& s) { return FromJson(SceneToJson(s)); })
      .def("__repr__", [](const Scene& s) {
        return "<slshadow.Scene '" + s.name + "': " + std::to_string(s.objects.size()) +
               " object(s)>";
      });

  py::class_<PyImageSet>(m, "ImageSet",
                         "A capture folder, real or virtual (docs/formats.md \"ImageSet\"). "
                         "Images are read on request; each call returns new arrays.")
      .def_static(
          "open", [](const std::filesystem::path& dir) { return PyImageSet{ImageSet::Open(dir)}; },
          py::arg("dir"))
      .def_property_readonly("dir", [](const PyImageSet& s) { return s.image_set.dir().string(); })
      .def_property_readonly("rig", [](const PyImageSet& s) { return s.image_set.rig(); })
      .def_property_readonly("patterns",
                             [](const PyImageSet& s) {
                               return PatternSpecFromConfig(ConfigNode::FromJson(
                                   s.image_set.patterns(),
                                   (s.image_set.dir() / "manifest.json").string(), "patterns"));
                             })
      .def_property_readonly("extra",
                             [](const PyImageSet& s) { return FromJson(s.image_set.extra()); })
      .def_property_readonly("cameras",
                             [](const PyImageSet& s) { return s.image_set.CameraNames(); })
      .def_property_readonly("pattern_count",
                             [](const PyImageSet& s) { return s.image_set.PatternCount(); })
      .def(
          "image",
          [](const PyImageSet& s, const std::string& camera, int index) {
            cv::Mat image;
            {
              py::gil_scoped_release release;
              image = s.image_set.Load(camera, index);
            }
            return MatToArray(image);
          },
          py::arg("camera"), py::arg("index"),
          "One image (rows, cols), uint8 or uint16, sharing memory with nothing else.")
      .def(
          "images",
          [](const PyImageSet& s, const std::string& camera) {
            std::vector<cv::Mat> images;
            {
              py::gil_scoped_release release;
              images = s.image_set.LoadCamera(camera);
            }
            return StackImages(images);
          },
          py::arg("camera"), "All images of one camera, in pattern order: (N, rows, cols).")
      .def("__repr__", [](const PyImageSet& s) {
        return "<slshadow.ImageSet '" + s.image_set.dir().string() +
               "': " + std::to_string(s.image_set.records().size()) + " images>";
      });

  m.def(
      "write_image_set",
      [](const std::filesystem::path& dir, const Rig& rig, const py::handle& patterns,
         const py::dict& images, const std::string& encoding, int png_compression, bool overwrite,
         double exposure_us, const std::string& source, const py::object& extra) {
        const PatternSpec spec = PatternSpecFromObject(patterns, "patterns");
        ImageSetWriterOptions options;
        options.encoding = ImageEncodingFromString(encoding);
        options.png_compression = png_compression;
        options.overwrite = overwrite;
        const ImageSource image_source = ImageSourceFromString(source);
        std::vector<std::pair<std::string, std::vector<cv::Mat>>> all;
        std::vector<py::object> keep;
        for (const auto& [key, value] : images) {
          const std::string camera = py::str(key);
          all.emplace_back(camera, ImagesFromObject(value, "images['" + camera + "']", &keep));
          SLSHADOW_THROW_IF(static_cast<int>(all.back().second.size()) != spec.NumImages(),
                            "images['", camera, "']: ", all.back().second.size(),
                            " images but the pattern spec has ", spec.NumImages());
        }
        nlohmann::json extra_json =
            extra.is_none() ? nlohmann::json::object() : ToJson(extra, "extra");
        {
          py::gil_scoped_release release;
          ImageSetWriter writer(dir, rig, PatternSpecToJson(spec), options);
          if (!extra_json.empty()) writer.SetExtra(extra_json);
          for (const auto& [camera, frames] : all)
            for (size_t i = 0; i < frames.size(); ++i)
              writer.Add(camera, static_cast<int>(i), frames[i], exposure_us, image_source);
          writer.Commit();
        }
        return PyImageSet{ImageSet::Open(dir)};
      },
      py::arg("dir"), py::arg("rig"), py::arg("patterns"), py::arg("images"), py::kw_only(),
      py::arg("encoding") = "png", py::arg("png_compression") = 1, py::arg("overwrite") = false,
      py::arg("exposure_us") = 0.0, py::arg("source") = "device", py::arg("extra") = py::none(),
      "Writes an ImageSet from arrays: images maps camera name -> (N, rows, cols) uint8/uint16 "
      "(or a list of 2-D arrays) in pattern order. Atomic: the folder appears complete or not at "
      "all. Returns the ImageSet opened from it.");
}

}  // namespace slshadow::python
