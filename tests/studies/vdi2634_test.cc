// Study 5 (workflows/studies/vdi2634.h): the placements of the virtual VDI/VDE 2634-2 test through
// the measuring volume (geometry oracles: inside the volume, seen by every device, the space
// diagonals), a small study scanned end to end (figures of noise-free scans near zero, figures
// that grow with sensor noise, the overall figures recomputed from the per-position ones), the same
// study through GNU parallel equal byte for byte, and bad input.
#include "workflows/studies/vdi2634.h"

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "tests/studies/sweep_cli.h"
#include "tests/testing/temp_dir.h"
#include "workflows/studies/sweep.h"

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace slshadow::studies {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::SourceDir;
using testing::TempDir;

Rig QuarterRig() { return LoadRig(SourceDir() / "config/studies/quarter_demo_rig.yaml"); }

Vdi2634Study StudyFrom(const std::string& yaml, const Rig& rig) {
  const ConfigNode node = ConfigNode::ParseYaml(yaml, "study.yaml");
  return Vdi2634StudyFromConfig(node["vdi2634"], rig, {"projector", "stereo"});
}

Eigen::Vector3d V(const json& j) {
  return {j[0].get<double>(), j[1].get<double>(), j[2].get<double>()};
}

bool InVolume(const MeasuringVolume& v, const Eigen::Vector3d& p) {
  return ((p - v.center_mm).cwiseAbs() - 0.5 * v.size_mm).maxCoeff() <= 1e-6;
}

TEST(Vdi2634Study, PlacementsFollowTheGuidelinesSchemeInsideTheVolume) {
  const Rig rig = QuarterRig();
  const Vdi2634Study s = StudyFrom("vdi2634: {}\n", rig);
  const MeasuringVolume& v = s.volume;
  ASSERT_TRUE(s.volume_from_rig);
  // Every device sees the volume; 10 % larger (the 90 % margin) some device does not.
  const auto devices = StudyDevices(rig, {"projector", "stereo"});
  ASSERT_EQ(devices.size(), 3u);
  EXPECT_EQ(VolumeVisibilityProblem(v, devices), "");
  MeasuringVolume larger = v;
  larger.size_mm *= 1.0 / 0.9 * 1.05;
  EXPECT_NE(VolumeVisibilityProblem(larger, devices), "");
  EXPECT_EQ(v.size_mm.z(), std::floor(v.size_mm.z()));
  const double l0 = v.DiagonalMm();

  int spheres = 0, bars = 0, planes = 0;
  std::vector<Eigen::Vector3d> directions;
  for (const auto& p : s.placements) {
    const json& g = p.geometry;
    if (p.artefact == "sphere") {
      ++spheres;
      const double r = g["diameter_mm"].get<double>() / 2;
      EXPECT_NEAR(2 * r, std::round(0.1 * l0 * 10) / 10, 1e-9);
      // The whole sphere inside the volume, at the centre or touching three faces (a corner).
      const Eigen::Vector3d c = V(g["center_mm"]);
      for (int i = 0; i < 3; ++i) {
        EXPECT_TRUE(InVolume(v, c + r * Eigen::Vector3d::Unit(i)));
        EXPECT_TRUE(InVolume(v, c - r * Eigen::Vector3d::Unit(i)));
      }
      if (spheres > 1) {
        const Eigen::Vector3d gap = 0.5 * v.size_mm - (c - v.center_mm).cwiseAbs();
        EXPECT_NEAR(gap.maxCoeff(), r, 1e-9);
        EXPECT_NEAR(gap.minCoeff(), r, 1e-9);
      } else {
        EXPECT_LT((c - v.center_mm).norm(), 1e-9);
      }
    } else if (p.artefact == "ball_bar") {
      ++bars;
      const Eigen::Vector3d c = V(g["center_mm"]), u = V(g["direction"]);
      const double len = g["length_mm"].get<double>(),
                   r = g["sphere_diameter_mm"].get<double>() / 2;
      EXPECT_LE(len, 2.0 / 3.0 * l0 + 1e-9);
      for (const double side : {-0.5, 0.5}) {
        for (int i = 0; i < 3; ++i) {
          EXPECT_TRUE(InVolume(v, c + side * len * u + r * Eigen::Vector3d::Unit(i)));
          EXPECT_TRUE(InVolume(v, c + side * len * u - r * Eigen::Vector3d::Unit(i)));
        }
      }
      // The first four along the volume's space diagonals.
      if (bars <= 4) {
        const Eigen::Vector3d au = u.cwiseAbs(), ad = (0.5 * v.size_mm).normalized();
        EXPECT_LT((au - ad).norm(), 1e-12) << p.label;
      }
      // The scene object and the artefact file agree with the geometry.
      EXPECT_EQ(p.object["distance_mm"].get<double>(), len);
      EXPECT_LT((V(p.artefacts["spheres"][1]["center_mm"]) -
                 V(p.artefacts["spheres"][0]["center_mm"]) - len * u)
                    .norm(),
                1e-9);
      for (const auto& d : directions) EXPECT_LT(std::abs(d.dot(u)), 1 - 1e-6) << "parallel bars";
      directions.push_back(u);
    } else {
      ASSERT_EQ(p.artefact, "plane");
      ++planes;
      const Eigen::Vector3d n = V(g["normal"]);
      EXPECT_NEAR(n.norm(), 1, 1e-12);
    }
  }
  EXPECT_EQ(spheres, 9);
  EXPECT_EQ(bars, 7);
  EXPECT_EQ(planes, 7);
}

TEST(Vdi2634Study, BadInputNamesTheField) {
  const Rig rig = QuarterRig();
  const auto fails_with = [&](const std::string& yaml, const std::string& expected) {
    try {
      StudyFrom(yaml, rig);
      ADD_FAILURE() << "accepted: " << yaml;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(expected), std::string::npos) << e.what();
    }
  };
  fails_with("vdi2634: {sphere: {diameter_mm: 500}}\n", "vdi2634.sphere.diameter_mm");
  fails_with("vdi2634: {ball_bar: {length_mm: 900}}\n", "vdi2634.ball_bar.length_mm");
  fails_with("vdi2634: {plane: {size_mm: [900, 10]}}\n", "vdi2634.plane.size_mm");
  fails_with("vdi2634: {volume: {center_mm: [0, 0, 500], size_mm: [2000, 100, 100]}}\n",
             "vdi2634.volume");
  fails_with("vdi2634: {sphere: {positions: 10}}\n", "vdi2634.sphere.positions");
  fails_with(
      "vdi2634: {sphere: {positions: 0}, ball_bar: {orientations: 0}, plane: {positions: 0}}\n",
      "places no artefact");
  fails_with("vdi2634: {spheres: {}}\n", "spheres");
}

