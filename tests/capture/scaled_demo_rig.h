// The demo rig at 1/scale of its resolution (same optics, coarser pixels), so that closed-loop
// tests run in seconds: cameras 1920x1200 -> 480x300, projector 1280x800 -> 320x200 at scale 4.
#pragma once

#include <filesystem>

#include "core/rig.h"

namespace slshadow::testing {

inline Rig ScaledDemoRig(int scale) {
  Rig rig = LoadRig(std::filesystem::path(SLSHADOW_SOURCE_DIR) / "config/demo/rig.yaml");
  auto shrink = [scale](CameraModel& m) {
    m.width /= scale;
    m.height /= scale;
    m.params[CameraModel::kFx] /= scale;
    m.params[CameraModel::kFy] /= scale;
    m.params[CameraModel::kCx] = (m.params[CameraModel::kCx] + 0.5) / scale - 0.5;
    m.params[CameraModel::kCy] = (m.params[CameraModel::kCy] + 0.5) / scale - 0.5;
  };
  for (RigDevice& c : rig.cameras) shrink(c.model);
  shrink(rig.projector->model);
  rig.Check("scaled demo rig");
  return rig;
}

}  // namespace slshadow::testing
