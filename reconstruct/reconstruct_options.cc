#include "reconstruct/reconstruct.h"

#include <cmath>
#include <limits>

#include "core/config.h"
#include "core/enum_names.h"
#include "core/error.h"

namespace slshadow {

constexpr EnumName<ReconstructMode> kReconstructModeNames[] = {
    {ReconstructMode::kProjector, "projector"}, {ReconstructMode::kStereo, "stereo"}};

std::string ToString(ReconstructMode value) { return EnumToString(value, kReconstructModeNames); }

constexpr EnumName<StereoInterpolation> kStereoInterpolationNames[] = {
    {StereoInterpolation::kAuto, "auto"},
    {StereoInterpolation::kLinear, "linear"},
    {StereoInterpolation::kCubic, "cubic"}};

std::string ToString(StereoInterpolation value) {
  return EnumToString(value, kStereoInterpolationNames);
}

StereoInterpolation StereoInterpolationFromString(const std::string& name) {
  return EnumFromString("stereo interpolation", name, kStereoInterpolationNames);
}

ReconstructMode ReconstructModeFromString(const std::string& name) {
  return EnumFromString("reconstruct mode", name, kReconstructModeNames);
}

void ReconstructOptions::Check() const {
  auto fail = [](const std::string& field, const std::string& rule, double value) {
    SLSHADOW_THROW("reconstruct options: ", field, ": ", rule, " (got ", value, ")");
  };
  if (!(reference_noise_ratio > 0) || !std::isfinite(reference_noise_ratio))
    fail("reference_noise_ratio", "must be finite and positive", reference_noise_ratio);
  if (!(min_depth_mm > 0)) fail("min_depth_mm", "must be positive", min_depth_mm);
  if (!(max_depth_mm > min_depth_mm))
    fail("max_depth_mm", "must exceed min_depth_mm", max_depth_mm);
  if (!(min_triangulation_angle_deg >= 0 && min_triangulation_angle_deg < 90))
    fail("min_triangulation_angle_deg", "must be in [0, 90)", min_triangulation_angle_deg);
  if (!(max_reprojection_error_px > 0))
    fail("max_reprojection_error_px", "must be positive", max_reprojection_error_px);
  if (!(max_epipolar_error_px > 0))
    fail("max_epipolar_error_px", "must be positive", max_epipolar_error_px);
  if (!(min_quality >= 0) || !std::isfinite(min_quality))
    fail("min_quality", "must be finite and >= 0", min_quality);
  if (!(max_code_step_px >= 0) || !std::isfinite(max_code_step_px))
    fail("max_code_step_px", "must be finite and positive, or 0 (auto)", max_code_step_px);
  if (!(max_code_step_ratio == 0 || max_code_step_ratio > 1) || !std::isfinite(max_code_step_ratio))
    fail("max_code_step_ratio", "must be finite and > 1, or 0 (off)", max_code_step_ratio);
  if (!(max_depth_jump_footprints > 0))
    fail("max_depth_jump_footprints", "must be positive", max_depth_jump_footprints);
  if (discontinuity_dilation_px < 0 || discontinuity_dilation_px > 16)
    fail("discontinuity_dilation_px", "must be in [0, 16]", discontinuity_dilation_px);
  if (outlier_window_radius_px < 1 || outlier_window_radius_px > 5)
    fail("outlier_window_radius_px", "must be in [1, 5]", outlier_window_radius_px);
  if (outlier_neighbors < 1 ||
      outlier_neighbors >
          (2 * outlier_window_radius_px + 1) * (2 * outlier_window_radius_px + 1) - 1)
    fail("outlier_neighbors", "must be in [1, (2 r + 1)^2 - 1] for the window radius r",
         outlier_neighbors);
  if (!(outlier_std_ratio > 0) || !std::isfinite(outlier_std_ratio))
    fail("outlier_std_ratio", "must be finite and positive", outlier_std_ratio);
  if (!(outlier_min_distance_footprints >= 0) || !std::isfinite(outlier_min_distance_footprints))
    fail("outlier_min_distance_footprints", "must be finite and >= 0",
         outlier_min_distance_footprints);
  if (!(calibration_warning_px >= 0))
    fail("calibration_warning_px", "must be >= 0 (0: automatic)", calibration_warning_px);
  if (!(calibration_noise_factor > 0) || !std::isfinite(calibration_noise_factor))
    fail("calibration_noise_factor", "must be finite and positive", calibration_noise_factor);
  if (!(calibration_min_warning_px >= 0) || !std::isfinite(calibration_min_warning_px))
    fail("calibration_min_warning_px", "must be finite and >= 0", calibration_min_warning_px);
}

nlohmann::json ReconstructOptions::ToJson() const {
  auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json("inf"); };
  return {{"method", ToString(method)},
          {"reference_noise_ratio", reference_noise_ratio},
          {"min_depth_mm", min_depth_mm},
          {"max_depth_mm", max_depth_mm},
          {"min_triangulation_angle_deg", min_triangulation_angle_deg},
          {"max_reprojection_error_px", num(max_reprojection_error_px)},
          {"max_epipolar_error_px", num(max_epipolar_error_px)},
          {"min_quality", min_quality},
          {"max_code_step_px",
           max_code_step_px > 0 ? nlohmann::json(max_code_step_px) : nlohmann::json("auto")},
          {"max_code_step_ratio", max_code_step_ratio},
          {"stereo_interpolation", ToString(stereo_interpolation)},
          {"filter_depth_discontinuities", filter_depth_discontinuities},
          {"max_depth_jump_footprints", max_depth_jump_footprints},
          {"discontinuity_dilation_px", discontinuity_dilation_px},
          {"filter_outliers", filter_outliers},
          {"outlier_window_radius_px", outlier_window_radius_px},
          {"outlier_neighbors", outlier_neighbors},
          {"outlier_std_ratio", outlier_std_ratio},
          {"outlier_min_distance_footprints", outlier_min_distance_footprints},
          {"estimate_normals", estimate_normals},
          {"report_residuals", report_residuals},
          {"calibration_warning_px", num(calibration_warning_px)},
          {"calibration_noise_factor", calibration_noise_factor},
          {"calibration_min_warning_px", calibration_min_warning_px}};
}

