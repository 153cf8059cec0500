// A pose as a merge report writes it (docs/formats.md, `rotation_quat_wxyz`, `translation_mm`),
// for the bench tools that read report.json.
#pragma once

#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include "core/rigid3.h"

namespace slshadow::bench {

inline Rigid3d ReportPose(const nlohmann::json& j) {
  const auto& q = j.at("rotation_quat_wxyz");
  const auto& t = j.at("translation_mm");
  return Rigid3d(Eigen::Quaterniond(q[0].get<double>(), q[1].get<double>(), q[2].get<double>(),
                                    q[3].get<double>())
                     .normalized(),
                 Eigen::Vector3d(t[0].get<double>(), t[1].get<double>(), t[2].get<double>()));
}

}  // namespace slshadow::bench
