#include "workflows/multiview/turntable_scene.h"
#include "sim/scene_surface.h"

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {

namespace {

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() &&
         s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

bool IsVector3(const nlohmann::json& j) {
  return j.is_array() && j.size() == 3 &&
         std::all_of(j.begin(), j.end(), [](const nlohmann::json& v) { return v.is_number(); });
}

nlohmann::json Moved(const nlohmann::json& v, const Rigid3d& motion, bool is_point) {
  const Eigen::Vector3d x(v[0].get<double>(), v[1].get<double>(), v[2].get<double>());
  const Eigen::Vector3d y =
      is_point ? Eigen::Vector3d(motion * x) : Eigen::Vector3d(motion.rotation * x);
  return {y.x(), y.y(), y.z()};
}

// Moves the point ("_in_rig_mm") and direction ("_in_rig") values of one artefact record.
void MoveArtefact(nlohmann::json& record, const Rigid3d& motion) {
  if (!record.is_object()) return;
  for (auto it = record.begin(); it != record.end(); ++it) {
    const bool point = EndsWith(it.key(), "_in_rig_mm");
    const bool direction = !point && EndsWith(it.key(), "_in_rig");
    if (!point && !direction) continue;
    nlohmann::json& v = it.value();
    if (IsVector3(v)) {
      v = Moved(v, motion, point);
    } else if (v.is_array()) {
      for (auto& e : v) {
        if (IsVector3(e)) e = Moved(e, motion, point);
      }
    }
  }
}

}  // namespace

void TableDisc::Check() const {
  SLSHADOW_THROW_IF(name.empty(), "table disc: name must not be empty");
  SLSHADOW_THROW_IF(!(radius_mm > 0) || !std::isfinite(radius_mm),
                    "table disc: radius_mm must be positive (got ", radius_mm, ")");
  SLSHADOW_THROW_IF(!(thickness_mm > 0) || !std::isfinite(thickness_mm),
                    "table disc: thickness_mm must be positive (got ", thickness_mm, ")");
  SLSHADOW_THROW_IF(!(gap_mm >= 0) || !std::isfinite(gap_mm),
                    "table disc: gap_mm must be >= 0 (got ", gap_mm, ")");
  SLSHADOW_THROW_IF(!(albedo >= 0 && albedo <= 1), "table disc: albedo must be in [0, 1] (got ",
                    albedo, ")");
}

Scene WithTableDisc(Scene scene, const TurntableAxis& axis, const TableDisc& disc) {
  disc.Check();
  for (const SceneObject& o : scene.objects) {
    SLSHADOW_THROW_IF(o.name == disc.name, "table disc: the scene already has an object named '",
                      disc.name, "'");
  }
  const Eigen::Vector3d up = axis.direction_in_rig.normalized();
  SceneObject o;
  o.name = disc.name;
  o.type = ObjectType::kCylinder;
  o.radius_mm = disc.radius_mm;
  o.height_mm = disc.thickness_mm;
  o.albedo.value = disc.albedo;
  o.rig_from_object = Rigid3d(Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), up),
                              axis.point_in_rig_mm - up * (disc.gap_mm + disc.thickness_mm / 2));
  scene.objects.push_back(std::move(o));
  scene.source_config = nullptr;
  return scene;
}

Scene MoveScene(const Scene& scene, const Rigid3d& rig_from_part,
                const std::vector<std::string>& fixed_objects) {
  for (const std::string& name : fixed_objects) {
    const bool found = std::any_of(scene.objects.begin(), scene.objects.end(),
                                   [&](const SceneObject& o) { return o.name == name; });
    SLSHADOW_THROW_IF(!found, "scene '", scene.name, "': no object named '", name,
                      "' to keep fixed");
  }
  Scene moved = scene;
  for (SceneObject& o : moved.objects) {
    if (std::find(fixed_objects.begin(), fixed_objects.end(), o.name) != fixed_objects.end())
      continue;
    o.rig_from_object = rig_from_part * o.rig_from_object;
    if (moved.artefacts.is_object() && moved.artefacts.contains(o.name))
      MoveArtefact(moved.artefacts[o.name], rig_from_part);
  }
  moved.source_config = nullptr;
  return moved;
}

Scene SceneAtTableAngle(const Scene& scene, const TurntableAxis& axis, double commanded_deg,
                        const std::vector<std::string>& fixed_objects) {
  return MoveScene(scene, axis.RigFromTableTurn(commanded_deg), fixed_objects);
}

TriangleMesh PartSurface(const Scene& scene) {
  TriangleMesh part = SceneMeshSurface(scene);
  SLSHADOW_THROW_IF(part.empty(), "scene '", scene.name,
                    "': has no mesh, so no part to compare with its CAD model");
  return part;
}

TurntableAxis AxisUnderObject(const SceneObject& object) {
  TurntableAxis axis;
  axis.direction_in_rig = (object.rig_from_object.rotation * Eigen::Vector3d::UnitZ()).normalized();
  axis.point_in_rig_mm = object.rig_from_object.translation;
  return axis;
}

TurntableSetup MakeTurntableSetup(Rig rig, Scene scene, const std::string& part_object,
                                  const std::vector<std::string>& remove_objects,
                                  const TableDisc& disc) {
  const auto part = std::find_if(scene.objects.begin(), scene.objects.end(),
                                 [&](const SceneObject& o) { return o.name == part_object; });
  SLSHADOW_THROW_IF(part == scene.objects.end(), "scene '", scene.name, "': no object named '",
                    part_object, "' to stand on the turntable");
  const TurntableAxis axis = AxisUnderObject(*part);
  for (const std::string& name : remove_objects) {
    const auto it = std::find_if(scene.objects.begin(), scene.objects.end(),
                                 [&](const SceneObject& o) { return o.name == name; });
    SLSHADOW_THROW_IF(it == scene.objects.end(), "scene '", scene.name, "': no object named '",
                      name, "' to remove");
    if (scene.artefacts.is_object()) scene.artefacts.erase(name);
    scene.objects.erase(it);
  }
  TurntableSetup setup;
  rig.turntable = axis;
  rig.Check("turntable rig");
  setup.rig = std::move(rig);
  setup.scene = WithTableDisc(std::move(scene), axis, disc);
  setup.scene.Check("turntable scene");
  return setup;
}

TurntableSetup DemoTurntableSetup() {
  return MakeTurntableSetup(pipeline::LoadRigOrDemo(""), pipeline::LoadSceneOrDemo(""));
}

}  // namespace slshadow::multiview
