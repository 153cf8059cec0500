// Internal to calib/ (calib/internal/: not part of the public API; include only from calib/*.cc).
// The unknowns of one calibration problem (State) and the small helpers every stage of
// Calibrate() shares: pose blocks, views, losses, held intrinsics, reprojection at a state.
#pragma once

#include <algorithm>
#include <array>
#include <vector>

#include <ceres/ceres.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "calib/calibration.h"
#include "calib/internal/cost_functions.h"
#include "core/rigid3.h"

namespace slshadow::calib::internal {

using Pose6 = std::array<double, 6>;  // angle-axis (rad), translation (mm)
using Intr9 = std::array<double, CameraModel::kNumParams>;

inline Pose6 ToPose6(const Rigid3d& t) {
  const Eigen::Vector3d r = RotationVectorFromQuaternion(t.rotation);
  return {r.x(), r.y(), r.z(), t.translation.x(), t.translation.y(), t.translation.z()};
}

inline Rigid3d FromPose6(const Pose6& p) {
  return Rigid3d::FromRotationVector(Eigen::Vector3d(p[0], p[1], p[2]),
                                     Eigen::Vector3d(p[3], p[4], p[5]));
}

// Weights of the joint noise model (CalibrationOptions::correlated_carried_noise).
struct NoiseModel {
  std::vector<double> sigma_px;  // per device, per coordinate
  double carry_scale = 1;        // k on carry_covariances_px2
};

// Error field of one device's corners within a view (view-correlated noise model): sigma per
// coordinate, and the correlation of two corners delta grid squares apart, share *
// exp(-delta^2 / (2 length^2)) (1 at delta 0).
struct ViewNoiseKernel {
  double sigma_px = 0;
  double share = 0;
  double length_squares = 1;
};

// Index of `device`'s view of `pose` in input.views, -1 when there is none.
inline int FindView(const CalibrationInput& input, int device, int pose) {
  for (size_t i = 0; i < input.views.size(); ++i) {
    if (input.views[i].device == device && input.views[i].pose == pose) return static_cast<int>(i);
  }
  return -1;
}

inline ceres::LossFunction* MakeLoss(const CalibrationOptions& options, double scale) {
  if (options.loss == LossType::kHuber) return new ceres::HuberLoss(scale);
  if (options.loss == LossType::kCauchy) return new ceres::CauchyLoss(scale);
  return nullptr;
}

// All unknowns of one problem.
struct State {
  std::vector<Intr9> intrinsics;
  std::vector<double> aspect;  // per device: fixed fy/fx, or 0 when free
  std::vector<Pose6> dev_from_rig;
  std::vector<Pose6> rig_from_board;
  std::vector<bool> pose_known;
  // Per device: principal-point coordinates pinned to their bound by the last solve (Solve).
  std::vector<std::vector<int>> pinned;
  std::array<double, 2> warp{0, 0};                  // board warp, mm
  Eigen::Vector4d extent = Eigen::Vector4d::Zero();  // board xmin xmax ymin ymax, mm
};

inline Eigen::Vector4d BoardExtent(const CalibrationInput& input) {
  Eigen::Vector4d e(1e300, -1e300, 1e300, -1e300);
  for (const auto& v : input.views) {
    for (const auto& p : v.points_in_board_mm) {
      e[0] = std::min(e[0], p.x());
      e[1] = std::max(e[1], p.x());
      e[2] = std::min(e[2], p.y());
      e[3] = std::max(e[3], p.y());
    }
  }
  return e;
}

inline Intr9 EffectiveParams(const State& s, int d) {
  Intr9 p = s.intrinsics[d];
  if (s.aspect[d] > 0) p[CameraModel::kFy] = p[CameraModel::kFx] * s.aspect[d];
  return p;
}

inline Eigen::Vector2d ProjectView(const State& s, const BoardView& v, size_t i) {
  const ReprojectionFunctor f(v.points_in_board_mm[i], Eigen::Vector2d::Zero(), s.aspect[v.device],
                              s.extent);
  Eigen::Vector2d pixel;
  f(s.intrinsics[v.device].data(), s.dev_from_rig[v.device].data(), s.rig_from_board[v.pose].data(),
    s.warp.data(), pixel.data());
  return pixel;
}

inline std::vector<int> HeldIntrinsics(const CalibrationOptions& o, const CalibrationDevice& device,
                                       double aspect) {
  std::vector<int> held;
  for (int i : device.held_params) {
    if (i != CameraModel::kFy || aspect <= 0) held.push_back(i);
  }
  if (aspect > 0) held.push_back(CameraModel::kFy);
  if (o.fix_principal_point) {
    held.push_back(CameraModel::kCx);
    held.push_back(CameraModel::kCy);
  }
  if (o.zero_tangential) {
    held.push_back(CameraModel::kP1);
    held.push_back(CameraModel::kP2);
  }
  if (o.fix_k3) held.push_back(CameraModel::kK3);
  std::sort(held.begin(), held.end());
  held.erase(std::unique(held.begin(), held.end()), held.end());
  return held;
}

struct SolveOutput {
  ceres::Solver::Summary summary;
  std::vector<Matrix9d> covariance;  // per device, unscaled (J^T J)^-1 in the 9 parameters
  std::vector<Matrix9d> correlated_covariance;  // per device, px-scaled sandwich (with `kernels`)
  int num_free_parameters = 0;
  bool repeat = false;  // a principal-point coordinate was pinned to its bound: solve again
};

}  // namespace slshadow::calib::internal
