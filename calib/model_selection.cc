#include "calib/model_selection.h"

#include <cmath>
#include <set>

#include <nlohmann/json.hpp>

#include "core/error.h"

namespace slshadow {

std::vector<ModelScore> ScoreModelsByLeaveOnePoseOut(const CalibrationInput& input,
                                                     const CalibrationOptions& options,
                                                     const std::vector<ModelCandidate>& candidates,
                                                     int reference_device, int target_device) {
  const int num_devices = static_cast<int>(input.devices.size());
  SLSHADOW_THROW_IF(reference_device < 0 || reference_device >= num_devices || target_device < 0 ||
                        target_device >= num_devices || reference_device == target_device,
                    "model selection: reference and target devices must be two different devices "
                    "of the input (got ",
                    reference_device, " and ", target_device, ")");
  std::set<int> ref_poses, target_poses;
  for (const auto& v : input.views) {
    if (v.device == reference_device) ref_poses.insert(v.pose);
    if (v.device == target_device) target_poses.insert(v.pose);
  }
  std::vector<int> shared;
  for (int p : target_poses) {
    if (ref_poses.count(p)) shared.push_back(p);
  }
  SLSHADOW_THROW_IF(shared.size() < 3,
                    "model selection: leave-one-pose-out needs at least 3 poses seen by both '",
                    input.devices[reference_device].name, "' and '",
                    input.devices[target_device].name, "' (got ", shared.size(), ")");
  CalibrationOptions fold_options = options;
  fold_options.compute_covariance = false;
  std::vector<ModelScore> scores;
  for (const auto& c : candidates) {
    SLSHADOW_THROW_IF(static_cast<int>(c.held_params.size()) != num_devices,
                      "model selection: candidate '", c.name, "': held_params has ",
                      c.held_params.size(), " entries for ", num_devices, " devices");
    CalibrationInput in = input;
    for (int d = 0; d < num_devices; ++d) in.devices[d].held_params = c.held_params[d];
    ModelScore score;
    score.name = c.name;
    score.result = Calibrate(in, options);
    score.fit_rms_px = score.result.summary.devices[target_device].rms_px;
    double sq = 0;
    for (int k : shared) {
      CalibrationInput fold = in;
      fold.views.clear();
      for (const auto& v : in.views) {
        if (v.pose != k) fold.views.push_back(v);
      }
      const CalibrationResult r = Calibrate(fold, fold_options);
      score.fold_models.push_back(r.devices[target_device].model);
      // Pose k from the reference device's view alone, its intrinsics held.
      CalibrationInput single;
      single.num_poses = 1;
      single.devices = {in.devices[reference_device]};
      single.devices[0].initial = r.devices[reference_device].model;
      single.devices[0].hold_intrinsics = true;
      const BoardView* target_view = nullptr;
      for (const auto& v : in.views) {
        if (v.pose != k) continue;
        if (v.device == reference_device) {
          single.views.push_back(v);
          single.views.back().device = 0;
          single.views.back().pose = 0;
          single.views.back().DropCarry();
        }
        if (v.device == target_device) target_view = &v;
      }
      const CalibrationResult posed = Calibrate(single, fold_options);
      SLSHADOW_CHECK(posed.rig_from_board[0].has_value() && target_view != nullptr);
      const Rigid3d ref_from_board = *posed.rig_from_board[0];
      const Rigid3d target_from_board = r.devices[target_device].cam_from_rig *
                                        r.devices[reference_device].cam_from_rig.Inverse() *
                                        ref_from_board;
      for (size_t i = 0; i < target_view->pixels_px.size(); ++i) {
        const auto px = r.devices[target_device].model.Project(target_from_board *
                                                               target_view->points_in_board_mm[i]);
        if (!px) continue;
        sq += (*px - target_view->pixels_px[i]).squaredNorm();
        ++score.num_predicted;
      }
    }
    score.prediction_rms_px =
        score.num_predicted ? std::sqrt(sq / score.num_predicted) : std::nan("");
    scores.push_back(std::move(score));
  }
  return scores;
}

double JackknifeSigma(const ModelScore& score, int parameter) {
  const size_t n = score.fold_models.size();
  if (n < 2) return std::nan("");
  double mean = 0;
  for (const auto& m : score.fold_models) mean += m.params[static_cast<size_t>(parameter)];
  mean /= static_cast<double>(n);
  double ss = 0;
  for (const auto& m : score.fold_models)
    ss += std::pow(m.params[static_cast<size_t>(parameter)] - mean, 2);
  return std::sqrt((static_cast<double>(n) - 1) / static_cast<double>(n) * ss);
}

std::vector<ModelCandidate> DistortionModelCandidates(const CalibrationInput& input,
                                                      int projector_device) {
  SLSHADOW_THROW_IF(
      projector_device < 0 || projector_device >= static_cast<int>(input.devices.size()) ||
          !input.devices[static_cast<size_t>(projector_device)].is_projector,
      "model selection: device ", projector_device, " is not a projector of the input");
  using M = CameraModel;
  const std::vector<std::pair<std::string, std::vector<int>>> cameras = {{"k1 k2 p1 p2 k3", {}},
                                                                         {"k1 k2 p1 p2", {M::kK3}}};
  const std::vector<std::pair<std::string, std::vector<int>>> projectors = {
      {"k1 k2 p1 p2 k3", {}},
      {"k1 k2 p1 p2", {M::kK3}},
      {"k1 k2", {M::kP1, M::kP2, M::kK3}},
      {"k1", {M::kK2, M::kP1, M::kP2, M::kK3}}};
  std::vector<ModelCandidate> candidates;
  for (const auto& [cam_name, cam_held] : cameras) {
    for (const auto& [proj_name, proj_held] : projectors) {
      ModelCandidate c;
      c.name = "cameras " + cam_name + " / projector " + proj_name;
      for (size_t d = 0; d < input.devices.size(); ++d) {
        c.held_params.push_back(static_cast<int>(d) == projector_device ? proj_held : cam_held);
      }
      candidates.push_back(std::move(c));
    }
  }
  return candidates;
}

ModelSelection SelectDistortionModels(CalibrationInput* input, const CalibrationOptions& options) {
  int projector = -1;
  for (size_t d = 0; d < input->devices.size(); ++d) {
    if (input->devices[d].is_projector) projector = static_cast<int>(d);
  }
  SLSHADOW_THROW_IF(projector < 0, "--select-model: the input has no projector");
  const std::vector<ModelCandidate> candidates = DistortionModelCandidates(*input, projector);
  ModelSelection selection;
  selection.scores = ScoreModelsByLeaveOnePoseOut(*input, options, candidates, 0, projector);
  for (size_t i = 0; i < selection.scores.size(); ++i) {
    if (selection.scores[i].prediction_rms_px <
        selection.scores[selection.chosen].prediction_rms_px)
      selection.chosen = i;
  }
  selection.chosen_held_params = candidates[selection.chosen].held_params;
  for (size_t d = 0; d < input->devices.size(); ++d)
    input->devices[d].held_params = selection.chosen_held_params[d];
  return selection;
}

nlohmann::json ModelSelectionToJson(const ModelSelection& selection) {
  nlohmann::json table = nlohmann::json::array();
  for (const auto& s : selection.scores) {
    table.push_back({{"model", s.name},
                     {"fit_rms_px", s.fit_rms_px},
                     {"prediction_rms_px", s.prediction_rms_px},
                     {"num_predicted", s.num_predicted}});
  }
  return {{"candidates", table}, {"chosen", selection.scores.at(selection.chosen).name}};
}

}  // namespace slshadow
