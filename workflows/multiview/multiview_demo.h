// `slshadow demo --views N`: the whole-part loop on the embedded demo. The demo part stands on a
// turntable in the demo rig (turntable_scene.h DemoTurntableSetup: the axis is the part's table
// normal through the centre of its footprint), N views evenly spaced over a full turn are scanned
// virtually into a project (virtual_project.h), merged (project_merge.h) and compared with the
// part's CAD model: coverage of its reachable surface, C2M RMS merged and per view, the poses'
// errors against the truth.
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include "core/rig.h"
#include "sim/scene.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {

struct MultiviewDemoOptions {
  int views = 12;
  double start_deg = 0;
  // OUT/project (the virtual multi-view scan), OUT/model (the merge's model folder, WriteModel),
  // OUT/cad.ply (the CAD mesh, part frame), OUT/multiview_demo.json (figures). Replaced only when
  // it holds an earlier multi-view demo output.
  std::filesystem::path out_dir = "slshadow-demo-views";
  ImageEncoding encoding = ImageEncoding::kPgm;
  ProjectMergeOptions merge;
  // The simulator's sensor noise (sim/scene.h SceneLayers: shot and read noise) in every view.
  bool sensor_noise = false;
  // The seed of that noise (sim/scene.h SceneLayers::seed): another seed, another draw.
  uint64_t noise_seed = 1;
  // Replace the embedded demo rig and scene (e.g. a scaled-down rig in tests); the scene is at
  // table angle 0 with its disc and the rig has its turntable axis (TurntableSetup). The demo's
  // pattern sequence is sized to the rig's projector.
  std::optional<Rig> rig;
  std::optional<Scene> scene;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct MultiviewDemoResult {
  VirtualProjectSummary scan;
  ProjectMergeResult merge;
  double single_view_rms_mm = 0;  // median over the views of each view's own C2M RMS
  double total_seconds = 0;
  std::filesystem::path out_dir;
  nlohmann::json ToJson() const;
  std::string Table() const;  // what the command prints
};

MultiviewDemoResult RunMultiviewDemo(const MultiviewDemoOptions& options);

}  // namespace slshadow::multiview
