#include "workflows/multiview/virtual_project.h"

#include <chrono>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/pose_io.h"
#include "core/provenance.h"
#include "core/string_printf.h"
#include "patterns/codec.h"
#include "patterns/simulator_projector.h"
#include "sim/simulate.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

double SecondsSince(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

SimulateOptions ViewSimulateOptions(const VirtualProjectOptions& options) {
  SimulateOptions s;
  s.writer.encoding = options.encoding;
  s.writer.png_compression = options.png_compression;
  s.write_ground_truth = false;
  return s;
}

nlohmann::json ProjectProvenance(const Scene& scene, const VirtualProjectOptions& options) {
  return {{"generator", options.generator},
          {"scene",
           {{"config", scene.source_config},
            {"base_dir", scene.source_dir.string()},
            {"summary", SceneToJson(scene)}}},
          {"simulate", SimulateOptionsToJson(ViewSimulateOptions(options))},
          {"fixed_objects", options.fixed_objects}};
}

// Why an existing project cannot be resumed with these inputs, or empty.
std::string ResumeMismatch(const ProjectManifest& project, const Rig& rig,
                           const nlohmann::json& patterns, const ViewsFile& views,
                           const nlohmann::json& provenance) {
  const std::string inputs = ProjectInputsMismatch(project, rig, patterns, views);
  if (!inputs.empty()) return inputs;
  for (const char* key : {"scene", "simulate", "fixed_objects"}) {
    if (!project.provenance.contains(key) || project.provenance[key] != provenance[key])
      return std::string("provenance.") + key;
  }
  return "";
}

}  // namespace

void VirtualProjectOptions::Check() const {
  SLSHADOW_THROW_IF(png_compression < 0 || png_compression > 9,
                    "virtual project: png_compression must be in 0..9 (got ", png_compression, ")");
  SLSHADOW_THROW_IF(generator.empty(), "virtual project: generator must not be empty");
}

std::string VirtualProjectSummary::BriefReport() const {
  return StringPrintf(
      "views rendered %zu, kept %zu; render %.2f s, write %.2f s, total %.2f s wall",
      rendered.size(), kept.size(), render_seconds, write_seconds, total_seconds);
}

Rigid3d VirtualViewPose(const ViewSpec& view, const Rig& rig) {
  if (view.OnTable()) {
    SLSHADOW_THROW_IF(!rig.turntable, "view '", view.name, "': table_deg ", *view.table_deg,
                      ", but rig '", rig.name, "' has no turntable axis (rig.turntable)");
    return rig.turntable->RigFromTableTurn(*view.table_deg).Inverse();
  }
  SLSHADOW_THROW_IF(
      !view.part_from_rig_guess, "view '", view.name,
      "': a view placed by hand needs part_from_rig_guess in a virtual scan (the pose "
      "the part is rendered at)");
  return *view.part_from_rig_guess;
}

uint64_t VirtualViewNoiseSeed(uint64_t scene_seed, size_t view_index) {
  auto mix = [](uint64_t x) {  // SplitMix64
    x += 0x9E3779B97F4A7C15ull;
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
    return x ^ (x >> 31);
  };
  return mix(scene_seed ^ mix(0x766965770000ull + static_cast<uint64_t>(view_index)));
}

Scene VirtualViewScene(const Scene& scene, const Rig& rig, const ViewSpec& view, size_t view_index,
                       const std::vector<std::string>& fixed_objects) {
  Scene placed = MoveScene(scene, VirtualViewPose(view, rig).Inverse(), fixed_objects);
  placed.layers.seed = VirtualViewNoiseSeed(scene.layers.seed, view_index);
  return placed;
}

VirtualProjectSummary SimulateProject(const Scene& scene, const Rig& rig, const PatternSpec& spec,
                                      const ViewsFile& views, const fs::path& project_dir,
                                      const VirtualProjectOptions& options) {
  const auto t_start = std::chrono::steady_clock::now();
  options.Check();
  views.Check("views");
  scene.Check("scene '" + scene.name + "'");
  rig.Check("rig '" + rig.name + "'");
  const std::string rig_what =
      options.rig_what.empty() ? "rig '" + rig.name + "'" : options.rig_what;
  CheckSimulatorProjector(rig, spec, options.spec_what.empty() ? "pattern spec" : options.spec_what,
                          rig_what);
  for (const ViewSpec& v : views.views) VirtualViewPose(v, rig);  // every view has a pose

  const nlohmann::json patterns = PatternSpecToJson(spec);
  const nlohmann::json provenance = ProjectProvenance(scene, options);
  std::error_code ec;
  // A complete view whose folder was lost since is rendered again below.
  StartedProject started =
      StartOrResumeProject(project_dir, rig, patterns, views, provenance, options.resume,
                           "render its missing views", [&](const ProjectManifest& stored) {
                             return ResumeMismatch(stored, rig, patterns, views, provenance);
                           });
  ProjectManifest& project = started.manifest;

  VirtualProjectSummary summary;
  const SimulateOptions simulate = ViewSimulateOptions(options);
  std::vector<cv::Mat> projector_images;  // generated when the first view needs them
  // A view whose ImageSet is on disk: complete in the manifest, which is saved at once.
  const auto mark_complete = [&](ProjectView& view, const fs::path& dir) {
    view.state = ViewState::kComplete;
    view.source = "virtual";
    view.completed = ImageSet::Open(dir).created();
    SaveProject(project, project_dir);
  };
  for (size_t i = 0; i < project.views.size(); ++i) {
    ProjectView& view = project.views[i];
    const fs::path dir = project_dir / view.Folder();
    if (fs::exists(dir / "manifest.json", ec)) {
      // Kept: complete on disk (also when an interruption struck between the ImageSet's commit
      // and the manifest's update).
      if (view.state != ViewState::kComplete) mark_complete(view, dir);
      summary.kept.push_back(view.spec.name);
      if (options.on_view) options.on_view(view.spec.name, i, false);
      continue;
    }
    if (view.state == ViewState::kComplete) {  // its folder was removed: render it again
      view.state = ViewState::kMissing;
      SaveProject(project, project_dir);
    }
    if (projector_images.empty()) projector_images = GeneratePatterns(spec);
    const Rigid3d part_from_rig = VirtualViewPose(view.spec, rig);
    const Scene placed = VirtualViewScene(scene, rig, view.spec, i, options.fixed_objects);
    auto t0 = std::chrono::steady_clock::now();
    std::vector<std::vector<cv::Mat>> images = RenderScan(placed, rig, projector_images);
    summary.render_seconds += SecondsSince(t0);
    t0 = std::chrono::steady_clock::now();
    ScanProvenance scan_provenance = VirtualScanProvenance(placed, simulate, options.generator);
    nlohmann::json extra = ExtraWithProvenance(scan_provenance);
    extra["view"] = {{"name", view.spec.name},
                     {"table_deg", view.spec.table_deg ? nlohmann::json(*view.spec.table_deg)
                                                       : nlohmann::json(nullptr)},
                     {"part_from_rig_true", PoseToJson(part_from_rig)}};
    pipeline::WriteVirtualScan(dir, rig, spec, placed, images, simulate.writer, extra);
    summary.write_seconds += SecondsSince(t0);
    images.clear();
    mark_complete(view, dir);
    summary.rendered.push_back(view.spec.name);
    if (options.on_view) options.on_view(view.spec.name, i, true);
  }
  ReleaseSimulatorPool();
  summary.total_seconds = SecondsSince(t_start);
  return summary;
}

}  // namespace slshadow::multiview