namespace {

// A number, or "inf" / absent (then `fallback`) for gates that infinity disables.
double GetDoubleOrInf(const ConfigNode& node, const std::string& key, double fallback) {
  if (!node.Has(key)) return fallback;
  const ConfigNode n = node[key];
  if (n.json().is_string()) {
    if (n.AsString() == "inf") return std::numeric_limits<double>::infinity();
    n.Fail("expected a number or \"inf\"");
  }
  return n.AsDouble();
}

template <typename Parse>
auto ParseEnum(const ConfigNode& node, Parse parse) {
  try {
    return parse(node.AsString());
  } catch (const Error& e) {
    node.Fail(e.what());
  }
}

}  // namespace

ReconstructOptions ReconstructOptionsFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a mapping of reconstruct options");
  node.RejectUnknownKeys({"method",
                          "reference_noise_ratio",
                          "min_depth_mm",
                          "max_depth_mm",
                          "min_triangulation_angle_deg",
                          "max_reprojection_error_px",
                          "max_epipolar_error_px",
                          "min_quality",
                          "max_code_step_px",
                          "max_code_step_ratio",
                          "stereo_interpolation",
                          "filter_depth_discontinuities",
                          "max_depth_jump_footprints",
                          "discontinuity_dilation_px",
                          "filter_outliers",
                          "outlier_window_radius_px",
                          "outlier_neighbors",
                          "outlier_std_ratio",
                          "outlier_min_distance_footprints",
                          "estimate_normals",
                          "report_residuals",
                          "calibration_warning_px",
                          "calibration_noise_factor",
                          "calibration_min_warning_px"});
  ReconstructOptions o;
  if (node.Has("method")) {
    o.method = ParseEnum(node["method"],
                         [](const std::string& s) { return TriangulationMethodFromString(s); });
  }
  o.reference_noise_ratio = node.GetDouble("reference_noise_ratio", o.reference_noise_ratio);
  o.min_depth_mm = node.GetDouble("min_depth_mm", o.min_depth_mm);
  o.max_depth_mm = node.GetDouble("max_depth_mm", o.max_depth_mm);
  o.min_triangulation_angle_deg =
      node.GetDouble("min_triangulation_angle_deg", o.min_triangulation_angle_deg);
  o.max_reprojection_error_px =
      GetDoubleOrInf(node, "max_reprojection_error_px", o.max_reprojection_error_px);
  o.max_epipolar_error_px = GetDoubleOrInf(node, "max_epipolar_error_px", o.max_epipolar_error_px);
  o.min_quality = static_cast<float>(node.GetDouble("min_quality", o.min_quality));
  if (node.Has("max_code_step_px") && node["max_code_step_px"].json().is_string()) {
    const ConfigNode n = node["max_code_step_px"];
    if (n.AsString() != "auto") n.Fail("expected a number of projector px or \"auto\"");
    o.max_code_step_px = 0;
  } else {
    o.max_code_step_px = node.GetDouble("max_code_step_px", o.max_code_step_px);
  }
  o.max_code_step_ratio = node.GetDouble("max_code_step_ratio", o.max_code_step_ratio);
  if (node.Has("stereo_interpolation")) {
    o.stereo_interpolation = ParseEnum(node["stereo_interpolation"], [](const std::string& s) {
      return StereoInterpolationFromString(s);
    });
  }
  o.filter_depth_discontinuities =
      node.GetBool("filter_depth_discontinuities", o.filter_depth_discontinuities);
  o.max_depth_jump_footprints =
      node.GetDouble("max_depth_jump_footprints", o.max_depth_jump_footprints);
  o.discontinuity_dilation_px =
      static_cast<int>(node.GetInt("discontinuity_dilation_px", o.discontinuity_dilation_px));
  o.filter_outliers = node.GetBool("filter_outliers", o.filter_outliers);
  o.outlier_window_radius_px =
      static_cast<int>(node.GetInt("outlier_window_radius_px", o.outlier_window_radius_px));
  o.outlier_neighbors = static_cast<int>(node.GetInt("outlier_neighbors", o.outlier_neighbors));
  o.outlier_std_ratio = node.GetDouble("outlier_std_ratio", o.outlier_std_ratio);
  o.outlier_min_distance_footprints =
      node.GetDouble("outlier_min_distance_footprints", o.outlier_min_distance_footprints);
  o.estimate_normals = node.GetBool("estimate_normals", o.estimate_normals);
  o.report_residuals = node.GetBool("report_residuals", o.report_residuals);
  o.calibration_warning_px =
      GetDoubleOrInf(node, "calibration_warning_px", o.calibration_warning_px);
  o.calibration_noise_factor =
      node.GetDouble("calibration_noise_factor", o.calibration_noise_factor);
  o.calibration_min_warning_px =
      node.GetDouble("calibration_min_warning_px", o.calibration_min_warning_px);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), node.path().empty() ? "" : ": ", node.path(), ": ", e.what());
  }
  return o;
}

}  // namespace slshadow
