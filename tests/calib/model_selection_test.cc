#include "calib/model_selection.h"

#include <gtest/gtest.h>

#include <cmath>

#include <nlohmann/json.hpp>

#include "calib/synthetic.h"
#include "core/error.h"

namespace slshadow {
namespace {

// A camera-"projector" pair from synthetic corners: the second device's truth has no tangential
// distortion and no k3, as the kamino projector's data suggest.
SyntheticRig Procam() {
  SyntheticRig rig = SyntheticRig::Stereo();
  rig.devices[1].name = "projector";
  rig.devices[1].model.params[CameraModel::kP1] = 0;
  rig.devices[1].model.params[CameraModel::kP2] = 0;
  return rig;
}

TEST(ModelSelection, PerDeviceHeldParametersStayHeld) {
  SyntheticData data = MakeSyntheticData(Procam(), 8, 0.1, 11);
  data.input.devices[1].held_params = {CameraModel::kP1, CameraModel::kP2, CameraModel::kK3};
  const CalibrationResult r = Calibrate(data.input, {});
  const auto& proj = r.devices[1].model.params;
  EXPECT_EQ(proj[CameraModel::kP1], 0.0);
  EXPECT_EQ(proj[CameraModel::kP2], 0.0);
  EXPECT_EQ(proj[CameraModel::kK3], 0.0);
  EXPECT_NE(r.devices[0].model.params[CameraModel::kP1], 0.0);  // the other device's stay free
  ASSERT_EQ(r.intrinsics_covariance.size(), 2u);
  EXPECT_EQ(r.intrinsics_covariance[1](CameraModel::kP1, CameraModel::kP1), 0.0);
  EXPECT_GT(r.intrinsics_covariance[0](CameraModel::kP1, CameraModel::kP1), 0.0);
  CalibrationInput bad = data.input;
  bad.devices[1].held_params = {9};
  EXPECT_THROW(Calibrate(bad, {}), Error);
}

// Noise-free corners: every candidate that contains the true model predicts held-out poses
// exactly; dropping a true term (k1) makes the prediction error large.
TEST(ModelSelection, LeaveOnePoseOutScoresAgainstTruth) {
  const SyntheticData data = MakeSyntheticData(Procam(), 6, 0.0, 12);
  using M = CameraModel;
  const std::vector<ModelCandidate> candidates = {
      {"full / full", {{}, {}}},
      {"full / k1 k2", {{}, {M::kP1, M::kP2, M::kK3}}},
      {"full / none", {{}, {M::kK1, M::kK2, M::kP1, M::kP2, M::kK3}}}};
  const auto scores = ScoreModelsByLeaveOnePoseOut(data.input, {}, candidates, 0, 1);
  ASSERT_EQ(scores.size(), 3u);
  for (const auto& s : scores) {
    EXPECT_EQ(s.num_predicted, 6 * data.input.views[1].pixels_px.size()) << s.name;
    EXPECT_EQ(s.fold_models.size(), 6u);
  }
  EXPECT_LT(scores[0].prediction_rms_px, 1e-4);
  EXPECT_LT(scores[1].prediction_rms_px, 1e-4);
  EXPECT_GT(scores[2].prediction_rms_px, 100 * scores[1].prediction_rms_px + 0.05);
  EXPECT_LT(JackknifeSigma(scores[1], M::kCx), 1e-3);
  // With noise, the jackknife sigma of the folds is of the covariance's order.
  const SyntheticData noisy = MakeSyntheticData(Procam(), 8, 0.2, 13);
  const auto n = ScoreModelsByLeaveOnePoseOut(noisy.input, {}, {candidates[1]}, 0, 1);
  const double cov = std::sqrt(n[0].result.intrinsics_covariance[1](M::kFx, M::kFx));
  EXPECT_GT(JackknifeSigma(n[0], M::kFx), cov / 4);
  EXPECT_LT(JackknifeSigma(n[0], M::kFx), cov * 4);
  // Bad calls.
  EXPECT_THROW(ScoreModelsByLeaveOnePoseOut(data.input, {}, candidates, 1, 1), Error);
  EXPECT_THROW(ScoreModelsByLeaveOnePoseOut(data.input, {}, {{"short", {{}}}}, 0, 1), Error);
  CalibrationInput few = data.input;
  few.views.resize(4);  // 2 poses
  few.num_poses = 2;
  EXPECT_THROW(ScoreModelsByLeaveOnePoseOut(few, {}, candidates, 0, 1), Error);
}

// The grid of `slshadow calibrate --select-model` and the choice by the lowest prediction error.
TEST(ModelSelection, DistortionModelGridAndTheLowestPredictionIsChosen) {
  SyntheticData data = MakeSyntheticData(Procam(), 4, 0.0, 14);
  data.input.devices[1].is_projector = true;
  using M = CameraModel;
  const auto candidates = DistortionModelCandidates(data.input, 1);
  ASSERT_EQ(candidates.size(), 8u);
  EXPECT_EQ(candidates[0].name, "cameras k1 k2 p1 p2 k3 / projector k1 k2 p1 p2 k3");
  EXPECT_EQ(candidates[7].name, "cameras k1 k2 p1 p2 / projector k1");
  EXPECT_EQ(candidates[2].held_params,
            (std::vector<std::vector<int>>{{}, {M::kP1, M::kP2, M::kK3}}));
  EXPECT_EQ(candidates[5].held_params, (std::vector<std::vector<int>>{{M::kK3}, {M::kK3}}));
  EXPECT_EQ(candidates[7].held_params,
            (std::vector<std::vector<int>>{{M::kK3}, {M::kK2, M::kP1, M::kP2, M::kK3}}));
  EXPECT_THROW(DistortionModelCandidates(data.input, 0), Error);  // not a projector
  EXPECT_THROW(DistortionModelCandidates(data.input, 2), Error);

  CalibrationInput input = data.input;
  const ModelSelection selection = SelectDistortionModels(&input, {});
  ASSERT_EQ(selection.scores.size(), 8u);
  for (size_t i = 0; i < selection.scores.size(); ++i) {
    EXPECT_EQ(selection.scores[i].name, candidates[i].name);
    EXPECT_GE(selection.scores[i].prediction_rms_px,
              selection.scores[selection.chosen].prediction_rms_px);
  }
  EXPECT_LT(selection.scores[selection.chosen].prediction_rms_px,
            1e-4);  // noise-free: a candidate holds the truth
  EXPECT_EQ(selection.chosen_held_params, candidates[selection.chosen].held_params);
  EXPECT_EQ(input.devices[0].held_params, candidates[selection.chosen].held_params[0]);
  EXPECT_EQ(input.devices[1].held_params, candidates[selection.chosen].held_params[1]);
  const nlohmann::json json = ModelSelectionToJson(selection);
  EXPECT_EQ(json.at("chosen"), selection.scores[selection.chosen].name);
  ASSERT_EQ(json.at("candidates").size(), 8u);
  EXPECT_EQ(json.at("candidates")[3].at("model"), candidates[3].name);
  EXPECT_EQ(json.at("candidates")[3].at("prediction_rms_px").get<double>(),
            selection.scores[3].prediction_rms_px);
  EXPECT_EQ(json.at("candidates")[3].at("num_predicted").get<int>(),
            selection.scores[3].num_predicted);

  CalibrationInput cameras_only = data.input;
  cameras_only.devices[1].is_projector = false;
  EXPECT_THROW(SelectDistortionModels(&cameras_only, {}), Error);
}

}  // namespace
}  // namespace slshadow
