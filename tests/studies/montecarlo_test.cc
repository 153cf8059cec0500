// Study 4 (workflows/studies/montecarlo.h): scan uncertainty by Monte Carlo. Oracles: the sampled
// rigs' parameters have the stated standard deviations; a scan's per-pixel standard uncertainty
// from 400 prediction samples covers an independent set of 400 replicate scans at 2 sigma between
// 90 % and 98 %; the same study through GNU parallel and `sweep study` merges to identical files;
// bad input.
//
// The coverage check can fail: every pixel of a scan shares its rig sample, so the coverage has the
// sampling spread of a standard deviation estimated from the prediction samples and of a share
// estimated from the replicates, not of the pixel count. With 6 samples and 4 replicates it gave
// 50 % on the demo; with 100 and 50 it gave 98.9 % for one of three seeds. With 400 and 400 its
// spread is about 1.3 % around the expected 95 %, so the test uses 400 + 400 scans of a camera
// reduced to 120 x 75 px (the figure depends on the number of rig samples, not of pixels).
#include "workflows/studies/montecarlo.h"

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "tests/studies/sweep_cli.h"
#include "tests/testing/temp_dir.h"
#include "workflows/studies/sweep.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace slshadow::studies {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::SourceDir;
using testing::TempDir;

TEST(MonteCarlo, SampledRigsHaveTheStatedSpread) {
  const Rig rig = LoadRig(SourceDir() / "config/studies/quarter_demo_rig.yaml");
  RigSigma sigma;
  sigma.camera = {0.5, 0.4, 0.3, 0.2, 0.001, 0, 0, 0, 0};
  sigma.projector = {3, 3, 2, 8, 0, 0, 0, 0, 0};
  sigma.rotation_deg = 0.05;
  sigma.translation_mm = 0.1;
  const int n = 4000;
  double s_fx = 0, s_cy_proj = 0, s_tx = 0, s_rot = 0, cam0_moved = 0;
  for (int k = 0; k < n; ++k) {
    const Rig s = SampleRig(rig, sigma, 1000 + static_cast<uint64_t>(k));
    s_fx += std::pow(s.cameras[1].model.fx() - rig.cameras[1].model.fx(), 2);
    s_cy_proj += std::pow(s.projector->model.cy() - rig.projector->model.cy(), 2);
    s_tx += std::pow(
        s.cameras[1].cam_from_rig.translation.x() -
            (s.cameras[1].cam_from_rig.rotation * rig.cameras[1].cam_from_rig.rotation.conjugate() *
             rig.cameras[1].cam_from_rig.translation)
                .x(),
        2);
    s_rot += std::pow(
        s.projector->cam_from_rig.rotation.angularDistance(rig.projector->cam_from_rig.rotation),
        2);
    cam0_moved +=
        (s.cameras[0].cam_from_rig.translation.norm() > 0 ||
         s.cameras[0].cam_from_rig.rotation.angularDistance(Eigen::Quaterniond::Identity()) > 0);
  }
  // Standard deviations within 5 % (4000 samples: the estimate's own spread is ~1.1 %).
  EXPECT_NEAR(std::sqrt(s_fx / n), 0.5, 0.025);
  EXPECT_NEAR(std::sqrt(s_cy_proj / n), 8, 0.4);
  EXPECT_NEAR(std::sqrt(s_tx / n), 0.1, 0.005);
  // The angle of a rotation with N(0, s^2) per axis: E[angle^2] = 3 s^2.
  EXPECT_NEAR(std::sqrt(s_rot / n), std::sqrt(3.0) * 0.05 * M_PI / 180,
              0.05 * std::sqrt(3.0) * 0.05 * M_PI / 180);
  EXPECT_EQ(cam0_moved, 0) << "the first camera is the rig frame";
  // Same seed, same rig.
  EXPECT_EQ(RigToJson(SampleRig(rig, sigma, 7)), RigToJson(SampleRig(rig, sigma, 7)));

  // A covariance in the rig's calibration evidence is used for that device instead.
  Rig with = rig;
  std::vector<double> cov(81, 0.0);
  cov[0] = 4.0;  // var(fx) = 4 px^2
  with.calibration = {{"devices", {{{"name", rig.cameras[0].name}}}},
                      {"intrinsics_covariance", {cov}}};
  double s0 = 0, s_cx = 0;
  std::vector<std::string> used;
  for (int k = 0; k < n; ++k) {
    used.clear();
    const Rig s = SampleRig(with, sigma, 5000 + static_cast<uint64_t>(k), &used);
    s0 += std::pow(s.cameras[0].model.fx() - rig.cameras[0].model.fx(), 2);
    s_cx += std::pow(s.cameras[0].model.cx() - rig.cameras[0].model.cx(), 2);
  }
  EXPECT_EQ(used, std::vector<std::string>{rig.cameras[0].name});
  EXPECT_NEAR(std::sqrt(s0 / n), 2.0, 0.1);
  EXPECT_LT(s_cx, 1e-20);  // no variance of cx in that covariance
}

