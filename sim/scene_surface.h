// The surfaces of a scene that the workflows compare against (its ground truth in the rig frame),
// and the lit visible surface of a traced camera: what the demo, the sweeps, the twin and the
// multi-view comparison measure a reconstruction with.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "sim/geometry_pass.h"
#include "sim/scene.h"

namespace slshadow {

// The ground-truth surface of the scene's meshes and planes in the rig frame. Other object
// types (exact primitives, clouds) would need their exact surfaces: a scene with them is rejected,
// naming `what`, the object and its type.
// Planes are split into plane_cells x plane_cells squares (two triangles each), so samples and
// C2M spread over the whole plane; 1 keeps the two triangles of the demo.
TriangleMesh SceneSurface(const Scene& scene, const std::string& what, int plane_cells = 1);
// The scene's meshes only, in the rig frame (other objects, e.g. the demo's table, left out).
TriangleMesh SceneMeshSurface(const Scene& scene);

// Points of the surface the camera sees lit by the projector (geometry.visibility == 2), every
// second pixel in x and y, from the pixel-centre ground truth.
std::vector<Eigen::Vector3d> LitVisibleSurface(const GeometryBuffer& geometry);

// The ground-truth surface of a scene in the rig frame: meshes and planes as SceneSurface gives
// them; exact spheres and cylinders (also those of a ball bar) tessellated finely enough that
// their true surface lies within 0.5 um of the mesh (UV spheres of 512 segments, cylinders of 512
// sides with caps; sim/shapes.h MakeSphereMesh). Throws slshadow::Error naming `what` and the
// object for other types (point clouds). Boxes are exact (12 triangles).
TriangleMesh GroundTruthSurface(const Scene& scene, const std::string& what);

}  // namespace slshadow