// One sphere, one ball bar (first space diagonal), one plane, both modes; read noise 6 e- and
// 300 e-: 6 jobs.
void WriteSmallStudy(const fs::path& file) {
  std::ofstream(file) << "format: slshadow-study\nversion: 1\nname: vdi-small\n"
                      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string()
                      << "\nmodes: [projector, stereo]\n"
                         "set:\n  scene.layers.noise: {full_well_e: 10000, seed: 3}\n"
                         "axes:\n  - {name: read_noise_e, set: scene.layers.noise.read_noise_e, "
                         "values: [6, 300]}\n"
                         "vdi2634:\n  sphere: {diameter_mm: 25.4, positions: 1}\n"
                         "  ball_bar: {sphere_diameter_mm: 20, orientations: 1}\n"
                         "  plane: {positions: 1}\n"
                         "  mpe: {pf_mm: 0.3, ps_mm: 0.2, sd_mm: 0.3, f_mm: 0.4}\n";
}

std::vector<std::vector<std::string>> ReadCsv(const fs::path& file) {
  std::vector<std::vector<std::string>> rows;
  std::istringstream in(ReadTextFile(file));
  for (std::string line; std::getline(in, line);) {
    std::vector<std::string> cells;
    std::string cell;
    std::istringstream l(line);
    while (std::getline(l, cell, ',')) cells.push_back(cell);
    if (!line.empty() && line.back() == ',') cells.push_back("");
    rows.push_back(cells);
  }
  return rows;
}

