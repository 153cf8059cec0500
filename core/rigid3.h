// Rigid transforms named target_from_source (DESIGN.md): x_in_target = rotation * x_in_source +
// translation. Units: millimetres.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace slshadow {

// The rotation of a rotation vector r (axis r / |r|, angle |r| radians; OpenCV's rvec, Ceres'
// angle-axis); the identity for r = 0.
inline Eigen::Quaterniond QuaternionFromRotationVector(const Eigen::Vector3d& r) {
  const double angle = r.norm();
  return angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, r / angle))
                   : Eigen::Quaterniond::Identity();
}

// The rotation vector of q (axis times angle, radians, angle in [0, pi]; OpenCV's rvec): the
// inverse of QuaternionFromRotationVector up to rounding.
inline Eigen::Vector3d RotationVectorFromQuaternion(const Eigen::Quaterniond& q) {
  const Eigen::AngleAxisd aa(q);
  return aa.angle() * aa.axis();
}

struct Rigid3d {
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Rigid3d() = default;
  Rigid3d(const Eigen::Quaterniond& r, const Eigen::Vector3d& t)
      : rotation(r.normalized()), translation(t) {}

  // Applies the transform to a point: x_in_target.
  Eigen::Vector3d operator*(const Eigen::Vector3d& x_in_source) const {
    return rotation * x_in_source + translation;
  }
  // Composition: (a_from_b * b_from_c) = a_from_c.
  Rigid3d operator*(const Rigid3d& b_from_c) const {
    return Rigid3d(rotation * b_from_c.rotation, rotation * b_from_c.translation + translation);
  }
  Rigid3d Inverse() const {
    const Eigen::Quaterniond inv = rotation.conjugate();
    return Rigid3d(inv, -(inv * translation));
  }
  // Position of the target frame's origin expressed in the source frame; for cam_from_rig this
  // is the camera's optical centre in the rig frame.
  Eigen::Vector3d TargetOriginInSource() const { return -(rotation.conjugate() * translation); }
  Eigen::Matrix4d ToMatrix() const {
    Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
    m.topLeftCorner<3, 3>() = rotation.toRotationMatrix();
    m.topRightCorner<3, 1>() = translation;
    return m;
  }
  // From a rotation vector (QuaternionFromRotationVector) and a translation: the poses of the
  // command line (`rx ry rz tx ty tz`), of Ceres' angle-axis blocks and of OpenCV's rvec, tvec.
  static Rigid3d FromRotationVector(const Eigen::Vector3d& rotation_vector,
                                    const Eigen::Vector3d& translation) {
    return Rigid3d(QuaternionFromRotationVector(rotation_vector), translation);
  }
  static Rigid3d FromMatrix(const Eigen::Matrix4d& m) {
    return Rigid3d(Eigen::Quaterniond(Eigen::Matrix3d(m.topLeftCorner<3, 3>())),
                   m.topRightCorner<3, 1>());
  }
};

}  // namespace slshadow
