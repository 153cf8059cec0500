// PatternSpec, ProjectorMap, decode and simulate in Python.
#include <map>
#include <memory>

#include "core/config.h"
#include "core/error.h"
#include "core/provenance.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "patterns/simulator_projector.h"
#include "python/bindings.h"
#include "python/convert.h"
#include "sim/simulate.h"

namespace slshadow::python {

namespace {

std::string RoleName(FrameRole role) {
  switch (role) {
    case FrameRole::kWhite:
      return "white";
    case FrameRole::kBlack:
      return "black";
    case FrameRole::kGrayBit:
      return "gray_bit";
    case FrameRole::kGrayBitInverse:
      return "gray_bit_inverse";
    case FrameRole::kPhase:
      return "phase";
  }
  return "white";
}

py::dict FrameDict(const FrameInfo& f) {
  py::dict d;
  d["name"] = f.Name();
  d["role"] = RoleName(f.role);
  d["axis"] = f.axis;
  d["bit"] = f.bit;
  d["frequency"] = f.frequency;
  d["step"] = f.step;
  d["code"] = f.code;
  return d;
}

// A simulated scan kept in memory.
struct Scan {
  Rig rig;
  PatternSpec spec;
  std::shared_ptr<const Scene> scene;
  std::vector<std::vector<cv::Mat>> images;  // [camera][pattern]
  std::vector<GeometryBuffer> geometry;      // per camera when ground truth was asked for
  SimulateSummary summary;
};

py::dict GroundTruthDict(const GeometryBuffer& g) {
  py::dict d;
  d["depth_mm"] = MatToArray(g.depth_mm);
  d["point_in_rig_mm"] = MatToArray(g.point_in_rig);
  d["normal_in_rig"] = MatToArray(g.normal_in_rig);
  d["visibility"] = MatToArray(g.visibility);
  d["object_id"] = MatToArray(g.object_id);
  d["proj_x"] = MatToArray(g.projector.proj_x);
  d["proj_y"] = MatToArray(g.projector.proj_y);
  return d;
}

DecodeOptions DecodeOptionsFromKwargs(const py::kwargs& kwargs, const std::string& what) {
  if (kwargs.empty()) return DecodeOptions{};
  const nlohmann::json tree = ToJson(kwargs, what);
  return WithoutSource(what,
                       [&] { return DecodeOptionsFromConfig(ConfigNode::FromJson(tree, what)); });
}

}  // namespace

void BindPatternsAndSim(py::module_& m) {
  py::class_<PatternSpec>(m, "PatternSpec",
                          "What is projected and how it is decoded (docs/formats.md \"Pattern "
                          "spec\"): Gray code, phase shift + Gray code, multi-frequency.")
      .def_static(
          "load", [](const std::filesystem::path& path) { return LoadPatternSpec(path); },
          py::arg("path"), "Reads a spec (.yaml/.json, or a manifest with a 'patterns' member).")
      .def_static(
          "from_dict",
          [](const py::dict& tree) { return PatternSpecFromObject(tree, "PatternSpec.from_dict"); },
          py::arg("tree"),
          "A spec from its fields (the names of to_dict()); unknown keys are refused.")
      .def("to_dict", [](const PatternSpec& s) { return FromJson(PatternSpecToJson(s)); })
      .def_property_readonly("kind", [](const PatternSpec& s) { return ToString(s.kind); })
      .def_readonly("projector_width", &PatternSpec::projector_width)
      .def_readonly("projector_height", &PatternSpec::projector_height)
      .def_readonly("code_x", &PatternSpec::code_x)
      .def_readonly("code_y", &PatternSpec::code_y)
      .def_readonly("phase_steps", &PatternSpec::phase_steps)
      .def_readonly("period_px", &PatternSpec::period_px)
      .def_property_readonly("periods_px", &PatternSpec::PeriodsPx)
      .def_property_readonly("num_images", &PatternSpec::NumImages)
      .def_property_readonly(
          "frames",
          [](const PatternSpec& s) {
            py::list out;
            for (const FrameInfo& f : s.Frames()) out.append(FrameDict(f));
            return out;
          },
          "The role of every frame in projection order: dicts with name, role (white, black, "
          "gray_bit, gray_bit_inverse, phase), axis (0: x, 1: y), bit, frequency, step, code.")
      .def_property_readonly("frame_names",
                             [](const PatternSpec& s) {
                               std::vector<std::string> names;
                               for (const FrameInfo& f : s.Frames()) names.push_back(f.Name());
                               return names;
                             })
      .def_property_readonly("white_frame_index", &PatternSpec::WhiteFrameIndex)
      .def_property_readonly("black_frame_index", &PatternSpec::BlackFrameIndex)
      .def(
          "generate",
          [](const PatternSpec& s) {
            std::vector<cv::Mat> images;
            {
              py::gil_scoped_release release;
              images = GeneratePatterns(s);
            }
            return StackImages(images);
          },
          "The projector images, (num_images, projector_height, projector_width) uint8.")
      .def("__repr__", [](const PatternSpec& s) {
        return "<slshadow.PatternSpec " + ToString(s.kind) + " " +
               std::to_string(s.projector_width) + "x" + std::to_string(s.projector_height) + ", " +
               std::to_string(s.NumImages()) + " images>";
      });

  py::class_<ProjectorMap>(
      m, "ProjectorMap",
      "Decoded projector coordinates per camera pixel. The arrays share memory with the map "
      "(no copy).")
      .def_property_readonly(
          "proj_x", [](const ProjectorMap& p) { return MatToArray(p.proj_x); },
          "projector column, px (float32; NaN where invalid or not coded)")
      .def_property_readonly(
          "proj_y", [](const ProjectorMap& p) { return MatToArray(p.proj_y); },
          "projector row, px (float32; NaN where invalid or not coded)")
      .def_property_readonly(
          "status", [](const ProjectorMap& p) { return MatToArray(p.status); },
          "uint8 per pixel: 0 valid, 1 shadow, 2 low contrast, 3 saturated, 4 code error, "
          "5 filtered")
      .def_property_readonly(
          "quality", [](const ProjectorMap& p) { return MatToArray(p.quality); },
          "float32 grey levels: the modulation B' (phase codecs) or the smallest bit contrast "
          "(Gray code)")
      .def_property_readonly(
          "modulation", [](const ProjectorMap& p) { return MatToArray(p.quality); },
          "the same array as quality (the fringe modulation for phase codecs)")
      .def_property_readonly(
          "mask",
          [](const ProjectorMap& p) {
            return MatToArray(p.status == static_cast<int>(PixelStatus::kValid))
                .attr("astype")("bool");
          },
          "bool per pixel: decoded (status 0); a new array")
      .def_readonly("has_x", &ProjectorMap::has_x)
      .def_readonly("has_y", &ProjectorMap::has_y)
      .def_property_readonly("width", &ProjectorMap::width)
      .def_property_readonly("height", &ProjectorMap::height)
      .def(
          "counts",
          [](const ProjectorMap& p) {
            py::dict out;
            const auto counts = p.CountByStatus();
            for (int s = 0; s < kNumPixelStatus; ++s)
              out[py::str(ToString(static_cast<PixelStatus>(s)))] = counts[static_cast<size_t>(s)];
            return out;
          },
          "Pixels per status name.");

  m.def(
      "decode",
      [](const py::handle& images, const py::handle& patterns, const py::kwargs& kwargs) {
        const PatternSpec spec = PatternSpecFromObject(patterns, "patterns");
        const DecodeOptions options = DecodeOptionsFromKwargs(kwargs, "decode");
        std::vector<py::object> keep;
        const std::vector<cv::Mat> mats = ImagesFromObject(images, "images", &keep);
        py::gil_scoped_release release;
        return DecodePatterns(spec, mats, options);
      },
      py::arg("images"), py::arg("patterns"),
      "Decodes one camera's images (N, rows, cols) of `patterns` into a ProjectorMap. Keyword "
      "options: the fields of DecodeOptions (shadow_threshold, contrast_threshold, "
      "saturation_level, full_scale, gray_edge_midpoint, unwrap_tolerance_cycles, parallel). The "
      "images are read in place (no copy) when C-contiguous.");

  py::class_<Scan, std::shared_ptr<Scan>>(
      m, "Scan", "A virtual scan in memory (simulate()): the images every camera of the rig sees.")
      .def_readonly("rig", &Scan::rig)
      .def_readonly("patterns", &Scan::spec)
      .def_property_readonly("cameras",
                             [](const Scan& s) {
                               std::vector<std::string> names;
                               for (const auto& c : s.rig.cameras) names.push_back(c.name);
                               return names;
                             })
      .def(
          "images",
          [](const Scan& s, const std::string& camera) {
            const int index = s.rig.CameraIndex(camera);
            SLSHADOW_THROW_IF(index < 0, "Scan: unknown camera '", camera, "'");
            return StackImages(s.images[static_cast<size_t>(index)]);
          },
          py::arg("camera"), "The camera's images (N, rows, cols), a copy.")
      .def(
          "image",
          [](const Scan& s, const std::string& camera, int pattern) {
            const int index = s.rig.CameraIndex(camera);
            SLSHADOW_THROW_IF(index < 0, "Scan: unknown camera '", camera, "'");
            const auto& frames = s.images[static_cast<size_t>(index)];
            SLSHADOW_THROW_IF(pattern < 0 || pattern >= static_cast<int>(frames.size()),
                              "Scan: pattern index ", pattern, " out of range (", frames.size(),
                              " images)");
            return MatToArray(frames[static_cast<size_t>(pattern)]);
          },
          py::arg("camera"), py::arg("index"),
          "One image (rows, cols), sharing memory with the scan (no copy).")
      .def(
          "ground_truth",
          [](const Scan& s, const std::string& camera) {
            const int index = s.rig.CameraIndex(camera);
            SLSHADOW_THROW_IF(index < 0, "Scan: unknown camera '", camera, "'");
            SLSHADOW_THROW_IF(s.geometry.empty(),
                              "Scan: no ground truth (simulate(..., ground_truth=True))");
            return GroundTruthDict(s.geometry[static_cast<size_t>(index)]);
          },
          py::arg("camera"),
          "The camera's ground-truth maps (no copy): depth_mm, point_in_rig_mm (H, W, 3), "
          "normal_in_rig, visibility (0 none, 1 not lit, 2 lit), object_id (-1 none), proj_x, "
          "proj_y.")
      .def(
          "visible_surface",
          [](const Scan& s, const std::string& camera) {
            const int index = s.rig.CameraIndex(camera);
            SLSHADOW_THROW_IF(index < 0, "Scan: unknown camera '", camera, "'");
            SLSHADOW_THROW_IF(s.geometry.empty(),
                              "Scan: no ground truth (simulate(..., ground_truth=True))");
            return std::make_shared<PointCloud>(
                VisibleSurface(s.geometry[static_cast<size_t>(index)]));
          },
          py::arg("camera"),
          "The surface the camera sees as a PointCloud (rig frame, mm), with normals.")
      .def_property_readonly("summary", [](const Scan& s) { return s.summary.BriefReport(); })
      .def(
          "write",
          [](const Scan& s, const std::filesystem::path& dir, const std::string& encoding,
             bool overwrite) {
            ImageSetWriterOptions options;
            options.encoding = ImageEncodingFromString(encoding);
            options.overwrite = overwrite;
            {
              py::gil_scoped_release release;
              SimulateOptions sim_options;
              sim_options.writer = options;
              ImageSetWriter writer(dir, s.rig, PatternSpecToJson(s.spec), options);
              writer.SetExtra(ExtraWithProvenance(
                  VirtualScanProvenance(*s.scene, sim_options, "slshadow python")));
              for (size_t c = 0; c < s.images.size(); ++c)
                for (size_t i = 0; i < s.images[c].size(); ++i)
                  writer.Add(s.rig.cameras[c].name, static_cast<int>(i), s.images[c][i],
                             s.scene->radiometry.exposure_us, ImageSource::kVirtual);
              writer.Commit();
            }
            return PyImageSet{ImageSet::Open(dir)};
          },
          py::arg("dir"), py::kw_only(), py::arg("encoding") = "png", py::arg("overwrite") = false,
          "Writes the scan as an ImageSet (source 'virtual', atomically) and opens it.");

  m.def(
      "simulate",
      [](const Rig& rig, std::shared_ptr<Scene> scene, const py::handle& patterns,
         bool ground_truth, const std::string& trace_mode, py::object progress) {
        auto scan = std::make_shared<Scan>();
        scan->rig = rig;
        scan->spec = PatternSpecFromObject(patterns, "patterns");
        scan->scene = scene;
        CheckSimulatorProjector(rig, scan->spec, "patterns", "rig '" + rig.name + "'");
        const TraceMode mode = TraceModeFromString(trace_mode);
        const ProgressCallback report(std::move(progress));
        {
          py::gil_scoped_release release;
          const ForwardLibraryProgress forward(report);
          scene->Check("scene '" + scene->name + "'");
          rig.Check("rig '" + rig.name + "'");
          const std::vector<cv::Mat> projector_images = GeneratePatterns(scan->spec);
          Simulator simulator(*scene, scan->rig, mode, ground_truth);
          scan->summary = simulator.setup();
          scan->images = simulator.Render(projector_images, nullptr, &scan->summary);
          if (ground_truth) scan->geometry = simulator.ReleaseGeometry();
        }
        return scan;
      },
      py::arg("rig"), py::arg("scene"), py::arg("patterns"), py::kw_only(),
      py::arg("ground_truth") = false, py::arg("trace_mode") = "packet16",
      py::arg("progress") = py::none(),
      "Virtual scan in memory: every camera of `rig` sees every projector image of `patterns` on "
      "`scene` (the images `slshadow simulate` writes). Returns a Scan. progress(stage, done, "
      "total) is called per camera traced (stage 'trace') and per image rendered ('render'). "
      "The GIL is released while it runs.");
}

}  // namespace slshadow::python
