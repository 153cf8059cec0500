// A virtual multi-view scan: the scene turned to each view's table angle (or placed at a hand
// view's pose) and scanned by the rig with the simulate path every virtual scan takes
// (sim/simulate.h RenderScan, workflows/pipeline/scan_pipeline.h WriteVirtualScan), written as a
// project folder (workflows/multiview/views.h; docs/formats.md "Multi-view project"). Resumable: a
// project interrupted after some views (or with a view folder deleted) is continued by rendering
// the views whose ImageSet is missing; complete ones are kept untouched. Rendering is
// deterministic, so a resumed project's images equal an uninterrupted one's bit for bit.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "sim/scene.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

struct VirtualProjectOptions {
  ImageEncoding encoding = ImageEncoding::kPgm;  // of every view's images (lossless)
  int png_compression = 1;                       // 0..9, for kPng
  // Continue an existing project folder (same rig, patterns, scene and views; refused otherwise).
  // Without it an existing project folder is an error.
  bool resume = false;
  std::vector<std::string> fixed_objects;  // scene objects that do not turn (MoveScene)
  std::string generator = "slshadow simulate --views";  // recorded in the provenance
  // What errors call the rig and the pattern spec (their files); empty: "rig '<name>'" and
  // "pattern spec".
  std::string rig_what, spec_what;
  // Called after each view is written or kept (name, index, rendered): progress for the caller.
  std::function<void(const std::string&, size_t, bool)> on_view;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct VirtualProjectSummary {
  std::vector<std::string> rendered;  // views rendered by this call, in order
  std::vector<std::string> kept;      // views already complete, kept
  double render_seconds = 0;          // ray casting and pattern passes
  double write_seconds = 0;           // encoding and writing the ImageSets
  double total_seconds = 0;
  std::string BriefReport() const;
};

// The true part_from_rig of a view in a virtual project (views.h's part frame): for a table view
// axis.RigFromTableTurn(table_deg).Inverse(), for a hand-placed view its part_from_rig_guess
// (which a virtual scan renders as the truth). Throws slshadow::Error naming the view when it has
// neither, or is on the table and the rig has no axis.
Rigid3d VirtualViewPose(const ViewSpec& view, const Rig& rig);

// The scene as view `view_index` (its position in the views file) of a virtual project renders
// it: `scene` (at commanded angle 0) moved to VirtualViewPose (fixed_objects stay), with the
// sensor noise seed of that view, VirtualViewNoiseSeed: a real camera draws new noise in every
// frame, so each view gets its own draw (one seed would give every view the same noise field).
Scene VirtualViewScene(const Scene& scene, const Rig& rig, const ViewSpec& view, size_t view_index,
                       const std::vector<std::string>& fixed_objects = {});

// The noise seed of view `view_index` of a virtual project whose scene has noise seed
// `scene_seed`: a SplitMix64 hash of both, so two views (and two seeds) draw different noise and
// one seed reproduces every view bit for bit.
uint64_t VirtualViewNoiseSeed(uint64_t scene_seed, size_t view_index);

// Renders every view of `views` that `project_dir` does not hold complete, and writes the project:
// project.json first (all views missing), then each view's ImageSet (views/<name>/, atomically:
// source "virtual", its provenance with `extra.view` = {name, table_deg, part_from_rig_true})
// followed by project.json with that view complete. `scene` is the scene at commanded angle 0;
// `rig` must have a turntable axis when a view is on the table. The project's provenance records
// the scene (config, base_dir, summary), the simulator options, the fixed objects and the
// generator; a resume refuses a project made with another rig, pattern spec, scene summary,
// encoding or views, naming what differs. Throws slshadow::Error on bad input; a view being
// written when an error strikes is left out whole (missing), never half-written.
VirtualProjectSummary SimulateProject(const Scene& scene, const Rig& rig, const PatternSpec& spec,
                                      const ViewsFile& views,
                                      const std::filesystem::path& project_dir,
                                      const VirtualProjectOptions& options = {});

}  // namespace slshadow::multiview