// The quarter-resolution demo rig with its cameras reduced by `factor` again.
void WriteSmallRig(const fs::path& file, int factor) {
  json rig = RigToJson(LoadRig(SourceDir() / "config/studies/quarter_demo_rig.yaml"));
  for (auto& c : rig["cameras"]) {
    c["width"] = c["width"].get<int>() / factor;
    c["height"] = c["height"].get<int>() / factor;
    for (const char* k : {"fx", "fy"})
      c["intrinsics"][k] = c["intrinsics"][k].get<double>() / factor;
    for (const char* k : {"cx", "cy"})
      c["intrinsics"][k] = (c["intrinsics"][k].get<double>() + 0.5) / factor - 0.5;
  }
  std::ofstream(file) << rig.dump(1);
}

void WriteStudy(const fs::path& file, const fs::path& rig, int samples, int replicates) {
  std::ofstream(file)
      << "format: slshadow-study\nversion: 1\nname: mc\nrig: " << rig.string() << "\n"
      << "modes: [projector]\n"
         "reconstruct: {max_reprojection_error_px: \"inf\", max_epipolar_error_px: \"inf\"}\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6, seed: 1}\n"
         "monte_carlo:\n  samples: "
      << samples << "\n  replicates: " << replicates
      << "\n  seed: 1\n"
         "  sigma:\n    camera: {fx: 0.068, fy: 0.068, cx: 0.028, cy: 0.03}\n"
         "    projector: {fx: 3.1, fy: 3.1, cx: 2.9, cy: 7.9}\n"
         "    rotation_deg: 0.026\n    translation_mm: 0.03\n";
}

std::vector<std::string> SummaryRow(const fs::path& file) {
  std::istringstream in(ReadTextFile(file));
  std::string header, row, cell;
  std::getline(in, header);
  std::getline(in, row);
  std::vector<std::string> cells;
  std::istringstream l(row);
  while (std::getline(l, cell, ',')) cells.push_back(cell);
  return cells;
}

TEST(MonteCarlo, PredictedUncertaintyCoversIndependentReplicateScans) {
  TempDir tmp;
  WriteSmallRig(tmp / "rig.json", 4);
  WriteStudy(tmp / "study.yaml", tmp / "rig.json", 400, 400);
  const SweepPlanSummary plan = PlanSweep(tmp / "study.yaml", tmp / "jobs");
  EXPECT_EQ(plan.jobs, 800);
  EXPECT_EQ(plan.geometry_groups, 1);
  RunSweepShard(tmp / "jobs", SweepRunOptions{});
  const SweepMergeSummary m = MergeSweep(tmp / "jobs", tmp / "result");
  ASSERT_EQ(m.uncertainty.size(), 2u);
  const auto s = SummaryRow(tmp / "result/uncertainty_summary.csv");
  ASSERT_EQ(s.size(), 9u);
  SCOPED_TRACE(m.uncertainty[0] + "\n" + m.uncertainty[1]);
  std::printf("%s\n%s\n", m.uncertainty[0].c_str(), m.uncertainty[1].c_str());  // in the test log
  EXPECT_GT(std::stoi(s[0]), 5000);  // pixels with a point in every job (of 9000)
  const double median_u = std::stod(s[3]), coverage = std::stod(s[6]), ratio = std::stod(s[8]);
  EXPECT_GT(median_u, 0.01);
  EXPECT_GE(coverage, 0.90);
  EXPECT_LE(coverage, 0.98);
  EXPECT_EQ(s[7], "1");
  // The replicates' own spread agrees with the prediction (400 each: ~3.5 % per pixel).
  EXPECT_GT(ratio, 0.9);
  EXPECT_LT(ratio, 1.1);
  for (const char* f : {"uncertainty.ply", "uncertainty.png", "uncertainty.csv"})
    EXPECT_TRUE(fs::exists(tmp / "result" / f)) << f;
  EXPECT_NE(ReadTextFile(tmp / "result/uncertainty.ply").find("property float u_mm"),
            std::string::npos);
}

