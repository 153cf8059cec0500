// Poses in the project's files (docs/formats.md "Rig YAML": the rig's device poses, the views
// file's pose guesses, the multi-view project): read from `translation_mm` and exactly one of
// `rotation_quat_wxyz` (unit norm within 1e-6, renormalised), `rotation_rvec_rad` (Rodrigues, as
// OpenCV's rvec) or `rotation_matrix` (row-major, orthonormal within 1e-5, det +1); written as
// `rotation_quat_wxyz` and `translation_mm`. A bad node throws slshadow::Error naming the file
// and the field.
#pragma once

#include <nlohmann/json.hpp>

#include "core/rigid3.h"

namespace slshadow {

class ConfigNode;

Rigid3d PoseFromConfig(const ConfigNode& node);
nlohmann::json PoseToJson(const Rigid3d& pose);

}  // namespace slshadow
