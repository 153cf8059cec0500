#include "workflows/studies/sweep.h"

#include "compare/compare.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"
#include "core/shard.h"
#include "core/stage_meter.h"
#include "core/string_printf.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/studies/internal/sweep_files.h"
#include "workflows/studies/internal/sweep_job.h"
#include "workflows/studies/montecarlo.h"
#include "workflows/studies/sweep_reuse.h"
#include "workflows/studies/vdi2634.h"
#include "workflows/studies/whole_part.h"

#include <tbb/parallel_for.h>

#ifdef __GLIBC__
#include <malloc.h>
#endif

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <set>

namespace slshadow::studies {
namespace fs = std::filesystem;
using nlohmann::json;

namespace internal {

const std::vector<std::string> kCurveMetrics = {"p95_mm", "rms_mm", "outlier_fraction", "coverage",
                                                "visible_coverage"};
bool BreaksAbove(const std::string& metric) { return metric.find("coverage") == std::string::npos; }

std::string JobName(int id) {
  char buf[32];
  std::snprintf(buf, sizeof(buf), "%06d", id);
  return buf;
}
fs::path ResultFile(const fs::path& dir, int id) {
  return dir / "results" / (JobName(id) + ".json");
}

json ReadJsonFile(const fs::path& path) {
  try {
    return json::parse(ReadTextFile(path));
  } catch (const json::exception& e) {
    SLSHADOW_THROW(path.string(), ": not valid JSON: ", e.what());
  }
}

json ReadPlan(const fs::path& jobs_dir) {
  const fs::path file = jobs_dir / "plan.json";
  const json plan = ReadJsonFile(file);
  SLSHADOW_THROW_IF(!plan.is_object() || plan.value("format", "") != kPlanFormat ||
                        plan.value("version", 0) != kVersion,
                    file.string(), ": not a sweep plan (format ", kPlanFormat, ", version 1)");
  return plan;
}

}  // namespace internal

using namespace internal;  // NOLINT: the jobs folder's formats,
                           // workflows/studies/internal/sweep_files.h

namespace {

constexpr const char* kStudyFormat = "slshadow-study";
constexpr const char* kJobFormat = "slshadow-sweep-job";
// The top-level keys of a job an axis or a `set` entry may write into.
const std::vector<std::string> kSettable = {"scene",       "rig",     "patterns",  "decode",
                                            "reconstruct", "compare", "whole_part"};

fs::path JobFile(const fs::path& dir, int id) { return dir / "jobs" / (JobName(id) + ".json"); }

// "scene.layers.noise.seed" -> the JSON pointer into a job; `node` names the study field on error.
json::json_pointer SetPath(const std::string& path, const ConfigNode& node) {
  if (path.empty()) node.Fail("empty path");
  std::string pointer;
  size_t start = 0;
  while (true) {
    const size_t dot = path.find('.', start);
    const std::string part =
        path.substr(start, dot == std::string::npos ? std::string::npos : dot - start);
    if (part.empty()) node.Fail("path '" + path + "' has an empty component");
    if (start == 0 && std::find(kSettable.begin(), kSettable.end(), part) == kSettable.end()) {
      node.Fail("path '" + path +
                "' must start with one of scene, rig, patterns, decode, reconstruct, compare, "
                "whole_part");
    }
    pointer += '/';
    pointer += part;
    if (dot == std::string::npos) break;
    start = dot + 1;
  }
  return json::json_pointer(pointer);
}

// A file value of an axis or of the study's scene / rig / patterns keys, as its job JSON.
struct FileValue {
  json tree;
  std::string base_dir;  // scenes only
};
FileValue LoadFileValue(const std::string& key, const std::string& file,
                        const fs::path& study_dir) {
  const fs::path path = file.empty()
                            ? fs::path()
                            : (fs::path(file).is_absolute() ? fs::path(file) : study_dir / file);
  FileValue v;
  if (key == "scene") {
    const Scene scene = pipeline::LoadSceneOrDemo(path, study_dir);
    v.tree = scene.source_config;
    v.base_dir = fs::absolute(scene.source_dir).lexically_normal().string();
  } else if (key == "rig") {
    v.tree = RigToJson(pipeline::LoadRigOrDemo(path));
  } else {
    v.tree = PatternSpecToJson(pipeline::LoadPatternSpecOrDemo(path));
  }
  return v;
}

struct Axis {
  std::string name;
  json::json_pointer target;
  std::string target_text;
  std::vector<json> values;            // written at target (files: the loaded trees)
  std::vector<json> labels;            // the value in the results (files: the path as written)
  std::vector<std::string> base_dirs;  // scene files only
  // A study kind's axis (vdi2634's `position`): per value, also written at job[extra_key].
  std::string extra_key;
  std::vector<json> extras;
};

// A value of a study kind's axis (study 4's `sample`, study 5's `position`): what it writes at the
// axis's target, its label in the results, the tree written at job[extra_key] and, for scene
// values, the job's scene_base_dir.
struct KindValue {
  json value, label, extra;
  std::string base_dir;  // empty: not a scene
};

// Puts a study kind's axis first (the slowest), `target` a dotted path into the job.
void PrependKindAxis(const std::string& name, const std::string& target,
                     const std::string& extra_key, const std::vector<KindValue>& values,
                     std::vector<Axis>* axes, std::vector<std::string>* names) {
  Axis axis;
  axis.name = name;
  axis.target_text = target;
  std::string pointer = "/" + target;
  std::replace(pointer.begin(), pointer.end(), '.', '/');
  axis.target = json::json_pointer(pointer);
  axis.extra_key = extra_key;
  for (const KindValue& v : values) {
    axis.values.push_back(v.value);
    axis.labels.push_back(v.label);
    axis.extras.push_back(v.extra);
    if (!v.base_dir.empty()) axis.base_dirs.push_back(v.base_dir);
  }
  names->insert(names->begin(), name);
  axes->insert(axes->begin(), std::move(axis));
}

// Study 3's "one layer off" (study key effects.full): for every value of `axis` but the baseline
// and the full model, a value "without_<label>": the full model's mapping without that value's
// keys (e.g. all layers but noise). The merge measures each layer's effect against the full model
// from these (workflows/studies/sweep.h).
void AddOneLayerOffValues(const ConfigNode& effects, Axis* axis) {
  const json full_label = effects["full"].json();
  const json baseline = effects["baseline"].json();
  const auto full_it = std::find(axis->labels.begin(), axis->labels.end(), full_label);
  if (full_it == axis->labels.end()) {
    effects["full"].Fail("is not a value (or label) of axis '" + axis->name + "'");
  }
  if (full_label == baseline) effects["full"].Fail("must differ from the baseline");
  const std::string full_name =
      full_label.is_string() ? full_label.get<std::string>() : full_label.dump();
  const json full = axis->values[static_cast<size_t>(full_it - axis->labels.begin())];
  if (!full.is_object()) {
    effects["full"].Fail("the full model's value must be a mapping (e.g. of scene layers)");
  }
  const size_t n = axis->values.size();
  for (size_t i = 0; i < n; ++i) {
    const json& label = axis->labels[i];
    if (label == baseline || label == full_label) continue;
    const json& value = axis->values[i];
    if (!value.is_object() || !label.is_string()) {
      effects["full"].Fail("axis '" + axis->name + "' value " + label.dump() +
                           ": one layer off needs named values that are mappings");
    }
    json without = full;
    for (const auto& item : value.items()) {
      if (!full.contains(item.key())) {
        effects["full"].Fail("value '" + label.get<std::string>() + "' sets '" + item.key() +
                             "', which the full model '" + full_name + "' does not");
      }
      without.erase(item.key());
    }
    const json without_label = "without_" + label.get<std::string>();
    if (std::find(axis->labels.begin(), axis->labels.end(), without_label) != axis->labels.end()) {
      effects["full"].Fail("axis '" + axis->name + "' already has a value " + without_label.dump());
    }
    axis->values.push_back(std::move(without));
    axis->labels.push_back(without_label);
  }
}

// Checks a job by the codecs that will read it; `what` names it in errors.
void CheckJob(const json& job, const std::string& what, std::set<std::string>* seen_scenes) {
  const auto node = [&](const char* key) { return ConfigNode::FromJson(job.at(key), what, key); };
  const std::string scene_key = job.at("scene").dump() + job.at("scene_base_dir").dump();
  const Rig rig = RigFromConfig(node("rig"));
  if (seen_scenes->insert(scene_key).second) {
    const Scene scene = SceneFromConfig(node("scene"), job.at("scene_base_dir").get<std::string>());
    scene.Check(what + ": scene");
    if (job.contains("whole_part")) {
      // The part on the turntable: its object and the objects removed must be in the scene.
      const WholePartOptions w = WholePartOptionsFromConfig(node("whole_part"));
      try {
        multiview::MakeTurntableSetup(rig, scene, w.part_object, w.remove_objects);
      } catch (const Error& e) {
        SLSHADOW_THROW(what, ": whole_part: ", e.what());
      }
    }
  }
  PatternSpecFromConfig(node("patterns")).Check();
  DecodeOptionsFromConfig(node("decode"));
  ReconstructOptionsFromConfig(node("reconstruct"));
  compare::CompareOptionsFromConfig(node("compare"));
  for (const auto& m : job.at("modes")) {
    const ReconstructMode mode = ReconstructModeFromString(m.get<std::string>());
    SLSHADOW_THROW_IF(mode == ReconstructMode::kStereo && rig.cameras.size() < 2, what,
                      ": mode stereo needs a rig with two cameras");
    SLSHADOW_THROW_IF(mode == ReconstructMode::kProjector && !rig.projector, what,
                      ": mode projector needs a rig with a projector");
  }
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Plan.

SweepPlanSummary PlanSweep(const fs::path& study_file, const fs::path& jobs_dir) {
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(jobs_dir, ec), jobs_dir.string(),
                    ": exists; sweep plan writes a new folder (remove it or choose another --out)");
  const ConfigNode study = ConfigNode::LoadFile(study_file);
  const fs::path study_dir = fs::absolute(study_file).parent_path();
  study.RejectUnknownKeys({"format", "version", "name", "description", "scene", "rig", "patterns",
                           "modes", "decode", "reconstruct", "compare", "set", "axes", "curves",
                           "effects", "pareto", "vdi2634", "monte_carlo", "whole_part"});
  if (study["format"].AsString() != kStudyFormat)
    study["format"].Fail(std::string("must be ") + kStudyFormat);
  if (study["version"].AsInt() != kVersion) study["version"].Fail("must be 1");
  SweepPlanSummary summary;
  summary.study = study["name"].AsString();
  if (summary.study.empty()) study["name"].Fail("must not be empty");

  // The base job.
  json base = {{"format", kJobFormat}, {"version", kVersion}, {"study", summary.study}};
  {
    const FileValue scene = LoadFileValue("scene", study.GetString("scene", ""), study_dir);
    base["scene"] = scene.tree;
    base["scene_base_dir"] = scene.base_dir;
    base["rig"] = LoadFileValue("rig", study.GetString("rig", ""), study_dir).tree;
    base["patterns"] = LoadFileValue("patterns", study.GetString("patterns", ""), study_dir).tree;
  }
  base["modes"] = json::array({"projector", "stereo"});
  if (study.Has("modes")) {
    const ConfigNode modes = study["modes"];
    base["modes"] = json::array();
    for (size_t i = 0; i < modes.size(); ++i) {
      const std::string m = modes.at(i).AsString();
      try {
        ReconstructModeFromString(m);
      } catch (const Error&) {
        modes.at(i).Fail("unknown mode '" + m + "' (projector | stereo)");
      }
      base["modes"].push_back(m);
    }
    if (base["modes"].empty()) modes.Fail("must list at least one mode");
  }
  // Options through their codecs, so the job holds every field (defaults included).
  base["decode"] = DecodeOptionsToJson(
      study.Has("decode") ? DecodeOptionsFromConfig(study["decode"]) : DecodeOptions{});
  base["reconstruct"] =
      (study.Has("reconstruct") ? ReconstructOptionsFromConfig(study["reconstruct"])
                                : ReconstructOptions{})
          .ToJson();
  base["compare"] = compare::CompareOptionsToJson(
      study.Has("compare") ? compare::CompareOptionsFromConfig(study["compare"])
                           : compare::CompareOptions{});
  // Whole parts (workflows/studies/whole_part.h): every field, defaults included.
  if (study.Has("whole_part")) {
    base["whole_part"] = WholePartOptionsFromConfig(study["whole_part"]).ToJson();
    for (const char* other : {"vdi2634", "monte_carlo", "curves", "effects", "pareto"}) {
      if (study.Has(other)) {
        study[other].Fail(std::string("a whole_part study has no ") + other +
                          " (its merge writes the fronts of scan time against coverage and RMS)");
      }
    }
  }
  std::vector<std::pair<json::json_pointer, json>> set_entries;
  if (study.Has("set")) {
    const ConfigNode set = study["set"];
    for (const std::string& key : set.Keys()) {
      set_entries.emplace_back(SetPath(key, set[key]), set[key].json());
      base[set_entries.back().first] = set_entries.back().second;
    }
  }

  // Axes: the cartesian product, first axis slowest.
  std::vector<Axis> axes;
  if (study.Has("axes")) {
    const ConfigNode list = study["axes"];
    for (size_t a = 0; a < list.size(); ++a) {
      const ConfigNode n = list.at(a);
      n.RejectUnknownKeys({"name", "set", "values", "labels", "range", "files"});
      Axis axis;
      axis.name = n["name"].AsString();
      for (const auto& other : axes) {
        if (other.name == axis.name) n["name"].Fail("axis name '" + axis.name + "' used twice");
      }
      axis.target_text = n["set"].AsString();
      axis.target = SetPath(axis.target_text, n["set"]);
      const int kinds = int(n.Has("values")) + int(n.Has("range")) + int(n.Has("files"));
      if (kinds != 1) n.Fail("needs exactly one of values, range, files");
      if (n.Has("labels") && !n.Has("values")) n["labels"].Fail("labels go with values");
      if (n.Has("values")) {
        for (size_t i = 0; i < n["values"].size(); ++i)
          axis.values.push_back(n["values"].at(i).json());
        axis.labels = axis.values;
        // Names for values that read badly in tables and charts (e.g. mappings of layers).
        if (n.Has("labels")) {
          const ConfigNode labels = n["labels"];
          if (labels.size() != axis.values.size()) {
            labels.Fail("needs one label per value (" + std::to_string(axis.values.size()) + ")");
          }
          // A label is a name, or a number (e.g. an angle for a value that is a rotation vector),
          // which `curves` can then chart against.
          for (size_t i = 0; i < labels.size(); ++i) {
            const ConfigNode label = labels.at(i);
            if (label.json().is_number_float() && !std::isfinite(label.json().get<double>())) {
              label.Fail("a label must be a name or a finite number");
            }
            axis.labels[i] = label.json().is_number() ? label.json() : json(label.AsString());
          }
        }
      } else if (n.Has("range")) {
        const ConfigNode r = n["range"];
        r.RejectUnknownKeys({"first", "count", "step"});
        const int64_t first = r["first"].AsInt(), count = r["count"].AsInt(),
                      step = r.GetInt("step", 1);
        if (count < 1 || count > 1000000) r["count"].Fail("must be in 1..1000000");
        for (int64_t i = 0; i < count; ++i) axis.values.push_back(first + i * step);
        axis.labels = axis.values;
      } else {
        const std::string& t = axis.target_text;
        if (t != "scene" && t != "rig" && t != "patterns") {
          n["set"].Fail("files need set: scene, rig or patterns (got '" + t + "')");
        }
        for (size_t i = 0; i < n["files"].size(); ++i) {
          const std::string file = n["files"].at(i).AsString();
          FileValue v = LoadFileValue(t, file, study_dir);
          axis.values.push_back(v.tree);
          axis.labels.push_back(file);
          axis.base_dirs.push_back(v.base_dir);
        }
      }
      if (axis.values.empty()) n.Fail("axis '" + axis.name + "' has no values");
      summary.axes.push_back(axis.name);
      axes.push_back(std::move(axis));
    }
  }
  const auto study_rig = [&] {
    return RigFromConfig(ConfigNode::FromJson(base["rig"], study_file.string(), "rig"));
  };
  // Study 5 (workflows/studies/vdi2634.h): the artefact placements as the first axis, `position`.
  json vdi2634_plan;
  if (study.Has("vdi2634")) {
    const ConfigNode v = study["vdi2634"];
    for (size_t a = 0; a < axes.size(); ++a) {
      const std::string& t = axes[a].target_text;
      if (axes[a].name == "position" || t == "scene" || t == "rig" || t.rfind("rig.", 0) == 0 ||
          t.rfind("scene.objects", 0) == 0) {
        study["axes"].at(a).Fail(
            "with vdi2634, an axis may not be named position nor set the scene, its objects or "
            "the rig (got '" +
            axes[a].name + "' setting '" + t + "')");
      }
    }
    const Vdi2634Study vdi =
        Vdi2634StudyFromConfig(v, study_rig(), base["modes"].get<std::vector<std::string>>());
    std::vector<KindValue> positions;
    for (const Vdi2634Placement& p : vdi.placements) {
      json scene = base["scene"];  // radiometry and layers of the study's scene
      scene["name"] = "vdi2634_" + p.label;
      scene["objects"] = json::array({p.object});
      positions.push_back({scene,
                           p.label,
                           {{"position", p.label},
                            {"artefact", p.artefact},
                            {"artefacts", p.artefacts},
                            {"options", vdi.options}},
                           base["scene_base_dir"].get<std::string>()});
    }
    PrependKindAxis("position", "scene", "vdi2634", positions, &axes, &summary.axes);
    vdi2634_plan = vdi.ToJson();
  }
  // Study 4 (workflows/studies/montecarlo.h): the Monte Carlo samples as the only axis, `sample`.
  json monte_carlo_plan;
  if (study.Has("monte_carlo")) {
    const ConfigNode mc = study["monte_carlo"];
    if (study.Has("vdi2634")) mc.Fail("a study has at most one of monte_carlo and vdi2634");
    if (!axes.empty()) {
      study["axes"].Fail("a monte_carlo study has no other axes (its jobs are its samples)");
    }
    const MonteCarloStudy m = MonteCarloStudyFromConfig(mc, study_rig());
    std::vector<KindValue> samples;
    for (const json& j : m.jobs) samples.push_back({j.at("noise_seed"), j.at("sample"), j, ""});
    PrependKindAxis("sample", "scene.layers.noise.seed", "monte_carlo", samples, &axes,
                    &summary.axes);
    monte_carlo_plan = m.ToJson();
  }
  if (study.Has("curves")) {
    const ConfigNode c = study["curves"];
    c.RejectUnknownKeys({"x", "limits", "worse"});
    const std::string x = c["x"].AsString();
    if (c.Has("worse") && c["worse"].AsString() != "increasing" &&
        c["worse"].AsString() != "decreasing") {
      c["worse"].Fail(
          "must be 'increasing' (the default: the perturbation grows with x) or 'decreasing'");
    }
    const auto it =
        std::find_if(axes.begin(), axes.end(), [&](const Axis& a) { return a.name == x; });
    if (it == axes.end()) c["x"].Fail("'" + x + "' is not an axis of the study");
    for (const json& v : it->labels) {
      if (!v.is_number())
        c["x"].Fail("axis '" + x + "' has a value that is not a number: " + v.dump());
    }
    if (c.Has("limits")) {
      const ConfigNode limits = c["limits"];
      limits.RejectUnknownKeys(kCurveMetrics);
      for (const std::string& k : limits.Keys()) limits[k].AsDouble();
    }
  }
  if (study.Has("pareto")) {
    const ConfigNode pareto = study["pareto"];
    pareto.RejectUnknownKeys({"by", "time"});
    if (pareto.Has("by")) {
      const std::string name = pareto["by"].AsString();
      if (std::none_of(axes.begin(), axes.end(), [&](const Axis& a) { return a.name == name; })) {
        pareto["by"].Fail("'" + name + "' is not an axis of the study");
      }
    }
    if (pareto.Has("time") && pareto["time"].AsString() != "wall" &&
        pareto["time"].AsString() != "cpu") {
      pareto["time"].Fail("must be 'wall' (the default) or 'cpu'");
    }
  }
  if (study.Has("effects")) {
    const ConfigNode e = study["effects"];
    e.RejectUnknownKeys({"axis", "baseline", "full", "tolerance_mm"});
    const std::string name = e["axis"].AsString();
    const auto it =
        std::find_if(axes.begin(), axes.end(), [&](const Axis& a) { return a.name == name; });
    if (it == axes.end()) e["axis"].Fail("'" + name + "' is not an axis of the study");
    if (std::find(it->labels.begin(), it->labels.end(), e["baseline"].json()) == it->labels.end()) {
      e["baseline"].Fail("is not a value (or label) of axis '" + name + "'");
    }
    if (!(e["tolerance_mm"].AsDouble() >= 0)) e["tolerance_mm"].Fail("must be >= 0");
    if (e.Has("full")) AddOneLayerOffValues(e, &*it);
  }
  size_t total = 1;
  for (const auto& a : axes) total *= a.values.size();
  if (total > 1000000) study["axes"].Fail("more than 1000000 jobs");

  // The jobs, each checked before anything is written.
  std::vector<json> jobs;
  std::set<std::string> seen_scenes, groups;
  for (size_t k = 0; k < total; ++k) {
    json job = base;
    job["id"] = static_cast<int>(k);
    json params = json::object();
    size_t rest = k;
    std::vector<size_t> index(axes.size());
    for (size_t a = axes.size(); a-- > 0;) {
      index[a] = rest % axes[a].values.size();
      rest /= axes[a].values.size();
    }
    for (size_t a = 0; a < axes.size(); ++a) {
      const Axis& axis = axes[a];
      job[axis.target] = axis.values[index[a]];
      if (!axis.base_dirs.empty()) job["scene_base_dir"] = axis.base_dirs[index[a]];
      if (!axis.extras.empty()) job[axis.extra_key] = axis.extras[index[a]];
      params[axis.name] = axis.labels[index[a]];
    }
    // `set` entries under a tree an axis replaced whole (e.g. a scene file) apply to it too,
    // unless an axis sets that path or one under it.
    for (const auto& [path, value] : set_entries) {
      bool replaced = false, set_by_axis = false;
      for (const Axis& axis : axes) {
        const std::string t = axis.target.to_string(), p = path.to_string();
        replaced = replaced ||
                   (p.size() > t.size() && p.compare(0, t.size(), t) == 0 && p[t.size()] == '/');
        set_by_axis = set_by_axis || (t.compare(0, p.size(), p) == 0 &&
                                      (t.size() == p.size() || t[p.size()] == '/'));
      }
      if (replaced && !set_by_axis) job[path] = value;
    }
    job["params"] = params;
    // The spec's derived image count follows what the axes changed (e.g. patterns.phase_steps);
    // the job holds the spec as PatternSpecToJson writes it.
    job["patterns"].erase("num_images");
    job["patterns"] = PatternSpecToJson(PatternSpecFromConfig(ConfigNode::FromJson(
        job["patterns"], study_file.string() + " (job " + JobName(static_cast<int>(k)) + ")",
        "patterns")));
    if (job.contains("whole_part")) {
      // An axis or `set` wrote into it: checked, every field again.
      job["whole_part"] =
          WholePartOptionsFromConfig(ConfigNode::FromJson(job["whole_part"],
                                                          study_file.string() + " (job " +
                                                              JobName(static_cast<int>(k)) + ")",
                                                          "whole_part"))
              .ToJson();
    }
    CheckJob(job, study_file.string() + " (job " + JobName(static_cast<int>(k)) + ")",
             &seen_scenes);
    groups.insert(GeometryKey(job));
    jobs.push_back(std::move(job));
  }
  summary.jobs = static_cast<int>(jobs.size());
  summary.geometry_groups = static_cast<int>(groups.size());

  StagingDirectory staged(jobs_dir);
  const fs::path& staging = staged.path();
  fs::create_directories(staging / "jobs", ec);
  SLSHADOW_THROW_IF(ec, staging.string(), ": cannot create folder: ", ec.message());
  fs::create_directories(staging / "results", ec);
  for (const auto& job : jobs)
    WriteTextFileAtomically(JobFile(staging, job["id"].get<int>()), job.dump(1) + "\n");
  json plan = {{"format", kPlanFormat},
               {"version", kVersion},
               {"study", summary.study},
               {"study_file", fs::absolute(study_file).lexically_normal().string()},
               {"study_config", study.json()},
               {"axes", summary.axes},
               {"jobs", summary.jobs},
               {"geometry_groups", summary.geometry_groups}};
  if (!vdi2634_plan.is_null()) plan["vdi2634"] = vdi2634_plan;
  if (!monte_carlo_plan.is_null()) plan["monte_carlo"] = monte_carlo_plan;
  if (!jobs.empty() && jobs.front().contains("whole_part")) plan["whole_part"] = true;
  WriteTextFileAtomically(staging / "plan.json", plan.dump(2) + "\n");
  staged.Commit(/*overwrite=*/false);
  return summary;
}

// ---------------------------------------------------------------------------------------------
// Run.

void SweepRunOptions::Check() const {
  SLSHADOW_THROW_IF(shard_count < 1, "--shard: the number of shards must be at least 1 (got ",
                    shard_count, ")");
  SLSHADOW_THROW_IF(shard_index < 0 || shard_index >= shard_count, "--shard: index ", shard_index,
                    " is not in 0..", shard_count - 1);
}

void ParseShard(const std::string& text, const std::string& what, SweepRunOptions* options) {
  const Shard shard = slshadow::ParseShard(text, what);
  options->shard_index = shard.index;
  options->shard_count = shard.count;
}

std::string SweepPlanSummary::BriefReport(const fs::path& jobs_dir) const {
  return StringPrintf("study %s: %d job%s (%d geometry group%s) in %s\n", study.c_str(), jobs,
                      jobs == 1 ? "" : "s", geometry_groups, geometry_groups == 1 ? "" : "s",
                      jobs_dir.string().c_str());
}

std::string SweepMergeSummary::FullReport() const {
  const std::string out = out_dir.string();
  std::string text =
      StringPrintf("%d jobs merged: %d rows in %s/results.csv (+ results.json, timings.csv)\n",
                   jobs, rows, out.c_str());
  const auto section = [&text](const std::string& heading, const std::vector<std::string>& lines) {
    text += heading;
    for (const std::string& line : lines) text += "  " + line + "\n";
  };
  if (whole_part) {
    section(StringPrintf("Pareto front of scan time against coverage (%s/pareto.csv, "
                         "time_vs_coverage.png/.svg):\n",
                         out.c_str()),
            coverage_front);
    section(StringPrintf("Pareto front of scan time against merged RMS (%s/pareto.csv, "
                         "time_vs_rms.png/.svg):\n",
                         out.c_str()),
            front);
  } else {
    section(StringPrintf("Pareto front of decode + reconstruct time against RMS (%s/pareto.csv, "
                         "time_vs_rms.png/.svg):\n",
                         out.c_str()),
            front);
  }
  if (!break_points.empty()) {
    section(StringPrintf("Break points (%s/break_points.csv, curves_*.png):\n", out.c_str()),
            break_points);
  }
  if (!effects.empty()) {
    section(
        StringPrintf("Which layers the scene needs (%s/layers.csv, effects.csv):\n", out.c_str()),
        effects);
  }
  if (!acceptance.empty()) {
    section(StringPrintf("VDI/VDE 2634-2 figures, overall (%s/vdi2634_summary.csv, vdi2634.csv, "
                         "vdi2634.png/.svg):\n",
                         out.c_str()),
            acceptance);
  }
  if (!uncertainty.empty()) {
    section(StringPrintf("Scan uncertainty (%s/uncertainty_summary.csv, uncertainty.ply, "
                         "uncertainty.png):\n",
                         out.c_str()),
            uncertainty);
  }
  return text;
}

std::string SweepRunSummary::BriefReport() const {
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "%d jobs in this shard: %d already done, %d run, %d geometry traces, %.2f s",
                assigned, already_done, ran, geometry_traces, wall_s);
  return buf;
}

namespace {

json ReadJob(const fs::path& jobs_dir, int id) {
  const fs::path file = JobFile(jobs_dir, id);
  json job = ReadJsonFile(file);
  SLSHADOW_THROW_IF(
      !job.is_object() || job.value("format", "") != kJobFormat || job.value("id", -1) != id,
      file.string(), ": not sweep job ", id, " (format ", kJobFormat, ")");
  return job;
}

}  // namespace

std::vector<int> ShardJobs(const fs::path& jobs_dir, int shard_index, int shard_count) {
  SweepRunOptions check;
  check.shard_index = shard_index;
  check.shard_count = shard_count;
  check.Check();
  const json plan = ReadPlan(jobs_dir);
  const int n = plan.at("jobs").get<int>();
  // Jobs by geometry group, groups in order of first appearance.
  std::map<std::string, int> group_of_key;
  std::vector<std::pair<int, int>> order;  // (group, id)
  for (int id = 0; id < n; ++id) {
    const std::string key = GeometryKey(ReadJob(jobs_dir, id));
    const auto it = group_of_key.emplace(key, static_cast<int>(group_of_key.size())).first;
    order.emplace_back(it->second, id);
  }
  std::sort(order.begin(), order.end());
  const Shard shard{shard_index, shard_count};
  std::vector<int> ids;
  for (size_t k = shard.Begin(order.size()); k < shard.End(order.size()); ++k)
    ids.push_back(order[k].second);
  return ids;
}

SweepRunSummary RunSweepShard(const fs::path& jobs_dir, const SweepRunOptions& options) {
  options.Check();
#ifdef __GLIBC__
  // Every job allocates and frees the same large buffers (images, maps, grids, clouds of millions
  // of points). glibc would map each from the kernel and unmap it on free, so every job would
  // fault in and zero its pages again (~10 % of a demo job's CPU time): keep freed memory in the
  // heap for the next job instead (the demo noise sweep's peak memory: 2.76 GB, was 2.62 GB).
  // One arena for every thread: a worker thread's own arena holds at most 64 MB per heap, and
  // glibc maps anything larger (a cloud of 2 M points) from the kernel whatever M_MMAP_MAX says
  // (the demo noise sweep: 25 % fewer page faults, half the system time, ~0.1 s wall a job).
  mallopt(M_ARENA_MAX, 1);
  mallopt(M_MMAP_MAX, 0);
  mallopt(M_TRIM_THRESHOLD, std::numeric_limits<int>::max());
#endif
  const auto t0 = std::chrono::steady_clock::now();
  SweepRunSummary summary;
  const std::vector<int> ids = ShardJobs(jobs_dir, options.shard_index, options.shard_count);
  summary.assigned = static_cast<int>(ids.size());
  SweepJobRunner runner;
  // Per job, how many of its geometry group's jobs are still to run (the shard's jobs come group
  // by group): a scorer builds its C2M grid only for enough of them.
  std::vector<int> group_jobs_left(ids.size(), 0);
  {
    std::vector<std::string> keys;
    for (int id : ids) {
      std::error_code ec;
      const bool done = fs::exists(ResultFile(jobs_dir, id), ec);
      keys.push_back(done ? std::string() : GeometryKey(ReadJob(jobs_dir, id)));
    }
    for (size_t k = ids.size(); k-- > 0;) {
      if (keys[k].empty()) continue;
      int left = 1;
      for (size_t j = k + 1; j < ids.size() && left < 64; ++j) left += keys[j] == keys[k];
      group_jobs_left[k] = left;
    }
  }
  size_t position = 0;
  Progress progress("jobs", static_cast<int64_t>(ids.size()), false);  // for an observer only
  for (int id : ids) {
    const int jobs_left = group_jobs_left[position++];
    std::error_code ec;
    const fs::path result_file = ResultFile(jobs_dir, id);
    if (fs::exists(result_file, ec)) {
      ++summary.already_done;
      progress.Advance();
      continue;
    }
    const fs::path file = JobFile(jobs_dir, id);
    const json result = runner.Run(ReadJob(jobs_dir, id), file, jobs_left);
    WriteTextFileAtomically(result_file, result.dump(1) + "\n");
    ++summary.ran;
    progress.Advance();
    if (options.verbose) {
      std::printf("job %s: %s, %.3f s\n", JobName(id).c_str(), result["params"].dump().c_str(),
                  result["timing"]["total_s"].get<double>());
      std::fflush(stdout);
    }
  }
  summary.geometry_traces = runner.geometry_traces();
  summary.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return summary;
}

// ---------------------------------------------------------------------------------------------
// Plan, run and merge.

SweepStudySummary RunStudy(const fs::path& study_file, const fs::path& out_dir,
                           const SweepRunOptions& options,
                           const std::function<void(const SweepStudySummary&)>& planned) {
  options.Check();
  SweepStudySummary summary;
  summary.jobs_dir = out_dir / "jobs";
  std::error_code ec;
  const fs::path plan_file = summary.jobs_dir / "plan.json";
  if (fs::exists(plan_file, ec)) {
    // Resumed: only the jobs without a result run. The plan must be this study's.
    const json plan = ReadPlan(summary.jobs_dir);
    const json study = ConfigNode::LoadFile(study_file).json();
    SLSHADOW_THROW_IF(plan.at("study_config") != study, plan_file.string(),
                      ": planned from another study than ", study_file.string(), " (",
                      plan.value("study_file", std::string("?")),
                      "); remove the folder or choose another --out");
    summary.resumed = true;
  } else {
    summary.plan = PlanSweep(study_file, summary.jobs_dir);
  }
  if (planned) planned(summary);
  summary.run = RunSweepShard(summary.jobs_dir, options);
  summary.merge = MergeSweep(summary.jobs_dir, out_dir);
  return summary;
}

}  // namespace slshadow::studies
