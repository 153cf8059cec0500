#include "workflows/studies/internal/sweep_job.h"

#include "compare/compare.h"
#include "core/config.h"
#include "core/error.h"
#include "core/stage_meter.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/studies/internal/sweep_files.h"
#include "workflows/studies/montecarlo.h"
#include "workflows/studies/sweep_reuse.h"
#include "workflows/studies/whole_part.h"

#include <tbb/parallel_for.h>

#include <algorithm>
#include <chrono>
#include <vector>

namespace slshadow::studies::internal {
namespace fs = std::filesystem;
using nlohmann::json;

// The geometry group of a job: what the Simulator's geometry buffers depend on.
std::string GeometryKey(const json& job) {
  json scene = job.at("scene");
  scene.erase("radiometry");
  scene.erase("name");
  if (scene.contains("layers") && scene["layers"].is_object()) {
    json kept = json::object();
    for (const char* k : {"supersampling", "projector_defocus"}) {
      if (scene["layers"].contains(k)) kept[k] = scene["layers"][k];
    }
    scene["layers"] = kept;
  }
  return json{{"scene", scene}, {"base_dir", job.at("scene_base_dir")}, {"rig", job.at("rig")}}
      .dump();
}

// What a geometry group keeps for its jobs (workflows/studies/sweep_reuse.h).
struct SweepJobRunner::Group {
  std::string key;
  Scene scene;  // the first job's scene (geometry of all)
  Rig rig;
  std::unique_ptr<Simulator> simulator;
  std::unique_ptr<GroundTruthScorer> scorer;
  // The noise-free images of the last noisy job's patterns and noise-free scene, and the image
  // buffers every job renders into.
  std::string noise_free_key;
  std::unique_ptr<NoiseFreeImages> noise_free;
  std::vector<std::vector<cv::Mat>> images;
  // CPU seconds (all threads) of the geometry pass (the Simulator) and of the noise-free images:
  // what a job reusing them would have paid itself (its timing's model_cpu_s).
  double geometry_cpu_s = 0, noise_free_cpu_s = 0;
};

SweepJobRunner::SweepJobRunner() = default;
SweepJobRunner::~SweepJobRunner() = default;

json SweepJobRunner::Run(const json& job, const fs::path& file, int group_jobs_left) {
  // A whole-part job: a multi-view project rendered, merged and compared (whole_part.h); it
  // shares nothing with the jobs before it.
  if (job.contains("whole_part")) {
    group_.reset();
    return RunWholePartJob(job, file);
  }
  std::unique_ptr<Group>& group = group_;
  const std::string what = file.string();
  const auto node = [&](const char* key) { return ConfigNode::FromJson(job.at(key), what, key); };
  const std::string key = GeometryKey(job);
  const auto clock = [] { return std::chrono::steady_clock::now(); };
  const auto seconds = [](auto a, auto b) { return std::chrono::duration<double>(b - a).count(); };
  json timing = json::object();
  const double cpu0 = ProcessCpuSeconds();
  const auto t0 = clock();
  // CPU seconds of the process (every thread) since the previous stage ended.
  double cpu_mark = cpu0;
  const auto stage_cpu = [&](const char* name) {
    const double now = ProcessCpuSeconds();
    timing[name] = now - cpu_mark;
    cpu_mark = now;
  };

  Scene scene = SceneFromConfig(node("scene"), job.at("scene_base_dir").get<std::string>());
  if (!group || group->key != key) {
    group.reset();
    auto g = std::make_unique<Group>();
    g->key = key;
    g->scene = scene;
    g->rig = RigFromConfig(node("rig"));
    const double cg = ProcessCpuSeconds();
    g->simulator = std::make_unique<Simulator>(g->scene, g->rig);
    g->geometry_cpu_s = ProcessCpuSeconds() - cg;
    g->scorer = std::make_unique<GroundTruthScorer>(GroundTruthSurface(g->scene, what + ": scene"),
                                                    LitVisibleSurface(g->simulator->geometry(0)),
                                                    "scene ground truth");
    group = std::move(g);
    ++traces_;
  }
  const auto t1 = clock();
  timing["setup_s"] = seconds(t0, t1);
  stage_cpu("setup_cpu_s");

  const PatternSpec spec = PatternSpecFromConfig(node("patterns"));
  const double c1 = ProcessCpuSeconds();
  if (scene.layers.noise_enabled) {
    // Noise per seed on the noise-free images rendered once (bit for bit Simulator::Render's).
    const std::string images_key = NoiseFreeImages::Key(job.at("scene"), job.at("patterns"));
    if (!group->noise_free || group->noise_free_key != images_key) {
      group->noise_free.reset();
      group->noise_free = std::make_unique<NoiseFreeImages>(*group->simulator, scene, group->rig,
                                                            GeneratePatterns(spec));
      group->noise_free_key = images_key;
      group->noise_free_cpu_s = ProcessCpuSeconds() - c1;
    }
    const double cn = ProcessCpuSeconds();
    group->noise_free->Render(scene, &group->images);
    timing["model_cpu_s"] =
        group->geometry_cpu_s + group->noise_free_cpu_s + (ProcessCpuSeconds() - cn);
  } else {
    group->images = group->simulator->Render(GeneratePatterns(spec), &scene);
    timing["model_cpu_s"] = group->geometry_cpu_s + (ProcessCpuSeconds() - c1);
  }
  const std::vector<std::vector<cv::Mat>>& images = group->images;
  const auto t2 = clock();
  timing["render_s"] = seconds(t1, t2);
  stage_cpu("render_cpu_s");

  std::vector<ReconstructMode> modes;
  for (const auto& m : job.at("modes"))
    modes.push_back(ReconstructModeFromString(m.get<std::string>()));
  const bool stereo =
      std::find(modes.begin(), modes.end(), ReconstructMode::kStereo) != modes.end();
  const DecodeOptions decode = DecodeOptionsFromConfig(node("decode"));
  pipeline::DecodedScan decoded;
  // Study 4: scanned with the true rig, decoded and reconstructed with a sampled calibration.
  decoded.rig = group->rig;
  if (job.contains("monte_carlo")) {
    decoded.rig = RigFromConfig(ConfigNode::FromJson(job.at("monte_carlo").at("reconstruct_rig"),
                                                     what, "monte_carlo.reconstruct_rig"));
  }
  decoded.spec = spec;
  std::vector<double> decode_camera_s, decode_camera_cpu_s;
  for (size_t c = 0; c < (stereo ? 2u : 1u); ++c) {
    const auto tc = clock();
    const double cc = ProcessCpuSeconds();
    decoded.cameras.push_back(group->rig.cameras[c].name);
    decoded.maps.push_back(DecodePatterns(spec, images[c], decode));
    decode_camera_s.push_back(seconds(tc, clock()));
    decode_camera_cpu_s.push_back(ProcessCpuSeconds() - cc);
  }
  const auto t3 = clock();
  timing["decode_s"] = seconds(t2, t3);
  stage_cpu("decode_cpu_s");

  ReconstructOptions reconstruct = ReconstructOptionsFromConfig(node("reconstruct"));
  // Nothing in a job reads the clouds' normals (the signed distances take the reference mesh's,
  // registration and M3C2 the reference's or their own), nor the summary's residual statistics
  // and calibration check: no method pays for them.
  reconstruct.estimate_normals = false;
  reconstruct.report_residuals = false;
  std::vector<StageMeasurement> stages;
  std::vector<Reconstruction> recs =
      pipeline::ReconstructModes(decoded, modes, reconstruct, &stages);
  json monte_carlo;
  if (job.contains("monte_carlo")) {
    // The first mode's grid, next to the result (written first: a job without its result reruns).
    const Reconstruction& first = recs.at(0);
    const fs::path jobs_dir = file.parent_path().parent_path();
    WriteMonteCarloGrid(MonteCarloGridFile(jobs_dir, job.at("id").get<int>()), first.grid);
    const Eigen::Vector3d& v = first.grid.viewpoint_in_rig;
    monte_carlo = {{"sample", job.at("monte_carlo").at("sample")},
                   {"set", job.at("monte_carlo").at("set")},
                   {"viewpoint_in_rig_mm", {v.x(), v.y(), v.z()}}};
  }
  const auto t4 = clock();
  timing["reconstruct_s"] = seconds(t3, t4);
  stage_cpu("reconstruct_cpu_s");
  // Per mode, what the method costs: decoding the cameras it reads, then its reconstruction.
  json method_s = json::object(), method_cpu_s = json::object();
  for (size_t k = 0; k < modes.size() && k < stages.size(); ++k) {
    const bool two = modes[k] == ReconstructMode::kStereo;
    method_s[ToString(modes[k])] =
        decode_camera_s[0] + (two ? decode_camera_s[1] : 0.0) + stages[k].wall_s;
    method_cpu_s[ToString(modes[k])] =
        decode_camera_cpu_s[0] + (two ? decode_camera_cpu_s[1] : 0.0) + stages[k].cpu_s;
  }
  timing["method_s"] = method_s;
  timing["method_cpu_s"] = method_cpu_s;

  const compare::CompareOptions compare_options =
      compare::CompareOptionsFromConfig(node("compare"));
  // The modes' measurements are independent and partly serial: run them side by side.
  std::vector<pipeline::ModeAccuracy> measured(modes.size());
  std::vector<const PointCloud*> clouds;
  for (const Reconstruction& r : recs) clouds.push_back(&r.cloud);
  group->scorer->Prepare(clouds, group_jobs_left);
  // A method that reconstructs nothing (it broke) has no error figures: null, and coverage 0.
  tbb::parallel_for(size_t{0}, modes.size(), [&](size_t k) {
    measured[k].mode = ToString(modes[k]);
    if (recs[k].cloud.empty()) return;
    measured[k] = group->scorer->Measure(recs[k].cloud, compare_options, ToString(modes[k]));
  });
  json accuracy = json::array();
  for (const pipeline::ModeAccuracy& m : measured) {
    json a = pipeline::ModeAccuracyToJson(m);
    if (m.points == 0) {
      for (const char* k : {"mean_mm", "rms_mm", "p95_mm", "max_mm", "outlier_fraction"})
        a[k] = nullptr;
    }
    accuracy.push_back(a);
  }
  // Study 5: the VDI/VDE 2634-2 figures of the job's artefact in each mode (null: no cloud).
  if (job.contains("vdi2634")) {
    const json& v = job.at("vdi2634");
    const compare::ArtefactSpec artefacts = compare::ArtefactSpecFromConfig(
        ConfigNode::FromJson(v.at("artefacts"), what, "vdi2634.artefacts"));
    const compare::Vdi2634Options options = compare::Vdi2634OptionsFromConfig(
        ConfigNode::FromJson(v.at("options"), what, "vdi2634.options"));
    for (size_t k = 0; k < modes.size(); ++k) {
      accuracy[k]["vdi2634"] =
          recs[k].cloud.empty()
              ? json()
              : compare::EvaluateVdi2634(recs[k].cloud, artefacts, options).ToJson();
    }
  }
  const auto t5 = clock();
  timing["compare_s"] = seconds(t4, t5);
  stage_cpu("compare_cpu_s");
  timing["total_s"] = seconds(t0, t5);
  timing["cpu_s"] = ProcessCpuSeconds() - cpu0;
  json result = {{"format", kResultFormat},    {"version", kVersion}, {"id", job.at("id")},
                 {"params", job.at("params")}, {"modes", accuracy},   {"timing", timing}};
  if (!monte_carlo.is_null()) result["monte_carlo"] = monte_carlo;
  return result;
}

}  // namespace slshadow::studies::internal
