#include "core/pose_io.h"

#include <cmath>

#include <Eigen/Geometry>

#include "core/config.h"

namespace slshadow {

Rigid3d PoseFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys(
      {"rotation_quat_wxyz", "rotation_rvec_rad", "rotation_matrix", "translation_mm"});
  const auto t = node["translation_mm"].AsDoubles(3);
  const int n_rot =
      node.Has("rotation_quat_wxyz") + node.Has("rotation_rvec_rad") + node.Has("rotation_matrix");
  if (n_rot != 1) {
    node.Fail(
        "give exactly one of rotation_quat_wxyz, rotation_rvec_rad (Rodrigues, as OpenCV) or "
        "rotation_matrix");
  }
  Eigen::Quaterniond q;
  if (node.Has("rotation_quat_wxyz")) {
    const auto c = node["rotation_quat_wxyz"];
    const auto v = c.AsDoubles(4);
    q = Eigen::Quaterniond(v[0], v[1], v[2], v[3]);
    if (std::abs(q.norm() - 1.0) > 1e-6) c.Fail("quaternion must have unit norm");
    q.normalize();
  } else if (node.Has("rotation_rvec_rad")) {
    const auto v = node["rotation_rvec_rad"].AsDoubles(3);
    const Eigen::Vector3d r(v[0], v[1], v[2]);
    q = QuaternionFromRotationVector(r);
  } else {
    const auto c = node["rotation_matrix"];
    const auto v = c.AsDoubles(9);
    Eigen::Matrix3d m;
    m << v[0], v[1], v[2], v[3], v[4], v[5], v[6], v[7], v[8];
    // Tolerant enough for matrices pasted with 6 significant digits; re-orthonormalised below.
    if ((m * m.transpose() - Eigen::Matrix3d::Identity()).norm() > 1e-5 || m.determinant() < 0) {
      c.Fail("not a rotation matrix (must be orthonormal with determinant +1, row-major)");
    }
    q = Eigen::Quaterniond(m);
  }
  return Rigid3d(q, Eigen::Vector3d(t[0], t[1], t[2]));
}

nlohmann::json PoseToJson(const Rigid3d& pose) {
  const Eigen::Quaterniond& q = pose.rotation;
  const Eigen::Vector3d& t = pose.translation;
  return {{"rotation_quat_wxyz", {q.w(), q.x(), q.y(), q.z()}},
          {"translation_mm", {t.x(), t.y(), t.z()}}};
}

}  // namespace slshadow
