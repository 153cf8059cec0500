// Global registration of the demo scan's stereo cloud, which has lost its occlusion-edge points to
// stereo's code-jump test (ReconstructOptions::max_code_step_ratio), against the scene's surface
// (the demo part on its 400 x 300 mm table, as `slshadow shadow --part config/demo/scene.yaml`
// registers it). The truth is the identity: the cloud and the reference (the scene's surface) share
// the rig frame.
//
// The table dominates both clouds and fits at any turn about its normal, and the block is nearly
// symmetric under a turn of ~20 deg about it: RANSAC's most supported hypothesis is such a turn
// (docs/benchmarks/log/2026-12-07-shadow-registration.md). The registration must compare its
// hypotheses on the full clouds, not take the most supported one.
#include <cmath>
#include <cstdio>

#include <gtest/gtest.h>

#include "compare/compare.h"
#include "compare/registration.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::compare {
namespace {

TEST(Register, DemoSceneWithoutOcclusionEdgesLandsOnTheTruth) {
  const Scene scene = LoadScene(testing::SourceDir() / "config/demo/scene.yaml");
  const Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  const PatternSpec spec = LoadPatternSpec(testing::SourceDir() / "config/demo/patterns.yaml");
  std::vector<Eigen::Vector3d> cloud;
  {
    // The demo's scan (`slshadow demo`: noise-free), reconstructed in stereo with the library's
    // defaults: the code-jump test on.
    ASSERT_GT(ReconstructOptions{}.max_code_step_ratio, 0);
    const auto images = RenderScan(scene, rig, GeneratePatterns(spec));
    const Reconstruction rec =
        ReconstructStereo(rig, rig.cameras[0].name, rig.cameras[1].name,
                          DecodePatterns(spec, images[0]), DecodePatterns(spec, images[1]));
    cloud = rec.cloud.points;
  }
  ASSERT_GT(cloud.size(), 100000u);
  {
    Eigen::Vector3d lo = cloud[0], hi = cloud[0];
    for (const auto& p : cloud) lo = lo.cwiseMin(p), hi = hi.cwiseMax(p);
    std::printf("cloud %zu points, (%.1f %.1f %.1f) .. (%.1f %.1f %.1f)\n", cloud.size(), lo.x(),
                lo.y(), lo.z(), hi.x(), hi.y(), hi.z());
  }
  // The reference as the shadow builds it: the scene's surface, planes in 16 x 16 cells, 100 k
  // area-uniform samples with face normals.
  const Reference reference = ReferenceFromMesh(SceneSurface(scene, "demo", 16), "demo", 100000);
  std::vector<Eigen::Vector3d> normals;
  for (const auto& n : reference.cloud.normals) normals.push_back(n.cast<double>());
  const auto run = [&](int candidates, unsigned seed = 1) {
    RegistrationOptions o;
    o.seed = seed;
    o.method = RegistrationMethod::kGlobalIcp;
    o.global_candidates = candidates;
    const RegistrationResult r = Register(cloud, reference.cloud.points, normals, o);
    std::printf("%d candidate(s): %s; %.4f deg, %.4f mm from the truth", candidates,
                r.BriefReport().c_str(), RotationDifferenceDeg(r.reference_from_cloud, Rigid3d()),
                r.reference_from_cloud.translation.norm());
    if (r.alternative_fitness >= 0)
      std::printf("; chosen fitness %.4f, best other %.4f (%.1f deg, %.1f mm away)",
                  r.candidate_fitness, r.alternative_fitness, r.alternative_rotation_deg,
                  r.alternative_translation_mm);
    std::printf("\n");
    return r;
  };
  // The most supported hypothesis alone (the registration before the candidates were compared)
  // lands on a turned pose: the case this test is about.
  if (std::getenv("SEEDS"))
    for (unsigned s = 1; s <= 12; ++s) run(1, s);
  const RegistrationResult single = run(1);
  EXPECT_GT(RotationDifferenceDeg(single.reference_from_cloud, Rigid3d()), 5.0);
  // Compared on the full clouds, the true pose wins whatever the seed (with one candidate, 7 of
  // seeds 1-12 land 19-19.4 deg / 70-72 mm or 180 deg off), and a turned pose is the runner-up,
  // clearly worse. ICP on the reference's samples stops within ~0.5 mm along the table (the
  // shadow then refines on the exact surface).
  for (const unsigned seed : {1u, 2u, 4u}) {
    SCOPED_TRACE(seed);
    const RegistrationResult r = run(RegistrationOptions{}.global_candidates, seed);
    EXPECT_TRUE(r.global_found);
    EXPECT_TRUE(r.converged);
    EXPECT_LT(RotationDifferenceDeg(r.reference_from_cloud, Rigid3d()), 0.02);
    EXPECT_LT(r.reference_from_cloud.translation.norm(), 1.0);
    EXPECT_GT(r.fitness, 0.99);
    EXPECT_GT(r.candidate_fitness, 0.98);
    ASSERT_GE(r.alternative_fitness, 0);
    EXPECT_LT(r.alternative_fitness, r.candidate_fitness - 0.05);
    EXPECT_GT(r.alternative_rotation_deg, 5.0);
  }
}

}  // namespace
}  // namespace slshadow::compare
