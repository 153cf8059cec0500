// reconstruct and compare in Python: the library calls behind `slshadow reconstruct` and
// `slshadow compare`, with their options as keyword arguments read through the same config
// readers (so the names, the validation and the messages are the C++ ones).
#include <map>
#include <memory>
#include <set>

#include "compare/compare.h"
#include "compare/report.h"
#include "core/config.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "python/bindings.h"
#include "python/convert.h"
#include "reconstruct/reconstruct_image_set.h"
#include "reconstruct/write_reconstruction.h"

namespace slshadow::python {

namespace {

std::set<std::string> Keys(const nlohmann::json& object) {
  std::set<std::string> keys;
  for (const auto& [key, value] : object.items()) keys.insert(key);
  return keys;
}

std::string Join(const std::set<std::string>& names) {
  std::string out;
  for (const auto& n : names) out += (out.empty() ? "" : ", ") + n;
  return out;
}

}  // namespace

// Keyword arguments -> ImageSetReconstructOptions: the ReconstructOptions fields through
// ReconstructOptionsFromConfig, the DecodeOptions fields through DecodeOptionsFromConfig (their
// names, types and checks), mode and cameras as on the command line, then the whole Check(). A
// message is the command line's for the same value (WithoutSource). mode "auto" (the
// default): DefaultReconstructMode(rig); without a rig, mode and cameras are refused.
ImageSetReconstructOptions ReconstructOptionsFromKwargs(const py::kwargs& kwargs, const Rig* rig,
                                                        const std::string& call) {
  static const std::set<std::string> reconstruct_keys = Keys(ReconstructOptions{}.ToJson());
  static const std::set<std::string> decode_keys = Keys(DecodeOptionsToJson(DecodeOptions{}));
  nlohmann::json reconstruct_tree = nlohmann::json::object();
  nlohmann::json decode_tree = nlohmann::json::object();
  std::string mode = "auto";
  ImageSetReconstructOptions options;
  for (const auto& [key, value] : kwargs) {
    const std::string name = py::str(key);
    const std::string what = call + ": " + name;
    if (!rig && (name == "mode" || name == "cameras")) {
      SLSHADOW_THROW(call, ": unknown option '", name, "'");
    } else if (name == "mode") {
      SLSHADOW_THROW_IF(!py::isinstance<py::str>(value), what, ": expected a string (got ",
                        std::string(py::repr(value)), ")");
      mode = value.cast<std::string>();
    } else if (name == "cameras") {
      SLSHADOW_THROW_IF(py::isinstance<py::str>(value) || !py::isinstance<py::sequence>(value),
                        what, ": expected a list of camera names (got ",
                        std::string(py::repr(value)), ")");
      for (const py::handle camera : value) {
        SLSHADOW_THROW_IF(!py::isinstance<py::str>(camera), what,
                          ": expected a list of camera names (got ", std::string(py::repr(value)),
                          ")");
        options.cameras.push_back(camera.cast<std::string>());
      }
    } else if (reconstruct_keys.count(name)) {
      reconstruct_tree[name] = ToJson(value, what);
    } else if (decode_keys.count(name)) {
      decode_tree[name] = ToJson(value, what);
    } else {
      std::set<std::string> all = reconstruct_keys;
      all.insert(decode_keys.begin(), decode_keys.end());
      all.insert("mode");
      all.insert("cameras");
      if (!rig) {
        all.erase("mode");
        all.erase("cameras");
      }
      SLSHADOW_THROW(call, ": unknown option '", name, "' (expected one of ", Join(all), ")");
    }
  }
  if (!reconstruct_tree.empty())
    options.reconstruct = WithoutSource(call, [&] {
      return ReconstructOptionsFromConfig(ConfigNode::FromJson(reconstruct_tree, call));
    });
  if (!decode_tree.empty())
    options.decode = WithoutSource(
        call, [&] { return DecodeOptionsFromConfig(ConfigNode::FromJson(decode_tree, call)); });
  // The checks are the command line's code: their messages are its messages, as they are.
  if (rig)
    options.mode = mode == "auto" ? DefaultReconstructMode(*rig) : ReconstructModeFromString(mode);
  options.Check();
  return options;
}

namespace {

struct PyReconstruction {
  std::shared_ptr<ImageSetReconstruction> rec;
  ImageSetReconstructOptions options;
  Rig rig;
  std::string imageset;  // the ImageSet folder, when reconstructed from one
  std::string rig_file;  // a rig file given instead of the manifest's
  std::shared_ptr<PointCloud> Cloud() const { return {rec, &rec->cloud}; }
};

std::shared_ptr<PointCloud> CloudFromObject(const py::handle& object, std::string* source) {
  if (py::isinstance<PointCloud>(object)) return object.cast<std::shared_ptr<PointCloud>>();
  if (py::isinstance<PyReconstruction>(object)) return object.cast<PyReconstruction&>().Cloud();
  if (py::isinstance<py::str>(object) || py::hasattr(object, "__fspath__")) {
    const std::string path = py::str(py::module_::import("os").attr("fspath")(object));
    *source = path;
    return std::make_shared<PointCloud>(ReadPly(path));
  }
  if (py::isinstance<py::array>(object)) {
    return py::module_::import("slshadow")
        .attr("PointCloud")(object)
        .cast<std::shared_ptr<PointCloud>>();
  }
  SLSHADOW_THROW(
      "compare: cloud: expected a PointCloud, a Reconstruction, an (N, 3) array or a "
      "path (got ",
      std::string(py::str(py::type::of(object))), ")");
}

std::shared_ptr<compare::Reference> ReferenceFromObject(const py::handle& object,
                                                        size_t mesh_samples) {
  if (py::isinstance<compare::Reference>(object))
    return object.cast<std::shared_ptr<compare::Reference>>();
  if (py::isinstance<py::str>(object) || py::hasattr(object, "__fspath__")) {
    const std::string path = py::str(py::module_::import("os").attr("fspath")(object));
    py::gil_scoped_release release;
    return std::make_shared<compare::Reference>(compare::LoadReference(path, mesh_samples));
  }
  std::string unused;
  const std::shared_ptr<PointCloud> cloud = CloudFromObject(object, &unused);
  return std::make_shared<compare::Reference>(compare::ReferenceFromCloud(*cloud, "cloud"));
}

compare::CompareOptions CompareOptionsFromKwargs(const py::kwargs& kwargs) {
  nlohmann::json tree = nlohmann::json::object();
  for (const auto& [key, value] : kwargs) {
    const std::string name = py::str(key);
    // registration="icp" stands for registration={"method": "icp"}.
    if (name == "registration" && py::isinstance<py::str>(value)) {
      tree[name] = {{"method", value.cast<std::string>()}};
    } else {
      tree[name] = ToJson(value, "compare: " + name);
    }
  }
  // A message is the command line's for the same value.
  return WithoutSource("compare", [&] {
    return compare::CompareOptionsFromConfig(ConfigNode::FromJson(tree, "compare"));
  });
}

struct PyComparison {
  std::shared_ptr<compare::CompareResult> result;
};

}  // namespace

void BindReconstructAndCompare(py::module_& m) {
  py::class_<PyReconstruction>(
      m, "Reconstruction",
      "The result of reconstruct(): the merged cloud (rig frame, mm) and one summary per "
      "reconstruction. The arrays are read-only views of the cloud (no copy) unless noted.")
      .def_property_readonly("cloud", &PyReconstruction::Cloud)
      .def_property_readonly(
          "points", [](py::object self) -> py::object { return self.attr("cloud").attr("points"); })
      .def_property_readonly(
          "normals",
          [](py::object self) -> py::object { return self.attr("cloud").attr("normals"); })
      .def_property_readonly(
          "colors", [](py::object self) -> py::object { return self.attr("cloud").attr("colors"); },
          "None: reconstructions carry no colours (the cloud's quality is the decode contrast)")
      .def_property_readonly("quality",
                             [](py::object self) -> py::object {
                               return self.attr("cloud").attr("scalar")("quality");
                             })
      .def_property_readonly(
          "camera",
          [](py::object self) -> py::object { return self.attr("cloud").attr("scalar")("camera"); },
          "the rig index of the camera each point came from (float32)")
      .def_property_readonly(
          "source_pixel",
          [](const PyReconstruction& r) {
            const std::vector<float>* u = r.rec->cloud.Scalar("u");
            const std::vector<float>* v = r.rec->cloud.Scalar("v");
            std::vector<float> uv(2 * r.rec->cloud.size());
            for (size_t i = 0; u && v && i < u->size(); ++i) {
              uv[2 * i] = (*u)[i];
              uv[2 * i + 1] = (*v)[i];
            }
            return VectorToArray<float>(std::move(uv), 0)
                .attr("reshape")(py::make_tuple(r.rec->cloud.size(), 2));
          },
          "(N, 2) float32: the pixel (u, v) of the reference camera each point was seen at (a new "
          "array)")
      .def_property_readonly("cameras", [](const PyReconstruction& r) { return r.rec->cameras; })
      .def_property_readonly("summaries",
                             [](const PyReconstruction& r) {
                               py::list out;
                               for (const auto& s : r.rec->summaries)
                                 out.append(FromJson(s.ToJson()));
                               return out;
                             })
      .def_property_readonly("warnings",
                             [](const PyReconstruction& r) { return r.rec->Warnings(); })
      .def_property_readonly("notices", [](const PyReconstruction& r) { return r.rec->Notices(); })
      .def_property_readonly("residual_maps",
                             [](const PyReconstruction& r) {
                               py::dict out;
                               for (const auto& [name, map] : r.rec->residual_maps)
                                 out[py::str(name)] = MatToArray(map);
                               return out;
                             })
      .def_property_readonly("report",
                             [](const PyReconstruction& r) { return r.rec->FullReport(); })
      .def("to_dict", [](const PyReconstruction& r) { return FromJson(r.rec->ToJson()); })
      .def(
          "write",
          [](const PyReconstruction& r, const std::filesystem::path& path,
             const std::optional<std::filesystem::path>& summary, bool binary) {
            ReconstructionOutputOptions output;
            output.cloud_path = path;
            if (summary) output.summary_path = *summary;
            output.binary_ply = binary;
            output.imageset = r.imageset;
            output.rig_file = r.rig_file;
            py::gil_scoped_release release;
            const ReconstructionOutputs written =
                WriteReconstruction(*r.rec, r.options, r.rig, output);
            return written.summary.string();
          },
          py::arg("path"), py::arg("summary") = py::none(), py::arg("binary") = true,
          "Writes the cloud PLY, its summary JSON and the residual maps as `slshadow "
          "reconstruct` does; returns the summary's path.")
      .def("__len__", [](const PyReconstruction& r) { return r.rec->cloud.size(); })
      .def("__repr__", [](const PyReconstruction& r) {
        return "<slshadow.Reconstruction " + std::to_string(r.rec->cloud.size()) + " points>";
      });

  m.def(
      "reconstruct",
      [](const py::handle& source, const py::object& patterns, const std::optional<Rig>& rig_arg,
         const py::object& progress, const py::kwargs& kwargs) {
        PyReconstruction out;
        const ProgressCallback report(progress);
        if (py::isinstance<PyImageSet>(source)) {
          const ImageSet& image_set = source.cast<const PyImageSet&>().image_set;
          SLSHADOW_THROW_IF(!patterns.is_none(),
                            "reconstruct: patterns: not with an ImageSet (its manifest has them)");
          out.rig = rig_arg ? *rig_arg : image_set.rig();
          if (rig_arg) out.rig_file = "(Python)";
          out.imageset = image_set.dir().string();
          out.options = ReconstructOptionsFromKwargs(kwargs, &out.rig, "reconstruct");
          py::gil_scoped_release release;
          const ForwardLibraryProgress forward(report);
          out.rec = std::make_shared<ImageSetReconstruction>(
              ReconstructImageSet(image_set, out.options, out.rig));
          return out;
        }
        std::map<std::string, std::vector<cv::Mat>> images;
        std::vector<py::object> keep;
        PatternSpec spec;
        py::object scan_type = py::module_::import("slshadow").attr("Scan");
        if (py::isinstance(source, scan_type)) {
          const py::object scan = py::reinterpret_borrow<py::object>(source);
          out.rig = rig_arg ? *rig_arg : scan.attr("rig").cast<Rig>();
          spec = scan.attr("patterns").cast<PatternSpec>();
          for (const std::string& camera : scan.attr("cameras").cast<std::vector<std::string>>()) {
            const int n = spec.NumImages();
            std::vector<cv::Mat> frames;
            for (int i = 0; i < n; ++i) {
              py::object held;
              frames.push_back(ImageFromArray(scan.attr("image")(camera, i), camera, &held));
              keep.push_back(std::move(held));
            }
            images[camera] = std::move(frames);
          }
        } else if (py::isinstance<py::dict>(source)) {
          SLSHADOW_THROW_IF(!rig_arg || patterns.is_none(),
                            "reconstruct: images as a dict need rig= and patterns=");
          out.rig = *rig_arg;
          spec = PatternSpecFromObject(patterns, "patterns");
          for (const auto& [key, value] : py::reinterpret_borrow<py::dict>(source)) {
            const std::string camera = py::str(key);
            images[camera] = ImagesFromObject(value, "images['" + camera + "']", &keep);
          }
        } else {
          SLSHADOW_THROW(
              "reconstruct: expected an ImageSet, a Scan or a dict camera -> images (got ",
              std::string(py::str(py::type::of(source))), ")");
        }
        out.options = ReconstructOptionsFromKwargs(kwargs, &out.rig, "reconstruct");
        py::gil_scoped_release release;
        const ForwardLibraryProgress forward(report);
        out.rec = std::make_shared<ImageSetReconstruction>(
            ReconstructFromImages(out.rig, spec, images, out.options));
        return out;
      },
      py::arg("source"), py::arg("patterns") = py::none(), py::kw_only(),
      py::arg("rig") = py::none(), py::arg("progress") = py::none(),
      "Reconstructs a point cloud (`slshadow reconstruct`): from an ImageSet (its manifest's rig "
      "and patterns, or rig=), a Scan, or a dict camera -> (N, rows, cols) images with rig= and "
      "patterns. Keyword options: mode (auto | projector | stereo), cameras, the fields of "
      "ReconstructOptions (method: midpoint | dlt | optimal, min_depth_mm, max_depth_mm, "
      "min_triangulation_angle_deg, max_reprojection_error_px, max_epipolar_error_px (inf: off), "
      "min_quality, max_code_step_px, max_code_step_ratio, stereo_interpolation, "
      "filter_depth_discontinuities, "
      "max_depth_jump_footprints, discontinuity_dilation_px, filter_outliers, outlier_std_ratio, "
      "estimate_normals, calibration_warning_px, ...) and of DecodeOptions (shadow_threshold, "
      "contrast_threshold, ...). The GIL is released while it runs; progress(stage, done, total) "
      "is called per camera decoded and per camera (stereo: pair) triangulated, as stage "
      "'reconstruct' with done counting up to total.");

  py::class_<compare::Reference, std::shared_ptr<compare::Reference>>(
      m, "Reference",
      "What a cloud is compared with: a mesh (C2M) or a cloud (C2C). Load once to compare many "
      "clouds against it (the mesh's distance hierarchy is built once).")
      .def_static(
          "load",
          [](const std::filesystem::path& path, size_t mesh_samples) {
            py::gil_scoped_release release;
            return std::make_shared<compare::Reference>(compare::LoadReference(path, mesh_samples));
          },
          py::arg("path"), py::arg("mesh_samples") = 200000,
          ".stl / .obj: a mesh; .ply: a mesh when it has faces, else a cloud.")
      .def_static(
          "from_cloud",
          [](const PointCloud& cloud, const std::string& source) {
            return std::make_shared<compare::Reference>(compare::ReferenceFromCloud(cloud, source));
          },
          py::arg("cloud"), py::arg("source") = "cloud")
      .def_readonly("source", &compare::Reference::source)
      .def_property_readonly("is_mesh", &compare::Reference::IsMesh);

  py::class_<PyComparison>(m, "Comparison",
                           "The result of compare(): figures, per-point deviations, the "
                           "registered cloud.")
      .def_property_readonly(
          "figures", [](const PyComparison& c) { return FromJson(compare::ReportJson(*c.result)); },
          "The report (what `slshadow compare` writes to report.json) as a dict.")
      .def_property_readonly(
          "deviations",
          [](py::object self) {
            const auto& r = *self.cast<const PyComparison&>().result;
            return ViewArray(r.deviations_mm.data(), r.deviations_mm.size(), 0, self);
          },
          "(N,) float64, mm: signed distance to the mesh (+ outside), or the C2C distance; a "
          "read-only view (no copy)")
      .def_property_readonly(
          "compared",
          [](const PyComparison& c) {
            return std::shared_ptr<PointCloud>(c.result, &c.result->compared);
          },
          "The cloud in the reference frame with the 'deviation' field and "
          "colours")
      .def_property_readonly("reference_from_cloud",
                             [](const PyComparison& c) {
                               return Matrix4(c.result->registration.reference_from_cloud);
                             })
      .def_property_readonly("coverage", [](const PyComparison& c) { return c.result->coverage; })
      .def_property_readonly("summary", [](const PyComparison& c) { return c.result->Summary(); })
      .def("__repr__", [](const PyComparison& c) {
        return "<slshadow.Comparison " + std::to_string(c.result->deviations_mm.size()) +
               " points, rms " + std::to_string(c.result->c2c.rms_mm) + " mm>";
      });

  m.def(
      "compare",
      [](const py::handle& cloud_arg, const py::handle& reference_arg,
         const std::optional<std::filesystem::path>& out, size_t mesh_samples,
         const std::optional<std::string>& cloud_source, const std::optional<Rig>& view_rig,
         const std::optional<std::string>& view_camera, bool overwrite, const py::object& progress,
         const py::kwargs& kwargs) {
        std::string source = "cloud";
        const std::shared_ptr<PointCloud> cloud = CloudFromObject(cloud_arg, &source);
        if (cloud_source) source = *cloud_source;
        const compare::CompareOptions options = CompareOptionsFromKwargs(kwargs);
        const std::shared_ptr<compare::Reference> reference =
            ReferenceFromObject(reference_arg, mesh_samples);
        compare::ReportOptions report;
        report.overwrite = overwrite;
        if (view_rig) {
          const RigDevice& cam =
              view_camera ? view_rig->Camera(*view_camera) : view_rig->cameras.front();
          report.view = compare::ViewCamera{cam.model, cam.cam_from_rig};
        }
        const ProgressCallback callback(progress);
        PyComparison out_result;
        py::gil_scoped_release release;
        const ForwardLibraryProgress forward(callback);
        callback("compare", 0, 1);
        out_result.result = std::make_shared<compare::CompareResult>(
            out ? compare::CompareAndReport(*cloud, *reference, options, *out, report, source)
                : compare::Compare(*cloud, *reference, options, source));
        callback("done", 1, 1);
        return out_result;
      },
      py::arg("cloud"), py::arg("reference"), py::kw_only(), py::arg("out") = py::none(),
      py::arg("mesh_samples") = 200000, py::arg("cloud_source") = py::none(),
      py::arg("view_rig") = py::none(), py::arg("view_camera") = py::none(),
      py::arg("overwrite") = true, py::arg("progress") = py::none(),
      "Compares a cloud (PointCloud, Reconstruction, (N, 3) array or .ply path) with a reference "
      "(Reference, a mesh or cloud path, or a cloud) as `slshadow compare` does; with out= it "
      "also writes the report folder. Keyword options: the fields of CompareOptions "
      "(threshold_mm, color_range_mm, coverage_radius_mm, histogram_bins, m3c2, registration "
      "('none' | 'icp' | 'global+icp', or a dict), c2c (dict), m3c2_options (dict), ...). The GIL "
      "is released while it runs; progress(stage, done, total) is called as ('compare', 0, 1) "
      "and ('done', 1, 1).");
}

}  // namespace slshadow::python
