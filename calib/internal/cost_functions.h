// Internal to calib/ (calib/internal/: not part of the public API; include only from calib/*.cc).
// The Ceres cost functors of Calibrate() (calib/calibration.h) and the whitening of a carried
// point with its source (CalibrationOptions::correlated_carried_noise).
#pragma once

#include <optional>

#include <ceres/rotation.h>
#include <Eigen/Cholesky>
#include <Eigen/Core>

#include "core/camera_model.h"

namespace slshadow::calib::internal {

// r = weight * (ImgFromCam(intrinsics, dev_from_rig * rig_from_board * W(X)) - u). With aspect > 0
// the model's fy is aspect * fx (the fy entry of the block is held constant and ignored). W adds
// the board warp z += w_x (1 - s^2) + w_y (1 - t^2), (s, t) the point's position across the board
// extent scaled to [-1, 1] (mrcal's board deformation).
struct ReprojectionFunctor {
  ReprojectionFunctor(const Eigen::Vector3d& point_in_board, const Eigen::Vector2d& pixel,
                      double aspect, const Eigen::Vector4d& extent)
      : x(point_in_board), u(pixel), aspect_ratio(aspect) {
    const double sx =
        extent[1] > extent[0] ? 2 * (x.x() - extent[0]) / (extent[1] - extent[0]) - 1 : 0;
    const double sy =
        extent[3] > extent[2] ? 2 * (x.y() - extent[2]) / (extent[3] - extent[2]) - 1 : 0;
    warp_x = 1 - sx * sx;
    warp_y = 1 - sy * sy;
  }

  template <typename T>
  bool operator()(const T* intrinsics, const T* dev_from_rig, const T* rig_from_board,
                  const T* warp, T* residual) const {
    const T point_in_board[3] = {T(x.x()), T(x.y()),
                                 T(x.z()) + warp[0] * T(warp_x) + warp[1] * T(warp_y)};
    T point_in_rig[3], point_in_dev[3];
    ceres::AngleAxisRotatePoint(rig_from_board, point_in_board, point_in_rig);
    for (int i = 0; i < 3; ++i) point_in_rig[i] += rig_from_board[3 + i];
    ceres::AngleAxisRotatePoint(dev_from_rig, point_in_rig, point_in_dev);
    for (int i = 0; i < 3; ++i) point_in_dev[i] += dev_from_rig[3 + i];
    T params[CameraModel::kNumParams];
    for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = intrinsics[i];
    if (aspect_ratio > 0) params[CameraModel::kFy] = intrinsics[CameraModel::kFx] * T(aspect_ratio);
    T pixel[2];
    CameraModel::ImgFromCam(params, point_in_dev, pixel);
    residual[0] = (pixel[0] - T(u.x())) * T(weight);
    residual[1] = (pixel[1] - T(u.y())) * T(weight);
    return true;
  }

  Eigen::Vector3d x;
  Eigen::Vector2d u;
  double aspect_ratio;
  double warp_x = 0, warp_y = 0;
  double weight = 1;  // 1 / noise sigma when whitening
};

// One carried point and its source point (BoardView::source_device), whitened together:
// W (r_source; r_carried), W = L^-1 for their 4x4 noise covariance C = L L^T.
struct CarriedPairFunctor {
  template <typename T>
  bool operator()(const T* source_intrinsics, const T* source_from_rig, const T* intrinsics,
                  const T* dev_from_rig, const T* rig_from_board, const T* warp,
                  T* residual) const {
    T r[4];
    source(source_intrinsics, source_from_rig, rig_from_board, warp, r);
    carried(intrinsics, dev_from_rig, rig_from_board, warp, r + 2);
    for (int i = 0; i < 4; ++i) {
      residual[i] = T(0);
      for (int j = 0; j <= i; ++j) residual[i] += T(whiten(i, j)) * r[j];
    }
    return true;
  }

  ReprojectionFunctor source, carried;
  Eigen::Matrix4d whiten;  // lower triangular
};

// Whitening of a carried point and its source: C = [[s^2 I, s^2 J^T], [s^2 J, s^2 J J^T + carry]];
// std::nullopt when C is not positive definite.
inline std::optional<Eigen::Matrix4d> PairWhitening(double sigma, const Eigen::Matrix2d& jacobian,
                                                    const Eigen::Matrix2d& carry) {
  const double s2 = sigma * sigma;
  Eigen::Matrix4d c;
  c.topLeftCorner<2, 2>() = s2 * Eigen::Matrix2d::Identity();
  c.topRightCorner<2, 2>() = s2 * jacobian.transpose();
  c.bottomLeftCorner<2, 2>() = s2 * jacobian;
  c.bottomRightCorner<2, 2>() = s2 * jacobian * jacobian.transpose() + carry;
  const Eigen::LLT<Eigen::Matrix4d> llt(c);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::Matrix4d w = llt.matrixL().solve(Eigen::Matrix4d::Identity());
  if (!w.allFinite()) return std::nullopt;
  return w;
}

}  // namespace slshadow::calib::internal
