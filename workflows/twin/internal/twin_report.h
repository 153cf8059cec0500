// What workflows/twin/twin.cc (RunShadowOnImages, stage by stage) and workflows/twin/twin_report.cc
// (the report folder's maps, clouds and charts, and the text summary) share. Included only by those
// two.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/point_cloud.h"
#include "core/stage_meter.h"
#include "patterns/pattern_spec.h"
#include "workflows/twin/diagnose.h"

namespace slshadow::twin::internal {

// One reconstruction mode's clouds as compared, real and twin, with each point's signed C2M to
// the part (mm).
struct ModeClouds {
  std::string mode;
  PointCloud real, twin;
  std::vector<double> real_c2m, twin_c2m;
};

// The maps of one camera each, drawn into the report folder's maps/ (CV_32FC1, NaN where not
// compared; validity CV_8UC3).
struct ShadowMaps {
  std::vector<cv::Mat> residual, validity, white_difference, modulation;
};

// Per camera: the projector-coordinate residual, white-level difference and modulation-ratio
// charts and the validity image into `maps_dir`, each camera's entry appended to `maps_json`.
void WriteShadowMaps(const std::filesystem::path& maps_dir, const std::vector<std::string>& cameras,
                     const PatternSpec& spec, const DiagnoseOptions& diagnose, double fs_dn,
                     const ShadowMaps& maps, nlohmann::json* maps_json);

// Each mode's real and twin clouds, with their signed C2M to the part as the scalar
// "c2m_part_mm", into `clouds_dir` as real_<mode>.ply and twin_<mode>.ply.
void WriteShadowClouds(const std::filesystem::path& clouds_dir, std::vector<ModeClouds>* clouds);

// The charts into `staging`/charts (which exists): the per-frame intensity agreement (from the
// report's images.cameras) and per mode the histogram of real - twin C2M (`mode_diffs`) with its
// LoD95; each file named in (*report_json)["charts"].
void WriteShadowCharts(const std::filesystem::path& staging, const std::vector<ModeClouds>& clouds,
                       const std::vector<std::vector<double>>& mode_diffs,
                       const std::vector<double>& mode_lod95, nlohmann::json* report_json);

// The report's "stages": name, wall and CPU seconds, peak RSS of each stage.
nlohmann::json StagesToJson(const std::vector<StageMeasurement>& stages);

}  // namespace slshadow::twin::internal
