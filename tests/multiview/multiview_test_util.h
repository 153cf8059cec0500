// The demo on its turntable at 1/scale of the demo rig's resolution (tests/capture's
// ScaledDemoRig: same optics, coarser pixels), with the demo's pattern sequence resized to the
// scaled projector, so multi-view tests render and reconstruct a view in a fraction of a second.
#pragma once

#include <filesystem>

#include "core/mesh.h"
#include "patterns/pattern_spec.h"
#include "tests/capture/scaled_demo_rig.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/views.h"
#include "workflows/multiview/virtual_project.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::testing {

inline multiview::TurntableSetup ScaledTurntableDemo(int scale) {
  multiview::TurntableSetup setup = multiview::DemoTurntableSetup();
  const std::optional<TurntableAxis> axis = setup.rig.turntable;
  setup.rig = ScaledDemoRig(scale);
  setup.rig.turntable = axis;
  return setup;
}

inline PatternSpec ScaledDemoPatterns(const Rig& rig) {
  PatternSpec spec = pipeline::LoadPatternSpecOrDemo("");
  spec.projector_width = rig.projector->model.width;
  spec.projector_height = rig.projector->model.height;
  spec.Check();
  return spec;
}

// The demo part's turntable project at 1/4 of the demo rig's resolution, `views` views a full
// turn apart from start_deg (FullTurnViews), simulated into dir / "project", and the part's CAD
// surface written to dir / "cad.ply".
inline void WriteQuarterDemoProject(const std::filesystem::path& dir, int views, double start_deg) {
  const multiview::TurntableSetup setup = ScaledTurntableDemo(4);
  WriteMesh(dir / "cad.ply", multiview::PartSurface(setup.scene));
  multiview::SimulateProject(setup.scene, setup.rig, ScaledDemoPatterns(setup.rig),
                             multiview::FullTurnViews(views, start_deg), dir / "project");
}

}  // namespace slshadow::testing
