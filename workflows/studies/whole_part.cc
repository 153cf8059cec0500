#include "workflows/studies/whole_part.h"

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/stage_meter.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/views.h"
#include "workflows/multiview/virtual_project.h"
#include "workflows/studies/internal/sweep_files.h"
#include "workflows/studies/internal/sweep_pareto.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>

namespace slshadow::studies {
namespace fs = std::filesystem;
using nlohmann::json;

json WholePartOptions::ToJson() const {
  return {{"views", views},
          {"start_deg", start_deg},
          {"part_object", part_object},
          {"remove_objects", remove_objects},
          {"poses", poses},
          {"frame_ms", frame_ms},
          {"turn_s", turn_s},
          {"max_points_per_view", max_points_per_view},
          {"reference_views", reference_views},
          {"cad",
           {{"samples", cad_samples},
            {"grazing_deg", grazing_deg},
            {"table_tolerance_mm", table_tolerance_mm},
            {"coverage_radius_mm", coverage_radius_mm}}}};
}

WholePartOptions WholePartOptionsFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"views", "start_deg", "part_object", "remove_objects", "poses",
                          "frame_ms", "turn_s", "max_points_per_view", "reference_views", "cad"});
  WholePartOptions o;
  if (node.Has("views")) {
    const int64_t v = node["views"].AsInt();
    if (v < 1 || v > 360) node["views"].Fail("must be in 1..360");
    o.views = static_cast<int>(v);
  }
  o.start_deg = node.GetDouble("start_deg", o.start_deg);
  o.part_object = node.GetString("part_object", o.part_object);
  if (o.part_object.empty()) node["part_object"].Fail("must not be empty");
  if (node.Has("remove_objects")) {
    o.remove_objects.clear();
    for (size_t i = 0; i < node["remove_objects"].size(); ++i)
      o.remove_objects.push_back(node["remove_objects"].at(i).AsString());
  }
  o.poses = node.GetString("poses", o.poses);
  if (node.Has("poses")) {
    try {
      multiview::PoseSourceFromString(o.poses);
    } catch (const Error&) {
      node["poses"].Fail("must be 'registered' or 'axis'");
    }
  }
  o.frame_ms = node.GetDouble("frame_ms", o.frame_ms);
  if (!(o.frame_ms >= 0)) node["frame_ms"].Fail("must be >= 0 (0: the scene's exposure)");
  o.turn_s = node.GetDouble("turn_s", o.turn_s);
  if (!(o.turn_s >= 0)) node["turn_s"].Fail("must be >= 0");
  if (node.Has("max_points_per_view")) {
    const int64_t m = node["max_points_per_view"].AsInt();
    if (m < 0 || m > 100000000) node["max_points_per_view"].Fail("must be in 0..100000000");
    o.max_points_per_view = static_cast<int>(m);
  }
  if (node.Has("reference_views")) {
    const int64_t v = node["reference_views"].AsInt();
    if (v < 1 || v > 360) node["reference_views"].Fail("must be in 1..360");
    o.reference_views = static_cast<int>(v);
  }
  if (node.Has("cad")) {
    const ConfigNode cad = node["cad"];
    cad.RejectUnknownKeys({"samples", "grazing_deg", "table_tolerance_mm", "coverage_radius_mm"});
    if (cad.Has("samples")) {
      const int64_t s = cad["samples"].AsInt();
      if (s < 100 || s > 10000000) cad["samples"].Fail("must be in 100..10000000");
      o.cad_samples = static_cast<int>(s);
    }
    o.grazing_deg = cad.GetDouble("grazing_deg", o.grazing_deg);
    if (!(o.grazing_deg > 0 && o.grazing_deg <= 90)) cad["grazing_deg"].Fail("must be in (0, 90]");
    o.table_tolerance_mm = cad.GetDouble("table_tolerance_mm", o.table_tolerance_mm);
    if (!(o.table_tolerance_mm >= 0)) cad["table_tolerance_mm"].Fail("must be >= 0");
    o.coverage_radius_mm = cad.GetDouble("coverage_radius_mm", o.coverage_radius_mm);
    if (!(o.coverage_radius_mm >= 0)) cad["coverage_radius_mm"].Fail("must be >= 0");
  }
  return o;
}

