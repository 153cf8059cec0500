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

// A turntable's rotation axis in the rig frame (docs/formats.md "Rig YAML", `turntable`), as
// `slshadow calibrate turntable` measures it. A commanded table angle a (degrees) turns the part
// by the true angle  angle_deg(a) = angle_scale * a + angle_offset_deg  about the axis through
// point_in_rig_mm with unit direction direction_in_rig, right-handed (positive angles turn
// counter-clockwise seen from the tip of direction_in_rig looking back at the table).
// The sigma_* fields are 1-sigma uncertainties (0: unknown): the direction's as an angle.
struct TurntableAxis {
  Eigen::Vector3d direction_in_rig = Eigen::Vector3d::UnitY();  // unit
  Eigen::Vector3d point_in_rig_mm = Eigen::Vector3d::Zero();    // any point on the axis
  double angle_offset_deg = 0.0;
  double angle_scale = 1.0;
  double sigma_direction_deg = 0.0;
  double sigma_point_mm = 0.0;  // perpendicular to the axis
  double sigma_angle_offset_deg = 0.0;
  double sigma_angle_scale = 0.0;

  double TrueAngleDeg(double commanded_deg) const {
    return angle_scale * commanded_deg + angle_offset_deg;
  }
  // The rigid motion of a part on the table commanded to `commanded_deg`, from its placement at
  // commanded angle 0: x_at_angle = RigFromTableTurn(a) * x_at_zero, both in the rig frame.
  Rigid3d RigFromTableTurn(double commanded_deg) const;
};

struct Rig {
  std::string name;
  double working_distance_mm = 500;  // nominal stand-off along the first camera's axis
  std::vector<RigDevice> cameras;
  std::optional<RigDevice> projector;
  // Free-form evidence kept with the rig (e.g. calibration inputs and covariance), round-tripped
  // untouched. Empty when absent.
  nlohmann::json calibration;
  std::optional<TurntableAxis> turntable;  // the table's axis when the rig has one

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
