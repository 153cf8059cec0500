// workflows/studies/sweep_job.cc (internal to workflows/studies/): the geometry group of a job and
// the runner that keeps a group's simulator from one job to the next. Oracles: which settings
// change geometry (the Simulator's inputs) and which do not; a job run after another of its group
// gives the figures a fresh runner gives (reuse changes nothing but time).
#include "workflows/studies/internal/sweep_job.h"

#include <fstream>
#include <string>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/file_util.h"
#include "tests/testing/temp_dir.h"
#include "workflows/studies/internal/sweep_files.h"
#include "workflows/studies/sweep.h"

namespace slshadow::studies::internal {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

// 2 noise seeds x 2 triangulation methods on the quarter-resolution demo rig (sweep_test's small
// study): 4 jobs of one geometry group.
fs::path PlanSmallStudy(const testing::TempDir& tmp) {
  std::ofstream(tmp / "study.yaml")
      << "format: slshadow-study\nversion: 1\nname: small\n"
      << "rig: " << (testing::SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "modes: [projector, stereo]\n"
         "compare: {threshold_mm: 0.5}\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6}\n"
         "axes:\n"
         "  - {name: seed, set: scene.layers.noise.seed, values: [11, 12]}\n"
         "  - {name: method, set: reconstruct.method, values: [midpoint, optimal]}\n";
  PlanSweep(tmp / "study.yaml", tmp / "jobs");
  return tmp / "jobs";
}

json Job(const fs::path& jobs, int id) {
  return json::parse(ReadTextFile(jobs / "jobs" / (JobName(id) + ".json")));
}

TEST(GeometryKey, OnlyWhatTheSimulatorsGeometryDependsOnSplitsGroups) {
  testing::TempDir tmp;
  const fs::path jobs = PlanSmallStudy(tmp);
  const json job = Job(jobs, 0);
  const std::string key = GeometryKey(job);
  for (int id = 1; id < 4; ++id) EXPECT_EQ(GeometryKey(Job(jobs, id)), key) << "job " << id;
  // Radiometry, the scene's name, the noise and other layers: rendered per job, same geometry.
  json same = job;
  same["scene"]["name"] = "renamed";
  same["scene"]["radiometry"] = {{"ambient", 0.3}};
  same["scene"]["layers"]["noise"]["seed"] = 99;
  same["reconstruct"] = {{"method", "dlt"}};
  EXPECT_EQ(GeometryKey(same), key);
  // What the Simulator traces: supersampling, projector defocus, the rig, the scene's objects and
  // where its files are found.
  json other = job;
  other["scene"]["layers"]["supersampling"] = 2;
  EXPECT_NE(GeometryKey(other), key);
  other = job;
  other["scene"]["layers"]["projector_defocus"] = {{"sigma_px", 1.0}};
  EXPECT_NE(GeometryKey(other), key);
  other = job;
  other["scene_base_dir"] = "/elsewhere";
  EXPECT_NE(GeometryKey(other), key);
  other = job;
  other["rig"]["name"] = job["rig"].value("name", std::string()) + " moved";
  EXPECT_NE(GeometryKey(other), key);
  other = job;
  other["scene"]["objects"] = json::array();
  EXPECT_NE(GeometryKey(other), key);
}

// Two jobs of one group on one runner trace the geometry once; the second job's figures equal
// those of a fresh runner that traced for it alone.
TEST(SweepJobRunner, AGroupsSecondJobReusesTheGeometryAndMatchesAFreshRun) {
  testing::TempDir tmp;
  const fs::path jobs = PlanSmallStudy(tmp);
  SweepJobRunner runner;
  const json first = runner.Run(Job(jobs, 0), jobs / "jobs/000000.json", 2);
  const json second = runner.Run(Job(jobs, 3), jobs / "jobs/000003.json", 1);
  EXPECT_EQ(runner.geometry_traces(), 1);
  EXPECT_EQ(first["id"], 0);
  EXPECT_EQ(second["id"], 3);
  ASSERT_EQ(second["modes"].size(), 2u);
  SweepJobRunner fresh;
  const json alone = fresh.Run(Job(jobs, 3), jobs / "jobs/000003.json", 1);
  EXPECT_EQ(fresh.geometry_traces(), 1);
  EXPECT_EQ(alone["modes"], second["modes"]);
  EXPECT_EQ(alone["params"], second["params"]);
  // Different seeds, different noise: not the same figures.
  EXPECT_NE(first["modes"][0]["rms_mm"], second["modes"][0]["rms_mm"]);
}

}  // namespace
}  // namespace slshadow::studies::internal
