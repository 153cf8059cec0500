// The workflows in Python: shadow (`slshadow shadow`) and _sweep (`slshadow sweep study`), the
// library calls behind those commands (calibration: bind_calibrate.cc).
#include <atomic>
#include <chrono>
#include <filesystem>
#include <optional>

#include <unistd.h>

#include "core/error.h"
#include "core/image_io.h"
#include "python/bindings.h"
#include "python/convert.h"
#include "workflows/studies/sweep.h"
#include "workflows/twin/twin.h"

namespace slshadow::python {

namespace {

namespace fs = std::filesystem;

// rig_from_part from None, six numbers (rotation vector, rad, then translation, mm: the
// command line's --pose) or a 4x4 matrix.
std::optional<Rigid3d> PoseFromObject(const py::handle& pose) {
  if (pose.is_none()) return std::nullopt;
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(pose);
  SLSHADOW_THROW_IF(!a,
                    "shadow: pose: expected 6 numbers (rx ry rz, rad; tx ty tz, mm) or a 4x4 "
                    "matrix");
  if (a.ndim() == 1 && a.shape(0) == 6) {
    const double* p = a.data();
    return Rigid3d::FromRotationVector(Eigen::Vector3d(p[0], p[1], p[2]),
                                       Eigen::Vector3d(p[3], p[4], p[5]));
  }
  SLSHADOW_THROW_IF(a.ndim() != 2 || a.shape(0) != 4 || a.shape(1) != 4,
                    "shadow: pose: expected 6 numbers (rx ry rz, rad; tx ty tz, mm) or a 4x4 "
                    "matrix (got shape ",
                    std::string(py::str(py::tuple(a.attr("shape")))), ")");
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m(r, c) = a.at(r, c);
  return Rigid3d::FromMatrix(m);
}

// A colour map as RGB (the files are written by OpenCV's convention, BGR in memory).
py::array MapArray(const fs::path& path) {
  cv::Mat image = ReadImage(path, ImageReadMode::kUnchanged);
  if (image.channels() == 3) {
    cv::Mat rgb(image.size(), image.type());
    const int from_to[] = {0, 2, 1, 1, 2, 0};
    cv::mixChannels(&image, 1, &rgb, 1, from_to, 3);
    image = rgb;
  }
  return MatToArray(image);
}

// {camera: {map name: array}} of the report's "maps" entries (files under `dir`).
py::dict ReadMaps(const nlohmann::json& report, const fs::path& dir) {
  py::dict maps;
  if (!report.contains("maps")) return maps;
  for (const auto& entry : report["maps"]) {
    py::dict one;
    for (const auto& [key, value] : entry.items()) {
      if (value.is_string() && value.get<std::string>().ends_with(".png"))
        one[py::str(key)] = MapArray(dir / value.get<std::string>());
    }
    maps[py::str(entry.value("camera", std::string("?")))] = one;
  }
  return maps;
}

}  // namespace

void BindShadow(py::module_& m) {
  m.def(
      "shadow",
      [](const py::handle& real, const std::filesystem::path& part_path,
         const std::optional<std::filesystem::path>& out, const std::optional<Rig>& rig,
         const py::object& pose, bool refine_pose, bool fit_physics, double min_fitness,
         double max_rmse_mm, bool write_clouds, bool overwrite, const py::object& progress,
         const py::kwargs& kwargs) {
        std::string image_set_dir;
        if (py::isinstance<PyImageSet>(real)) {
          image_set_dir = real.cast<const PyImageSet&>().image_set.dir().string();
        } else {
          image_set_dir = py::str(py::module_::import("os").attr("fspath")(real));
        }
        twin::ShadowOptions options;
        const ImageSetReconstructOptions r =
            ReconstructOptionsFromKwargs(kwargs, nullptr, "shadow");
        options.reconstruct = r.reconstruct;
        options.decode = r.decode;
        options.rig_from_part = PoseFromObject(pose);
        SLSHADOW_THROW_IF(!refine_pose && !options.rig_from_part,
                          "shadow: refine_pose=False needs a pose (the command line's --fixed-pose "
                          "needs --pose)");
        options.refine_pose = refine_pose;
        options.fit_physics = fit_physics;
        options.min_fitness = min_fitness;
        options.max_rmse_mm = max_rmse_mm;
        options.write_clouds = write_clouds;
        options.overwrite = overwrite;
        options.Check();  // its messages are the command line's ("shadow: min_fitness ...")
        // Without out=, the report folder is written to a temporary folder for its maps, then
        // removed.
        static std::atomic<int> counter{0};
        const fs::path dir =
            out ? *out
                : fs::temp_directory_path() /
                      ("slshadow-shadow-" + std::to_string(::getpid()) + "-" +
                       std::to_string(counter++) + "-" +
                       std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()));
        const ProgressCallback report(progress);
        twin::ShadowResult result;
        {
          py::gil_scoped_release release;
          const ForwardLibraryProgress forward(report);
          report("shadow", 0, 1);
          try {
            const twin::ShadowPart part = twin::LoadShadowPart(part_path);
            result = twin::RunShadow(image_set_dir, part, options, dir, rig ? &*rig : nullptr);
          } catch (...) {
            std::error_code ec;
            if (!out) fs::remove_all(dir, ec);
            throw;
          }
          report("done", 1, 1);
        }
        py::dict d;
        d["report"] = FromJson(result.report);
        d["summary"] = result.Summary();
        d["rig_from_part"] = Matrix4(result.rig_from_part);
        try {
          d["maps"] = ReadMaps(result.report, dir);
        } catch (...) {
          std::error_code ec;
          if (!out) fs::remove_all(dir, ec);
          throw;
        }
        std::error_code ec;
        if (!out) fs::remove_all(dir, ec);
        return d;
      },
      py::arg("real"), py::arg("part"), py::kw_only(), py::arg("out") = py::none(),
      py::arg("rig") = py::none(), py::arg("pose") = py::none(), py::arg("refine_pose") = true,
      py::arg("fit_physics") = true, py::arg("min_fitness") = 0.5, py::arg("max_rmse_mm") = 0.5,
      py::arg("write_clouds") = true, py::arg("overwrite") = false,
      py::arg("progress") = py::none(),
      "Real vs virtual (`slshadow shadow`): the real scan (an ImageSet or its folder) against its "
      "twin re-scanning `part` (a mesh or scene file): pose, physics fit, re-scan, comparison, "
      "diagnosis. pose: rig_from_part as 6 numbers (rx ry rz in rad, tx ty tz in mm: --pose) or "
      "a 4x4 matrix; refine_pose=False keeps it (--fixed-pose). Keyword options: the fields of "
      "ReconstructOptions and DecodeOptions. Returns a dict: report (report.json), summary, "
      "rig_from_part (4x4), maps {camera: {name: RGB array}}. With out= the report folder is kept "
      "there. The GIL is released while it runs; progress(stage, done, total): ('shadow', 0, 1), "
      "then the reconstructions' and renderings' own steps (each run of a stage counts up), then "
      "('done', 1, 1).");
}