double AcquisitionSeconds(int views, int patterns, double frame_s, double turn_s) {
  return views * (patterns * frame_s + turn_s);
}

namespace internal {

namespace {

double SecondsBetween(std::chrono::steady_clock::time_point a,
                      std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

// Removes a job's work folder when the job ends, whichever way.
struct WorkFolder {
  fs::path path;
  ~WorkFolder() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

}  // namespace

json RunWholePartJob(const json& job, const fs::path& file) {
  const std::string what = file.string();
  const auto node = [&](const char* key) { return ConfigNode::FromJson(job.at(key), what, key); };
  const auto t0 = std::chrono::steady_clock::now();
  const double cpu0 = ProcessCpuSeconds();
  const WholePartOptions options = WholePartOptionsFromConfig(node("whole_part"));
  const Scene scene = SceneFromConfig(node("scene"), job.at("scene_base_dir").get<std::string>());
  const multiview::TurntableSetup setup = multiview::MakeTurntableSetup(
      RigFromConfig(node("rig")), scene, options.part_object, options.remove_objects);
  const PatternSpec spec = PatternSpecFromConfig(node("patterns"));
  const multiview::ViewsFile views = multiview::FullTurnViews(options.views, options.start_deg);
  const TriangleMesh cad = multiview::PartSurface(setup.scene);

  // The project under JOBS/work/<id>: an interrupted job's leftovers are removed first.
  const int id = job.at("id").get<int>();
  WorkFolder work{file.parent_path().parent_path() / "work" / JobName(id)};
  std::error_code ec;
  fs::remove_all(work.path, ec);
  fs::create_directories(work.path, ec);
  SLSHADOW_THROW_IF(ec, work.path.string(), ": cannot create folder: ", ec.message());
  multiview::VirtualProjectOptions scan;
  scan.generator = "slshadow sweep (whole_part)";
  scan.rig_what = what + ": rig";
  scan.spec_what = what + ": patterns";
  const multiview::VirtualProjectSummary rendered =
      multiview::SimulateProject(setup.scene, setup.rig, spec, views, work.path / "project", scan);
  json timing = {{"render_s", rendered.total_seconds}, {"method_s", json::object()},
                 {"reconstruct_s", json::object()},    {"merge_s", json::object()},
                 {"cad_compare_s", json::object()},    {"reference_s", json::object()}};

  const int patterns = spec.NumImages();
  const double frame_s =
      (options.frame_ms > 0 ? options.frame_ms : setup.scene.radiometry.exposure_us / 1000.0) /
      1000.0;
  const double acquisition_s = AcquisitionSeconds(options.views, patterns, frame_s, options.turn_s);
  json modes = json::array();
  for (const auto& m : job.at("modes")) {
    const std::string mode_name = m.get<std::string>();
    multiview::ProjectMergeOptions merge;
    merge.mode = ReconstructModeFromString(mode_name);
    merge.poses = multiview::PoseSourceFromString(options.poses);
    merge.decode = DecodeOptionsFromConfig(node("decode"));
    merge.reconstruct = ReconstructOptionsFromConfig(node("reconstruct"));
    merge.reconstruct.report_residuals = false;  // as MergeProject's default: same cloud, faster
    merge.max_points_per_view = static_cast<size_t>(options.max_points_per_view);
    merge.cad.threshold_mm = job.at("compare").at("threshold_mm").get<double>();
    merge.cad.samples = static_cast<size_t>(options.cad_samples);
    merge.cad.grazing_deg = options.grazing_deg;
    merge.cad.table_tolerance_mm = options.table_tolerance_mm;
    merge.cad.coverage_radius_mm = options.coverage_radius_mm;
    merge.mesh = false;  // the surface mesh is not a figure of the study
    const multiview::ProjectMergeResult r =
        multiview::MergeProject(work.path / "project", &cad, merge);
    const multiview::CadComparison& c = *r.cad;
    // Views the merge left out, with its reason (e.g. a registration that did not converge).
    json left_out = json::array();
    for (const multiview::MergedView& v : r.views) {
      if (!v.merged) left_out.push_back(v.name + ": " + v.reason);
    }
    // The part's reachable surface: what a full turn in reference_views uniform steps lets every
    // device of the mode see (the same CAD samples, cad_compare.h's rules, only the merged cloud
    // covering). Coverage = covered / (reachable from the full turn, or covered).
    std::vector<multiview::CadView> reference;
    for (const multiview::ViewSpec& v :
         multiview::FullTurnViews(options.reference_views, options.start_deg).views) {
      reference.push_back(
          {v.name, setup.rig.turntable->RigFromTableTurn(*v.table_deg).Inverse(), nullptr});
    }
    const multiview::CadComparison turn = multiview::CompareWithCad(
        cad, setup.rig, merge.mode, reference, r.merged, setup.rig.turntable, merge.cad);
    size_t covered = 0, reachable = 0;
    for (size_t i = 0; i < c.sample_reason.size(); ++i) {
      const auto job_reason = static_cast<multiview::CoverageReason>(c.sample_reason[i]);
      const auto turn_reason = static_cast<multiview::CoverageReason>(turn.sample_reason[i]);
      const bool is_covered = job_reason == multiview::CoverageReason::kCovered;
      covered += is_covered;
      reachable += is_covered || multiview::Reachable(turn_reason);
    }
    const double part_coverage =
        reachable ? static_cast<double>(covered) / static_cast<double>(reachable) : 0.0;
    std::vector<double> view_rms;
    int merged_views = 0;
    for (const multiview::CadViewFigures& v : c.views) {
      if (!v.merged) continue;
      view_rms.push_back(v.c2m.rms_mm);
      ++merged_views;
    }
    double single_view_rms = std::nan("");
    if (!view_rms.empty()) {
      const auto mid = view_rms.begin() + static_cast<long>((view_rms.size() - 1) / 2);
      std::nth_element(view_rms.begin(), mid, view_rms.end());
      single_view_rms = *mid;
    }
    const auto or_null = [](double v) { return std::isfinite(v) ? json(v) : json(); };
    modes.push_back({{"mode", mode_name},
                     {"views", options.views},
                     {"views_merged", merged_views},
                     {"left_out", left_out},
                     {"points", c.merged_points},
                     {"coverage", part_coverage},
                     {"coverage_views", c.coverage_reachable},
                     {"coverage_total", c.coverage_total},
                     {"reachable_share", c.reachable_share},
                     {"mean_mm", c.merged_c2m.signed_mean_mm},
                     {"rms_mm", c.merged_c2m.rms_mm},
                     {"median_mm", c.merged_c2m.median_mm},
                     {"p95_mm", c.merged_c2m.p95_mm},
                     {"max_mm", c.merged_c2m.max_mm},
                     {"single_view_rms_mm", or_null(single_view_rms)},
                     {"patterns", patterns},
                     {"frame_s", frame_s},
                     {"turn_s", options.turn_s},
                     {"acquisition_s", acquisition_s}});
    timing["reconstruct_s"][mode_name] = r.reconstruct_seconds;
    timing["merge_s"][mode_name] = r.merge_seconds;
    timing["cad_compare_s"][mode_name] = r.compare_seconds;
    timing["method_s"][mode_name] = r.reconstruct_seconds + r.merge_seconds;
    timing["reference_s"][mode_name] = turn.seconds;
  }
  timing["total_s"] = SecondsBetween(t0, std::chrono::steady_clock::now());
  timing["cpu_s"] = ProcessCpuSeconds() - cpu0;
  return {{"format", kResultFormat},    {"version", kVersion}, {"id", job.at("id")},
          {"params", job.at("params")}, {"modes", modes},      {"timing", timing}};
}

WholePartMerge WriteWholePartResults(const fs::path& out_dir, const std::vector<std::string>& axes,
                                     const std::vector<json>& results, const std::string& study) {
  WholePartMerge merge;
  const std::vector<std::string> metrics = {
      "views_merged",   "points",          "coverage", "coverage_views",
      "coverage_total", "reachable_share", "mean_mm",  "rms_mm",
      "median_mm",      "p95_mm",          "max_mm",   "single_view_rms_mm",
      "patterns",       "acquisition_s"};
  std::string csv = "id";
  for (const auto& a : axes) csv += ',' + CsvField(a);
  csv += ",mode";
  for (const auto& m : metrics) csv += ',' + m;
  csv += '\n';
  std::vector<FrontPoint> coverage, rms;
  std::vector<double> acquisition, processing;
  for (const auto& r : results) {
    const std::string id = JobName(r.at("id").get<int>());
    const std::string label = ParamsLabel(r.at("params"), axes, "");
    for (const auto& m : r.at("modes")) {
      csv += id;
      for (const auto& a : axes) csv += ',' + CsvField(r.at("params").at(a));
      csv += ',' + CsvField(m.at("mode"));
      for (const auto& k : metrics) csv += ',' + CsvField(m.at(k));
      csv += '\n';
      ++merge.rows;
      FrontPoint p;
      p.id = id;
      p.mode = m.at("mode").get<std::string>();
      p.group = p.mode;
      p.label = label.empty() ? id : label;
      p.described = label.empty() ? "job " + id : ParamsLabel(r.at("params"), axes, "", true);
      acquisition.push_back(m.at("acquisition_s").get<double>());
      processing.push_back(r.at("timing").at("method_s").at(p.mode).get<double>());
      p.time_s = acquisition.back() + processing.back();
      p.value = m.at("coverage").get<double>();
      coverage.push_back(p);
      p.value = m.at("rms_mm").get<double>();
      rms.push_back(p);
    }
  }
  WriteTextFileAtomically(out_dir / "results.csv", csv);
  MarkFront(coverage, /*higher_is_better=*/true);
  KeyFront(coverage);
  MarkFront(rms);
  KeyFront(rms);
  std::string front =
      "id,mode,label,acquisition_s,processing_s,scan_time_s,coverage,rms_mm,on_coverage_front,"
      "coverage_key,on_rms_front,rms_key\n";
  for (size_t i = 0; i < coverage.size(); ++i) {
    const FrontPoint& c = coverage[i];
    const FrontPoint& e = rms[i];
    front += c.id + ',' + c.mode + ',' + CsvField(c.label) + ',' +
             CsvField(json(acquisition[i]), 17) + ',' + CsvField(json(processing[i]), 17) + ',' +
             CsvField(json(c.time_s), 17) + ',' + CsvField(json(c.value), 17) + ',' +
             CsvField(json(e.value), 17) + ',' + (c.on_front ? "1" : "0") + ',' + c.key + ',' +
             (e.on_front ? "1" : "0") + ',' + e.key + '\n';
  }
  WriteTextFileAtomically(out_dir / "pareto.csv", front);
  const auto lines = [](const std::vector<FrontPoint>& points, std::vector<std::string>* out) {
    for (const size_t i : FrontInKeyOrder(points)) {
      const FrontPoint& p = points[i];
      out->push_back(p.key + " " + p.group + ": " + p.id + " (" + p.described + ")");
    }
  };
  lines(coverage, &merge.coverage_front);
  lines(rms, &merge.rms_front);
  FrontChartText text;
  text.x_label = "scan time (s): acquisition (modelled) + processing (measured)";
  text.y_label = "coverage of the reachable CAD surface";
  text.title = "scan time against coverage";
  text.value_unit = "";
  WriteFrontChart(out_dir / "time_vs_coverage", coverage, study, text);
  text.y_label = "merged C2M RMS (mm)";
  text.title = "scan time against RMS";
  text.value_unit = " mm";
  WriteFrontChart(out_dir / "time_vs_rms", rms, study, text);
  return merge;
}

}  // namespace internal
}  // namespace slshadow::studies
