// The discrepancy of a measured relative pose against two estimated view poses, as the pose graphs
// of workflows/multiview (pose_graph.cc: six free unknowns per view; turntable_graph.cc: the
// turntable model) weigh it: S (w, v), w the rotation vector and v the translation of
// P_a^-1 P_b M^-1 (the left perturbation of the measured a_from_b M, as the ICP linearises it).
// Templated for Ceres' automatic differentiation; internal to workflows/multiview, included only
// by the .cc files that already use Ceres.
#pragma once

#include <ceres/rotation.h>
#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/rigid3.h"
#include "workflows/multiview/internal/pairwise.h"

namespace slshadow::multiview::internal {

template <typename T>
void RelativePoseDelta(const Eigen::Quaternion<T>& rot_a, const Eigen::Matrix<T, 3, 1>& tr_a,
                       const Eigen::Quaternion<T>& rot_b, const Eigen::Matrix<T, 3, 1>& tr_b,
                       const Rigid3d& measured_inverse, const Matrix6d& sqrt_info, T* residuals) {
  const Eigen::Quaternion<T> rot_a_inv = rot_a.conjugate();
  const Eigen::Quaternion<T> rot_e = rot_a_inv * rot_b;
  const Eigen::Matrix<T, 3, 1> tr_e = rot_a_inv * (tr_b - tr_a);
  const Eigen::Quaternion<T> rot_d = rot_e * measured_inverse.rotation.cast<T>();
  const Eigen::Matrix<T, 3, 1> tr_d = rot_e * measured_inverse.translation.cast<T>() + tr_e;
  const T qd[4] = {rot_d.w(), rot_d.x(), rot_d.y(), rot_d.z()};
  Eigen::Matrix<T, 6, 1> delta;
  ceres::QuaternionToAngleAxis(qd, delta.data());
  delta.template tail<3>() = tr_d;
  Eigen::Map<Eigen::Matrix<T, 6, 1>> out(residuals);
  out = sqrt_info.cast<T>() * delta;
}

}  // namespace slshadow::multiview::internal
