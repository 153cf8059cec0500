// export_bench_part: writes the scene of sim_bench's 1 M-triangle workload
// (BM_PaperWorkloadWritten) for the same-run peer in bench/paper_peer/ (docs/benchmarks.md). Not a
// test.
//
//   export_bench_part SOURCE_DIR OUT_DIR [TRIANGLES=1000000]
//
// Loads SOURCE_DIR/config/demo/scene.yaml and SOURCE_DIR/config/demo/rig.yaml, re-tessellates the
// demo part as sim_bench's DemoScene does (DemoPartResolutionFor(TRIANGLES)), and writes in
// OUT_DIR, all in the rig frame (mm):
//   part.ply          the posed part (binary PLY, core's WriteMesh)
//   table.ply         the table plane as two triangles (when the scene has a plane object)
//   scene.txt         one line per object: name, file, albedo; then exposure and d_ref
//   silhouette_<camera>.pgm  8-bit mask, 255 where slshadow's ray caster sees the part first
//                     (the oracle for the peer's hole fraction)
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <memory>
#include <string>

#include <opencv2/imgcodecs.hpp>

#include "core/error.h"
#include "core/mesh.h"
#include "core/rig.h"
#include "sim/raycaster.h"
#include "sim/renderer.h"
#include "sim/scene.h"
#include "sim/shapes.h"

namespace slshadow {
namespace {

TriangleMesh Posed(TriangleMesh mesh, const Rigid3d& rig_from_object) {
  mesh.Transform(rig_from_object.rotation.toRotationMatrix(), rig_from_object.translation);
  return mesh;
}

int Run(int argc, char** argv) {
  if (argc < 3 || argc > 4) {
    std::cerr << "usage: export_bench_part SOURCE_DIR OUT_DIR [TRIANGLES=1000000]\n";
    return 2;
  }
  const std::filesystem::path source = argv[1];
  const std::filesystem::path out = argv[2];
  const double triangles = argc == 4 ? std::stod(argv[3]) : 1e6;
  std::filesystem::create_directories(out);

  Scene scene = LoadScene(source / "config/demo/scene.yaml");
  const Rig rig = LoadRig(source / "config/demo/rig.yaml");
  SLSHADOW_THROW_IF(scene.objects.empty() || scene.objects[0].type != ObjectType::kMesh,
                    "config/demo/scene.yaml: the first object is not a mesh");
  scene.objects[0].mesh =
      std::make_shared<const TriangleMesh>(MakeDemoPart(DemoPartResolutionFor(triangles)));

  std::ofstream list(out / "scene.txt");
  const SceneObject& part = scene.objects[0];
  WriteMesh(out / "part.ply", Posed(*part.mesh, part.rig_from_object));
  list << part.name << " part.ply " << part.albedo.value << "\n";
  std::cout << "part: " << part.mesh->NumTriangles() << " triangles, " << part.mesh->vertices.size()
            << " vertices, area " << part.mesh->SurfaceArea() << " mm^2\n";
  for (size_t i = 1; i < scene.objects.size(); ++i) {
    const SceneObject& o = scene.objects[i];
    if (o.type != ObjectType::kPlane) continue;
    const double hx = o.size_mm.x() / 2, hy = o.size_mm.y() / 2;
    TriangleMesh plane;
    plane.vertices = {{-hx, -hy, 0}, {hx, -hy, 0}, {hx, hy, 0}, {-hx, hy, 0}};
    plane.triangles = {{0, 1, 2}, {0, 2, 3}};
    const std::string file = o.name + ".ply";
    WriteMesh(out / file, Posed(plane, o.rig_from_object));
    list << o.name << " " << file << " " << o.albedo.value << "\n";
    const Eigen::Vector3d n = o.rig_from_object.rotation * Eigen::Vector3d::UnitZ();
    std::cout << "plane " << o.name << ": " << o.size_mm.x() << " x " << o.size_mm.y()
              << " mm, centre " << o.rig_from_object.translation.transpose() << ", normal "
              << n.transpose() << "\n";
  }
  const double d_ref = scene.radiometry.reference_distance_mm > 0
                           ? scene.radiometry.reference_distance_mm
                           : rig.working_distance_mm;
  list << "exposure " << scene.radiometry.exposure_fraction << "\nreference_distance_mm " << d_ref
       << "\n";

  // The part's silhouette per camera from slshadow's own geometry pass (object id 0 first hit).
  const RayCaster caster(scene);
  for (int c = 0; c < static_cast<int>(rig.cameras.size()); ++c) {
    const CameraRays rays = ComputeCameraRays(rig.cameras[c].model, 1);
    const GeometryBuffer g = TraceGeometry(caster, rig, c, rays);
    cv::Mat mask = g.object_id == 0;
    const std::filesystem::path file = out / ("silhouette_" + rig.cameras[c].name + ".pgm");
    SLSHADOW_THROW_IF(!cv::imwrite(file.string(), mask), "cannot write " + file.string());
    std::cout << "silhouette " << rig.cameras[c].name << ": " << cv::countNonZero(mask) << " px\n";
  }
  return 0;
}

}  // namespace
}  // namespace slshadow

int main(int argc, char** argv) {
  try {
    return slshadow::Run(argc, argv);
  } catch (const std::exception& e) {
    std::cerr << "export_bench_part: " << e.what() << "\n";
    return 1;
  }
}
