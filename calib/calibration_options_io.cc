// CalibrationOptions as JSON (the evidence's calibration.options; docs/formats.md "Calibration
// evidence"), declared in calib/calibration_io.h.
#include "calib/calibration_io.h"

#include <string>

#include <nlohmann/json.hpp>

#include "core/config.h"
#include "core/error.h"

namespace slshadow {

nlohmann::json CalibrationOptionsToJson(const CalibrationOptions& o) {
  return {{"fix_aspect_ratio", o.fix_aspect_ratio},
          {"aspect_ratio", o.aspect_ratio},
          {"fix_principal_point", o.fix_principal_point},
          {"zero_tangential", o.zero_tangential},
          {"fix_k3", o.fix_k3},
          {"fix_intrinsics", o.fix_intrinsics},
          {"loss", ToString(o.loss)},
          {"loss_scale_px", o.loss_scale_px},
          {"max_iterations", o.max_iterations},
          {"outlier_view_factor", o.outlier_view_factor},
          {"compute_covariance", o.compute_covariance},
          {"estimate_board_warp", o.estimate_board_warp},
          {"correlated_carried_noise", o.correlated_carried_noise},
          {"principal_point_inside", o.principal_point_inside}};
}

CalibrationOptions CalibrationOptionsFromJson(const nlohmann::json& json, const std::string& file) {
  const ConfigNode n = ConfigNode::FromJson(json, file, "calibration.options");
  n.RejectUnknownKeys({"fix_aspect_ratio", "aspect_ratio", "fix_principal_point", "zero_tangential",
                       "fix_k3", "fix_intrinsics", "loss", "loss_scale_px", "max_iterations",
                       "outlier_view_factor", "compute_covariance", "estimate_board_warp",
                       "correlated_carried_noise", "principal_point_inside"});
  CalibrationOptions o;
  o.fix_aspect_ratio = n.GetBool("fix_aspect_ratio", o.fix_aspect_ratio);
  o.aspect_ratio = n.GetDouble("aspect_ratio", o.aspect_ratio);
  o.fix_principal_point = n.GetBool("fix_principal_point", o.fix_principal_point);
  o.zero_tangential = n.GetBool("zero_tangential", o.zero_tangential);
  o.fix_k3 = n.GetBool("fix_k3", o.fix_k3);
  o.fix_intrinsics = n.GetBool("fix_intrinsics", o.fix_intrinsics);
  if (n.Has("loss")) {
    try {
      o.loss = LossTypeFromString(n["loss"].AsString());
    } catch (const Error&) {
      n["loss"].Fail("unknown robust loss (use none, huber or cauchy)");
    }
  }
  o.loss_scale_px = n.GetDouble("loss_scale_px", o.loss_scale_px);
  o.max_iterations = static_cast<int>(n.GetInt("max_iterations", o.max_iterations));
  o.outlier_view_factor = n.GetDouble("outlier_view_factor", o.outlier_view_factor);
  o.compute_covariance = n.GetBool("compute_covariance", o.compute_covariance);
  o.estimate_board_warp = n.GetBool("estimate_board_warp", o.estimate_board_warp);
  o.correlated_carried_noise = n.GetBool("correlated_carried_noise", o.correlated_carried_noise);
  o.principal_point_inside = n.GetBool("principal_point_inside", o.principal_point_inside);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(file, ": ", e.what());
  }
  return o;
}

}  // namespace slshadow
