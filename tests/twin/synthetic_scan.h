// Synthetic "real" scans for the shadow tests: the demo rig at half resolution (960 x 600 cameras,
// the demo patterns: 38 images), the demo part, rendered with known physics.
#pragma once

#include <map>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/config.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "sim/scene.h"
#include "sim/shapes.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"
#include "workflows/twin/twin.h"

namespace slshadow::testing {

inline Rig HalfDemoRig() {
  Rig rig = LoadRig(SourceDir() / "config/demo/rig.yaml");
  for (auto& cam : rig.cameras) {
    auto& m = cam.model;
    m.width /= 2;
    m.height /= 2;
    m.params[CameraModel::kFx] /= 2;
    m.params[CameraModel::kFy] /= 2;
    m.params[CameraModel::kCx] = (m.params[CameraModel::kCx] + 0.5) / 2 - 0.5;
    m.params[CameraModel::kCy] = (m.params[CameraModel::kCy] + 0.5) / 2 - 0.5;
  }
  return rig;
}

inline PatternSpec DemoSpec() {
  return LoadPatternSpec(SourceDir() / "config/patterns/graycode_phase.yaml");
}

// The demo part's pose in the demo scene (config/demo/scene.yaml).
inline Rigid3d DemoPartPose() {
  return Rigid3d(Eigen::Quaterniond(0.17364817766693, -0.98480775301221, 0.0, 0.0),
                 Eigen::Vector3d(0, 10, 545));
}

// The part as the shadow reads a mesh file: one mesh object, albedo 0.8.
inline twin::ShadowPart PartFromMesh(const TriangleMesh& mesh, const std::string& name) {
  twin::ShadowPart part;
  part.source = name;
  SceneObject o;
  o.name = name;
  o.type = ObjectType::kMesh;
  o.mesh = std::make_shared<TriangleMesh>(mesh);
  o.albedo.value = 0.8;
  part.scene.name = name;
  part.scene.objects.push_back(o);
  part.surface = mesh;
  return part;
}

// The "real" physics: exposure x albedo 0.8 x 0.7, a little ambient light, sensor noise.
inline Scene RealScene(const TriangleMesh& mesh, const Rigid3d& rig_from_part) {
  Scene s;
  s.name = "real";
  s.radiometry.exposure_fraction = 0.8;
  s.layers.ambient = 0.03;
  s.layers.noise_enabled = true;
  s.layers.full_well_e = 10000;
  s.layers.read_noise_e = 6;
  s.layers.seed = 12345;
  SceneObject o;
  o.name = "part";
  o.type = ObjectType::kMesh;
  o.mesh = std::make_shared<TriangleMesh>(mesh);
  o.albedo.value = 0.7;
  o.rig_from_object = rig_from_part;
  s.objects.push_back(o);
  return s;
}

inline std::map<std::string, std::vector<cv::Mat>> Render(const Scene& scene, const Rig& rig,
                                                          const PatternSpec& spec) {
  const auto images = RenderScan(scene, rig, GeneratePatterns(spec));
  std::map<std::string, std::vector<cv::Mat>> out;
  for (size_t c = 0; c < rig.cameras.size(); ++c) out[rig.cameras[c].name] = images[c];
  return out;
}

}  // namespace slshadow::testing
