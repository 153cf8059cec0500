#include "calib/calibration_io.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <climits>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <numbers>
#include <optional>
#include <set>
#include <utility>

#include <yaml-cpp/yaml.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/pose_io.h"

namespace slshadow {
namespace {

constexpr int kEvidenceVersion = 1;
// CameraModel parameter order.
constexpr std::array<const char*, CameraModel::kNumParams> kParamNames = {
    "fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3"};

nlohmann::json StatsToJson(const CalibrationSummary& s) {
  nlohmann::json j = {{"rms_px", s.rms_px},
                      {"max_px", s.max_px},
                      {"residual_sigma_px", s.residual_sigma_px},
                      {"initial_cost", s.initial_cost},
                      {"final_cost", s.final_cost},
                      {"iterations", s.iterations},
                      {"converged", s.converged},
                      {"termination", s.termination},
                      {"num_points", s.num_points},
                      {"num_free_parameters", s.num_free_parameters},
                      {"num_outlier_views", s.num_outlier_views},
                      {"solve_time_s", s.solve_time_s}};
  j["devices"] = nlohmann::json::array();
  for (const auto& d : s.devices) {
    j["devices"].push_back({{"name", d.name},
                            {"num_views", d.num_views},
                            {"num_points", d.num_points},
                            {"rms_px", d.rms_px},
                            {"max_px", d.max_px}});
  }
  if (!s.view_noise.empty()) {
    j["view_noise"] = nlohmann::json::array();
    for (const auto& k : s.view_noise) {
      j["view_noise"].push_back(
          {{"sigma_px", k.sigma_px}, {"share", k.share}, {"length_squares", k.length_squares}});
    }
  }
  if (!s.bounds_active.empty()) j["bounds_active"] = s.bounds_active;
  if (s.joint_noise) {
    j["joint_noise"] = {{"noise_sigma_px", s.noise_sigma_px},
                        {"carry_scale", s.carry_scale},
                        {"variance_factor", s.variance_factor}};
  }
  j["views"] = nlohmann::json::array();
  for (const auto& v : s.views) {
    j["views"].push_back(
        {{"label", v.label},
         {"device", v.device},
         {"pose", v.pose},
         {"num_points", v.num_points},
         {"rms_px", std::isfinite(v.rms_px) ? nlohmann::json(v.rms_px) : nlohmann::json()},
         {"max_px", std::isfinite(v.max_px) ? nlohmann::json(v.max_px) : nlohmann::json()},
         {"outlier", v.outlier}});
  }
  return j;
}

nlohmann::json MapStats(const PixelMap& m) {
  auto num = [](double x) { return std::isfinite(x) ? nlohmann::json(x) : nlohmann::json(); };
  return {{"median_px", num(m.median)},
          {"p95_px", num(m.p95)},
          {"max_px", num(m.max)},
          {"centre_px", num(m.centre)},
          {"cell_px", m.cell_px}};
}

}  // namespace

Rig RigFromCalibration(const CalibrationInput& input, const CalibrationResult& result,
                       const std::string& name) {
  Rig rig;
  rig.name = name;
  for (size_t d = 0; d < result.devices.size(); ++d) {
    if (input.devices[d].is_projector) {
      SLSHADOW_THROW_IF(rig.projector.has_value(), "calibration: more than one projector device ('",
                        rig.projector->name, "', '", result.devices[d].name,
                        "'); a rig has at most one");
      rig.projector = result.devices[d];
    } else {
      rig.cameras.push_back(result.devices[d]);
    }
  }
  SLSHADOW_THROW_IF(rig.cameras.empty(),
                    "calibration: no camera device; a rig needs at least one camera");
  SLSHADOW_THROW_IF(input.devices[0].is_projector,
                    "calibration: device 0 must be a camera (it defines the rig frame)");
  // Working distance: median board distance along the first camera's axis.
  std::vector<double> z;
  for (const auto& p : result.rig_from_board) {
    if (p) z.push_back(p->translation.z());
  }
  if (!z.empty()) {
    std::nth_element(z.begin(), z.begin() + static_cast<long>(z.size() / 2), z.end());
    if (z[z.size() / 2] > 0) rig.working_distance_mm = z[z.size() / 2];
  }
  return rig;
}

nlohmann::json CalibrationEvidenceToJson(const CalibrationInput& input,
                                         const CalibrationOptions& options,
                                         const CalibrationResult& result,
                                         const std::optional<CrossValidation>& cross_validation) {
  nlohmann::json j;
  j["format"] = "slshadow-calibration-evidence";
  j["version"] = kEvidenceVersion;
  j["options"] = CalibrationOptionsToJson(options);
  j["num_poses"] = input.num_poses;
  j["devices"] = nlohmann::json::array();
  for (const auto& d : input.devices) {
    nlohmann::json held = nlohmann::json::array();
    for (int i : d.held_params) held.push_back(kParamNames.at(static_cast<size_t>(i)));
    j["devices"].push_back({{"name", d.name},
                            {"width", d.width},
                            {"height", d.height},
                            {"is_projector", d.is_projector},
                            {"held_params", held}});
  }
  j["views"] = nlohmann::json::array();
  for (const auto& v : input.views) {
    nlohmann::json pts = nlohmann::json::array(), pix = nlohmann::json::array();
    for (const auto& p : v.points_in_board_mm) pts.push_back({p.x(), p.y(), p.z()});
    for (const auto& p : v.pixels_px) pix.push_back({p.x(), p.y()});
    j["views"].push_back({{"label", v.label},
                          {"device", v.device},
                          {"pose", v.pose},
                          {"points_in_board_mm", pts},
                          {"pixels_px", pix}});
    if (v.IsCarried()) {
      nlohmann::json jac = nlohmann::json::array(), cov = nlohmann::json::array();
      for (const auto& m : v.source_jacobians) jac.push_back({m(0, 0), m(0, 1), m(1, 0), m(1, 1)});
      for (const auto& m : v.carry_covariances_px2)
        cov.push_back({m(0, 0), m(0, 1), m(1, 0), m(1, 1)});
      j["views"].back()["source_device"] = v.source_device;
      j["views"].back()["source_points"] = v.source_points;
      j["views"].back()["source_jacobians"] = jac;
      j["views"].back()["carry_covariances_px2"] = cov;
    }
  }
  j["rig_from_board"] = nlohmann::json::array();
  for (const auto& p : result.rig_from_board)
    j["rig_from_board"].push_back(p ? PoseToJson(*p) : nlohmann::json());
  j["summary"] = StatsToJson(result.summary);
  j["board_warp_mm"] = {result.board_warp_mm.x(), result.board_warp_mm.y()};
  if (!result.intrinsics_covariance.empty()) {
    j["intrinsics_covariance"] = nlohmann::json::array();
    j["projection_uncertainty"] = nlohmann::json::array();
    for (size_t d = 0; d < result.intrinsics_covariance.size(); ++d) {
      const Matrix9d& c = result.intrinsics_covariance[d];
      std::vector<double> flat;
      for (int r = 0; r < 9; ++r) {
        for (int k = 0; k < 9; ++k) flat.push_back(c(r, k));
      }
      j["intrinsics_covariance"].push_back(flat);
      nlohmann::json u = MapStats(ProjectionUncertaintyMap(result.devices[d].model, c, 16));
      u["device"] = result.devices[d].name;
      j["projection_uncertainty"].push_back(u);
    }
  }
  if (!result.intrinsics_covariance_view_correlated.empty()) {
    j["intrinsics_covariance_view_correlated"] = nlohmann::json::array();
    j["projection_uncertainty_view_correlated"] = nlohmann::json::array();
    for (size_t d = 0; d < result.intrinsics_covariance_view_correlated.size(); ++d) {
      const Matrix9d& c = result.intrinsics_covariance_view_correlated[d];
      j["intrinsics_covariance_view_correlated"].push_back(
          std::vector<double>(c.data(), c.data() + 81));  // symmetric
      nlohmann::json u = MapStats(ProjectionUncertaintyMap(result.devices[d].model, c, 16));
      u["device"] = result.devices[d].name;
      j["projection_uncertainty_view_correlated"].push_back(u);
    }
  }
  if (cross_validation) {
    j["cross_validation"] = nlohmann::json::array();
    for (size_t d = 0; d < cross_validation->difference.size(); ++d) {
      nlohmann::json c = MapStats(cross_validation->difference[d]);
      c["device"] = input.devices[d].name;
      j["cross_validation"].push_back(c);
    }
  }
  return j;
}

CalibrationEvidence CalibrationEvidenceFromJson(const nlohmann::json& json,
                                                const std::string& file) {
  const ConfigNode n = ConfigNode::FromJson(json, file, "calibration");
  SLSHADOW_THROW_IF(n.GetString("format", "") != "slshadow-calibration-evidence", file,
                    ": calibration.format: not slshadow calibration evidence (got '",
                    n.GetString("format", ""), "')");
  const int64_t version = n["version"].AsInt();
  if (version != kEvidenceVersion) n["version"].Fail("unsupported version");
  CalibrationEvidence e;
  e.options = n.Has("options") ? CalibrationOptionsFromJson(n["options"].json(), file)
                               : CalibrationOptions{};
  e.input.num_poses = static_cast<int>(n["num_poses"].AsInt());
  const auto devs = n["devices"];
  for (size_t i = 0; i < devs.size(); ++i) {
    const auto d = devs.at(i);
    CalibrationDevice cd;
    cd.name = d["name"].AsString();
    cd.width = static_cast<int>(d["width"].AsInt());
    cd.height = static_cast<int>(d["height"].AsInt());
    cd.is_projector = d.GetBool("is_projector", false);
    if (d.Has("held_params")) {
      const auto held = d["held_params"];
      for (size_t k = 0; k < held.size(); ++k) {
        const std::string name = held.at(k).AsString();
        const auto it = std::find(kParamNames.begin(), kParamNames.end(), name);
        if (it == kParamNames.end())
          held.at(k).Fail("unknown parameter (use fx fy cx cy k1 k2 p1 p2 k3)");
        cd.held_params.push_back(static_cast<int>(it - kParamNames.begin()));
      }
    }
    e.input.devices.push_back(cd);
  }
  const auto views = n["views"];
  for (size_t i = 0; i < views.size(); ++i) {
    const auto v = views.at(i);
    BoardView bv;
    bv.label = v.GetString("label", "");
    bv.device = static_cast<int>(v["device"].AsInt());
    bv.pose = static_cast<int>(v["pose"].AsInt());
    const auto pts = v["points_in_board_mm"], pix = v["pixels_px"];
    for (size_t k = 0; k < pts.size(); ++k) {
      const auto p = pts.at(k).AsDoubles(3);
      bv.points_in_board_mm.emplace_back(p[0], p[1], p[2]);
    }
    for (size_t k = 0; k < pix.size(); ++k) {
      const auto p = pix.at(k).AsDoubles(2);
      bv.pixels_px.emplace_back(p[0], p[1]);
    }
    if (v.Has("source_device")) {
      bv.source_device = static_cast<int>(v["source_device"].AsInt());
      const auto ids = v["source_points"], jac = v["source_jacobians"],
                 cov = v["carry_covariances_px2"];
      for (size_t k = 0; k < ids.size(); ++k)
        bv.source_points.push_back(static_cast<int>(ids.at(k).AsInt()));
      auto matrix = [](const ConfigNode& node) {
        const auto m = node.AsDoubles(4);
        return (Eigen::Matrix2d() << m[0], m[1], m[2], m[3]).finished();
      };
      for (size_t k = 0; k < jac.size(); ++k) bv.source_jacobians.push_back(matrix(jac.at(k)));
      for (size_t k = 0; k < cov.size(); ++k) bv.carry_covariances_px2.push_back(matrix(cov.at(k)));
    }
    e.input.views.push_back(std::move(bv));
  }
  try {
    e.input.Check();
  } catch (const Error& err) {
    SLSHADOW_THROW(file, ": ", err.what());
  }
  return e;
}

double EvidenceProjectionUncertaintyP95Px(const nlohmann::json& evidence,
                                          const std::string& device) {
  double best = std::nan("");
  if (!evidence.is_object()) return best;
  for (const char* key : {"projection_uncertainty", "projection_uncertainty_view_correlated"}) {
    if (!evidence.contains(key) || !evidence[key].is_array()) continue;
    for (const auto& u : evidence[key]) {
      if (!u.is_object() || u.value("device", std::string()) != device || !u.contains("p95_px") ||
          !u["p95_px"].is_number())
        continue;
      const double v = u["p95_px"].get<double>();
      if (std::isfinite(v) && !(v <= best)) best = v;
    }
  }
  return best;
}

}  // namespace slshadow