void BindSweep(py::module_& m) {
  m.def(
      "_sweep",
      [](const std::filesystem::path& study, const std::filesystem::path& out,
         const std::string& shard, bool verbose, const py::object& progress) {
        studies::SweepRunOptions options;
        studies::ParseShard(shard, "shard", &options);
        options.verbose = verbose;
        const ProgressCallback report(progress);
        studies::SweepStudySummary s;
        {
          py::gil_scoped_release release;
          const ForwardLibraryProgress forward(report, "jobs");  // per job (run or found done)
          report("plan", 0, 1);
          s = studies::RunStudy(study, out, options,
                                [&](const studies::SweepStudySummary&) { report("plan", 1, 1); });
          report("done", 1, 1);
        }
        py::dict plan, run, merge;
        plan["study"] = s.plan.study;
        plan["jobs"] = s.plan.jobs;
        plan["geometry_groups"] = s.plan.geometry_groups;
        plan["axes"] = s.plan.axes;
        run["assigned"] = s.run.assigned;
        run["already_done"] = s.run.already_done;
        run["ran"] = s.run.ran;
        run["geometry_traces"] = s.run.geometry_traces;
        run["wall_s"] = s.run.wall_s;
        run["summary"] = s.run.BriefReport();
        merge["jobs"] = s.merge.jobs;
        merge["rows"] = s.merge.rows;
        merge["front"] = s.merge.front;
        merge["break_points"] = s.merge.break_points;
        merge["effects"] = s.merge.effects;
        merge["acceptance"] = s.merge.acceptance;
        merge["uncertainty"] = s.merge.uncertainty;
        py::dict d;
        d["resumed"] = s.resumed;
        d["plan"] = plan;
        d["run"] = run;
        d["merge"] = merge;
        d["jobs_dir"] = s.jobs_dir.string();
        d["out_dir"] = s.merge.out_dir.string();
        return d;
      },
      py::arg("study"), py::arg("out"), py::kw_only(), py::arg("shard") = "0/1",
      py::arg("verbose") = false, py::arg("progress") = py::none(),
      "`slshadow sweep study`: plans, runs and merges a study (docs/sweeps.md); slshadow.sweep "
      "adds the result tables.");
}

}  // namespace slshadow::python