TEST(Vdi2634Study, SmallStudyScansFitsAndShardsThroughGnuParallelToTheSameResult) {
  TempDir tmp;
  WriteSmallStudy(tmp / "study.yaml");
  const SweepPlanSummary plan = PlanSweep(tmp / "study.yaml", tmp / "one");
  EXPECT_EQ(plan.jobs, 6);
  EXPECT_EQ(plan.geometry_groups, 3);
  EXPECT_EQ(plan.axes, (std::vector<std::string>{"position", "read_noise_e"}));
  SweepRunOptions all;
  RunSweepShard(tmp / "one", all);
  const SweepMergeSummary merged = MergeSweep(tmp / "one", tmp / "one_result");
  ASSERT_EQ(merged.acceptance.size(), 4u);  // 2 noise levels x 2 modes

  // Per position and mode: every artefact found; at 6 e- the figures are small (the sphere's
  // size and the bar's length within 0.1 mm); at 300 e- form and flatness errors are larger.
  const json results = json::parse(ReadTextFile(tmp / "one_result/results.json"));
  std::map<std::string, double> figure;  // "position noise mode" -> PF / SD / F
  for (const auto& job : results["jobs"]) {
    const std::string position = job["params"]["position"].get<std::string>();
    const int noise = job["params"]["read_noise_e"].get<int>();
    for (const auto& m : job["modes"]) {
      const json& v = m["vdi2634"];
      ASSERT_FALSE(v.is_null()) << position;
      const std::string key =
          position + " " + std::to_string(noise) + " " + m["mode"].get<std::string>();
      SCOPED_TRACE(key + ": " + v.dump());
      if (position == "sphere_1") {
        ASSERT_TRUE(v["spheres"][0]["found"].get<bool>());
        if (noise == 6) {
          EXPECT_LT(std::abs(v["spheres"][0]["ps_mm"].get<double>()), 0.1);
        }
        figure[key] = v["spheres"][0]["pf_mm"].get<double>();
      } else if (position == "bar_1") {
        ASSERT_TRUE(v["sphere_pairs"][0]["found"].get<bool>());
        if (noise == 6) {
          EXPECT_LT(std::abs(v["sphere_pairs"][0]["sd_mm"].get<double>()), 0.1);
        }
        figure[key] = std::abs(v["sphere_pairs"][0]["sd_mm"].get<double>());
      } else {
        ASSERT_TRUE(v["planes"][0]["found"].get<bool>());
        figure[key] = v["planes"][0]["f_mm"].get<double>();
      }
    }
  }
  for (const char* mode : {"projector", "stereo"}) {
    for (const char* pos : {"sphere_1", "plane_1"}) {
      const std::string lo = std::string(pos) + " 6 " + mode,
                        hi = std::string(pos) + " 300 " + mode;
      EXPECT_GT(figure[hi], 1.5 * figure[lo]) << pos << " " << mode;
      EXPECT_GT(figure[lo], 0) << pos << " " << mode;
    }
  }
  // The summary's overall figures are the per-position ones (one position each here).
  const auto summary = ReadCsv(tmp / "one_result/vdi2634_summary.csv");
  ASSERT_EQ(summary.size(), 5u);
  ASSERT_EQ(summary[0][0], "series");
  for (size_t i = 1; i < summary.size(); ++i) {
    const std::string key_pf = "sphere_1 " + summary[i][0] + " " + summary[i][1];
    EXPECT_NEAR(std::stod(summary[i][2]), figure[key_pf], 1e-9 * (1 + figure[key_pf]));
    EXPECT_EQ(summary[i][3], "sphere_1");
    const std::string key_f = "plane_1 " + summary[i][0] + " " + summary[i][1];
    EXPECT_NEAR(std::stod(summary[i][8]), figure[key_f], 1e-9 * (1 + figure[key_f]));
    EXPECT_EQ(summary[i][9], "plane_1");
  }
  for (const char* f : {"vdi2634.csv", "positions.csv", "vdi2634.png", "vdi2634.svg"})
    EXPECT_TRUE(fs::exists(tmp / "one_result" / f)) << f;

  ASSERT_EQ(std::system("parallel --version > /dev/null 2>&1"), 0)
      << "GNU parallel is not installed (scripts/setup.sh installs it)";
  const std::string result = (tmp / "par_result").string();
  ASSERT_EQ(testing::SweepThroughGnuParallel(SLSHADOW_BINARY, tmp / "study.yaml", tmp / "par",
                                             result, "3 1 2 0", 4),
            "");
  for (const char* f :
       {"results.csv", "results.json", "vdi2634.csv", "vdi2634_summary.csv", "positions.csv"}) {
    EXPECT_EQ(ReadTextFile(tmp / "one_result" / f), ReadTextFile(tmp / "par_result" / f)) << f;
  }
}

}  // namespace
}  // namespace slshadow::studies