TEST(MonteCarlo, GnuParallelShardsMergeToTheOneProcessResult) {
  ASSERT_EQ(std::system("parallel --version > /dev/null 2>&1"), 0)
      << "GNU parallel is not installed (scripts/setup.sh installs it)";
  TempDir tmp;
  WriteSmallRig(tmp / "rig.json", 2);
  WriteStudy(tmp / "study.yaml", tmp / "rig.json", 3, 2);
  PlanSweep(tmp / "study.yaml", tmp / "one");
  RunSweepShard(tmp / "one", SweepRunOptions{});
  MergeSweep(tmp / "one", tmp / "one_result");
  const std::string bin = SLSHADOW_BINARY;
  ASSERT_EQ(testing::SweepThroughGnuParallel(bin, tmp / "study.yaml", tmp / "par",
                                             tmp / "par_result", "2 0 1", 3),
            "");
  // `sweep study`: plan, run and merge in one command; run again, it resumes (nothing to run).
  const std::string whole = bin + " sweep study " + (tmp / "study.yaml").string() + " --out " +
                            (tmp / "whole").string() + " > " + (tmp / "whole.log").string();
  ASSERT_EQ(std::system(whole.c_str()), 0) << whole;
  ASSERT_EQ(std::system(whole.c_str()), 0) << whole;
  EXPECT_NE(ReadTextFile(tmp / "whole.log").find("resuming"), std::string::npos);
  EXPECT_NE(ReadTextFile(tmp / "whole.log").find("0 run"), std::string::npos);
  for (const char* f : {"results.csv", "results.json", "uncertainty.csv", "uncertainty_summary.csv",
                        "uncertainty.ply"}) {
    EXPECT_EQ(ReadTextFile(tmp / "one_result" / f), ReadTextFile(tmp / "par_result" / f)) << f;
    EXPECT_EQ(ReadTextFile(tmp / "one_result" / f), ReadTextFile(tmp / "whole" / f)) << f;
  }
}

TEST(MonteCarlo, BadInputNamesTheField) {
  const Rig rig = LoadRig(SourceDir() / "config/studies/quarter_demo_rig.yaml");
  const auto fails_with = [&](const std::string& yaml, const std::string& expected) {
    try {
      MonteCarloStudyFromConfig(ConfigNode::ParseYaml(yaml, "s.yaml")["monte_carlo"], rig);
      ADD_FAILURE() << "accepted: " << yaml;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  fails_with("monte_carlo: {samples: 1, replicates: 3}\n", "monte_carlo.samples");
  fails_with("monte_carlo: {samples: 5, replicates: 0}\n", "monte_carlo.replicates");
  fails_with("monte_carlo: {samples: 5, replicates: 2, sigma: {camera: {fx: -1}}}\n",
             "monte_carlo.sigma.camera.fx");
  fails_with("monte_carlo: {samples: 5, replicates: 2, sigma: {camera: {f: 1}}}\n", "f");
  fails_with("monte_carlo: {samples: 5, replicates: 2, sigma: {camera: {fx: 1e6}}}\n",
             "a sampled rig is not valid");
}

}  // namespace
}  // namespace slshadow::studies
