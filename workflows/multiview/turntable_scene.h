// The simulator's turntable: a scene placed on a rotating table, as the rig's turntable axis
// (core/rig.h TurntableAxis) turns it, so that multi-view scans of a part run without hardware.
// The table is a disc (an exact cylinder, sim/scene.h kCylinder) in the scene; the part is every
// mesh of the scene, and only the part is what a comparison with the CAD model reads
// (PartSurface).
//
// Frames and units: rig frame, mm, degrees for table angles. A scene is given at commanded table
// angle 0; its objects' rig_from_object at angle 0 are their poses in the part frame
// (workflows/multiview/views.h).
#pragma once

#include <string>
#include <vector>

#include "core/mesh.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "sim/scene.h"

namespace slshadow::multiview {

// The table: a disc centred on the axis, its top face perpendicular to the axis, gap_mm below the
// axis point (along -direction_in_rig: the axis direction points up, away from the table).
struct TableDisc {
  std::string name = "turntable";
  double radius_mm = 110;
  double thickness_mm = 10;
  double gap_mm = 0.05;  // between the axis point (the part's base) and the disc's top
  double albedo = 0.4;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// `scene` with the disc added as its last object. The scene's source config is cleared (the scene
// is now built in code). Throws on an invalid disc or a name already taken.
Scene WithTableDisc(Scene scene, const TurntableAxis& axis, const TableDisc& disc = {});

// The scene moved rigidly by rig_from_part: every object but those named in `fixed_objects`
// (e.g. a background that does not turn) gets rig_from_object' = rig_from_part * rig_from_object,
// and the point and direction values of their artefacts (scene.artefacts[object]: keys ending in
// "_in_rig_mm" and "_in_rig") move with them. The source config is cleared (built in code).
// Throws slshadow::Error when a fixed object name is not in the scene.
Scene MoveScene(const Scene& scene, const Rigid3d& rig_from_part,
                const std::vector<std::string>& fixed_objects = {});

// The scene at commanded table angle `commanded_deg`: MoveScene by axis.RigFromTableTurn.
Scene SceneAtTableAngle(const Scene& scene, const TurntableAxis& axis, double commanded_deg,
                        const std::vector<std::string>& fixed_objects = {});

// The part, i.e. the scene's meshes, in the rig frame of the scene as given (the part frame for a
// scene at table angle 0): the CAD model a multi-view scan is compared with. Throws when the scene
// has no mesh.
TriangleMesh PartSurface(const Scene& scene);

// The axis along an object's local +z through its local origin: for the demo part (base at z = 0,
// top towards +z) the table normal through the centre of its footprint.
TurntableAxis AxisUnderObject(const SceneObject& object);

// The demo on a turntable: the embedded demo rig (config/demo/rig.yaml) with the axis under the
// demo part (AxisUnderObject of its object "part": the normal of its table, tilted 20 degrees
// towards the cameras' y axis, through the centre of the part's footprint, 545 mm in front of the
// left camera) and the demo scene (config/demo/scene.yaml) with its fixed table plane ("table")
// replaced by a disc of radius 110 mm under the part. `rig` and `scene` replace the embedded ones
// when given: the scene's object `part_object` carries the axis and `remove_objects` are dropped.
struct TurntableSetup {
  Rig rig;      // with rig.turntable set
  Scene scene;  // at commanded angle 0, with the disc
};
TurntableSetup MakeTurntableSetup(Rig rig, Scene scene, const std::string& part_object = "part",
                                  const std::vector<std::string>& remove_objects = {"table"},
                                  const TableDisc& disc = {});
// The embedded demo rig and scene through MakeTurntableSetup.
TurntableSetup DemoTurntableSetup();

}  // namespace slshadow::multiview
