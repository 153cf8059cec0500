// Distortion-model selection by leave-one-pose-out cross-validation.
//
// With few board poses (a projector is often calibrated from 5-10), a full distortion model
// (k1 k2 p1 p2 k3) can fit the noise: the residual RMS drops, but the model predicts new views
// worse, and the principal point, tangential distortion and k3 trade off (wide covariance). Each
// candidate holds some parameters per device (CalibrationDevice::held_params); for every pose k
// seen by the reference device and the target device, the rig is calibrated without pose k, the
// board of pose k is posed from the reference device's view alone (its intrinsics held), and the
// target device's corners of pose k are predicted through the rig. The prediction RMS over all
// held-out corners scores the candidate: it measures what a scan needs (intrinsics and rig pose
// together), and unlike the fit RMS it does not reward extra parameters.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json_fwd.hpp>

#include "calib/calibration.h"

namespace slshadow {

struct ModelCandidate {
  std::string name;                           // e.g. "camera k1k2p1p2 / projector k1k2"
  std::vector<std::vector<int>> held_params;  // per device of the input: CameraModel indices held
};

struct ModelScore {
  std::string name;
  double fit_rms_px = 0;                 // target device's RMS with all poses
  double prediction_rms_px = 0;          // target device's RMS on held-out poses, predicted
  int num_predicted = 0;                 // held-out corners predicted
  std::vector<CameraModel> fold_models;  // target device's model from each fold, in pose order
  CalibrationResult result;              // with all poses
};

// Scores each candidate (throws slshadow::Error when a candidate's held_params does not have one
// entry per device, or fewer than 3 poses are seen by both devices). Devices' own held_params
// in `input` are replaced by the candidate's.
std::vector<ModelScore> ScoreModelsByLeaveOnePoseOut(const CalibrationInput& input,
                                                     const CalibrationOptions& options,
                                                     const std::vector<ModelCandidate>& candidates,
                                                     int reference_device, int target_device);

// The candidate grid of `slshadow calibrate --select-model`: every camera "k1 k2 p1 p2 k3" or
// "k1 k2 p1 p2" (k3 held) crossed with the projector "k1 k2 p1 p2 k3", "k1 k2 p1 p2", "k1 k2" or
// "k1": 8 candidates named "cameras <model> / projector <model>", held_params one entry per device
// of `input`. Throws slshadow::Error when `projector_device` is not a projector of the input.
std::vector<ModelCandidate> DistortionModelCandidates(const CalibrationInput& input,
                                                      int projector_device);

struct ModelSelection {
  std::vector<ModelScore> scores;  // per candidate of DistortionModelCandidates, in its order
  size_t chosen = 0;               // the lowest prediction_rms_px (the first of equals)
  std::vector<std::vector<int>> chosen_held_params;  // per device
};

// Scores DistortionModelCandidates by leave-one-pose-out (the first device as reference, the
// input's projector as target) and sets the devices' held_params in `input` to the chosen
// candidate's. scores[chosen].result is the chosen model's calibration with all poses (the same
// input and options: no need to solve again). Throws slshadow::Error when the input has no
// projector, and as ScoreModelsByLeaveOnePoseOut.
ModelSelection SelectDistortionModels(CalibrationInput* input, const CalibrationOptions& options);

// {"candidates": [{"model", "fit_rms_px", "prediction_rms_px", "num_predicted"}], "chosen": name}
// (the calibration report's extra.model_selection, docs/formats.md "Calibration report").
nlohmann::json ModelSelectionToJson(const ModelSelection& selection);

// Jackknife standard deviation of one intrinsics parameter over a score's folds:
// sqrt((n-1)/n * sum (theta_i - mean)^2), comparable with the covariance's predicted sigma.
double JackknifeSigma(const ModelScore& score, int parameter);

}  // namespace slshadow
