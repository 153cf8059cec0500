// A structured-light rig: named cameras and at most one projector, each a CameraModel with its
// cam_from_rig pose. The rig frame is the first camera's frame (DESIGN.md). Units: mm, rad, px.
//
// The rig is stored as YAML (config/demo/rig.yaml, docs/formats.md "Rig YAML") and embedded as
// the same tree in JSON in every ImageSet manifest.
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/camera_model.h"
#include "core/rigid3.h"

namespace slshadow {

class ConfigNode;

struct RigDevice {
  std::string name;
  CameraModel model;
  Rigid3d cam_from_rig;  // maps rig-frame points into this device's frame

  // Optical centre in the rig frame.
  Eigen::Vector3d CenterInRig() const { return cam_from_rig.TargetOriginInSource(); }
  // Optical axis (+z of the device) in the rig frame.
  Eigen::Vector3d AxisInRig() const {
    return cam_from_rig.rotation.conjugate() * Eigen::Vector3d::UnitZ();
  }
};

struct Rig {
  std::string name;
  double working_distance_mm = 500;  // nominal stand-off along the first camera's axis
  std::vector<RigDevice> cameras;
  std::optional<RigDevice> projector;
  // Free-form evidence kept with the rig (e.g. calibration inputs and covariance), round-tripped
  // untouched. Empty when absent.
  nlohmann::json calibration;

  // Device by name; throws slshadow::Error listing the known names when absent.
  const RigDevice& Camera(const std::string& name) const;
  int CameraIndex(const std::string& name) const;  // -1 when absent
  // Any device (camera or "projector" name) by name.
  const RigDevice& Device(const std::string& name) const;

  // Distance between two devices' optical centres, mm.
  double BaselineMm(const RigDevice& a, const RigDevice& b) const;
  // The point on the first camera's optical axis at the working distance, in the rig frame.
  Eigen::Vector3d WorkingPointInRig() const;
  // Angle between the rays from two devices' centres to a point, rad.
  static double TriangulationAngleRad(const RigDevice& a, const RigDevice& b,
                                      const Eigen::Vector3d& point_in_rig);
  // Fraction of device a's image whose rays, cut with the plane z = working distance (rig frame),
  // land inside device b's image. Sampled on a grid of `samples` x `samples` pixels.
  double OverlapAtWorkingDistance(const RigDevice& a, const RigDevice& b, int samples = 64) const;

  // Throws slshadow::Error (naming `what`) on duplicate names, no cameras, invalid models,
  // non-finite poses or a non-positive working distance.
  void Check(const std::string& what) const;
};

// Reading and writing. The YAML and JSON trees are identical (docs/formats.md).
Rig RigFromConfig(const ConfigNode& node);
nlohmann::json RigToJson(const Rig& rig);
Rig LoadRig(const std::filesystem::path& path);                   // .yaml/.yml/.json
void SaveRig(const Rig& rig, const std::filesystem::path& path);  // atomically; YAML unless .json

// Human-readable geometry summary (what `slshadow rig show` prints).
std::string DescribeRig(const Rig& rig);

}  // namespace slshadow
