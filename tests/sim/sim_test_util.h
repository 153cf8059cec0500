// Fixtures shared by the sim tests: the demo rig scaled down (fast), flat projector images.
#pragma once

#include <cmath>
#include <limits>

#include <opencv2/core.hpp>

#include "core/rig.h"
#include "sim/geometry_pass.h"
#include "sim/raycaster.h"
#include "sim/scene.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::testing {

// The demo rig with every device's resolution divided by `divisor` (same fields of view).
inline Rig SmallDemoRig(int divisor = 8) {
  Rig rig = LoadRig(SourceDir() / "config/demo/rig.yaml");
  auto scale = [&](CameraModel& m) {
    const double f = 1.0 / divisor;
    m.width /= divisor;
    m.height /= divisor;
    m.params[CameraModel::kFx] *= f;
    m.params[CameraModel::kFy] *= f;
    m.params[CameraModel::kCx] = (m.params[CameraModel::kCx] + 0.5) * f - 0.5;
    m.params[CameraModel::kCy] = (m.params[CameraModel::kCy] + 0.5) * f - 0.5;
  };
  for (auto& c : rig.cameras) scale(c.model);
  scale(rig.projector->model);
  return rig;
}

inline cv::Mat FlatProjectorImage(const Rig& rig, int value) {
  return cv::Mat(rig.projector->model.height, rig.projector->model.width, CV_8UC1,
                 cv::Scalar(value));
}

inline SceneObject MakePrimitive(ObjectType type, const Rigid3d& rig_from_object,
                                 double albedo = 0.8) {
  SceneObject o;
  o.name = ToString(type);
  o.type = type;
  o.rig_from_object = rig_from_object;
  o.albedo.value = albedo;
  return o;
}

inline Rigid3d Pose(const Eigen::Vector3d& axis_angle_rad, const Eigen::Vector3d& t) {
  const double a = axis_angle_rad.norm();
  return Rigid3d(a > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(a, axis_angle_rad / a))
                       : Eigen::Quaterniond::Identity(),
                 t);
}

// Both NaN, or equal.
inline bool SameFloat(float a, float b) { return (std::isnan(a) && std::isnan(b)) || a == b; }

// Traces camera `camera` of `rig` in `scene` (its supersampling).
inline GeometryBuffer Trace(const Scene& scene, const Rig& rig, int camera,
                            TraceMode mode = TraceMode::kPacket16) {
  const RayCaster caster(scene);
  const CameraRays rays =
      ComputeCameraRays(rig.cameras[static_cast<size_t>(camera)].model, scene.layers.supersampling);
  return TraceGeometry(caster, rig, camera, rays, mode);
}

// A 600 x 400 mm plane at `pose`.
inline Scene PlaneScene(const Rigid3d& pose, double albedo = 0.6) {
  Scene scene;
  SceneObject plane = MakePrimitive(ObjectType::kPlane, pose, albedo);
  plane.size_mm = Eigen::Vector3d(600, 400, 0);
  scene.objects.push_back(plane);
  return scene;
}

}  // namespace slshadow::testing
