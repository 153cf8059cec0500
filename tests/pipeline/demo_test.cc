#include "workflows/pipeline/demo.h"

#include <cstdio>
#include <fstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/error.h"
#include "core/image_set.h"
#include "core/point_cloud.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::pipeline {
namespace {

// The whole digital-shadow loop on the embedded demo, checked against the accuracy goal:
// on the noise-free demo fewer than 0.05 % of points lie beyond 0.25 mm, in both modes.
TEST(Demo, NoiseFreeDemoMeetsTheAccuracyGoalInBothModes) {
  testing::TempDir dir;
  DemoOptions options;
  options.out_dir = dir / "demo";
  options.encoding = "pgm";
  const DemoResult result = RunDemoJob(options);
  ASSERT_EQ(result.modes.size(), 2u);
  for (const auto& m : result.modes) {
    SCOPED_TRACE(m.mode);
    EXPECT_LT(m.outlier_fraction, 0.0005);
    EXPECT_LT(m.rms_mm, 0.05);
    EXPECT_GT(m.visible_coverage, 0.9);
    // Every point a mode reconstructs is seen by the left camera and lit, so the share of the
    // whole surface it covers cannot exceed the share of that visible, lit part it covers.
    EXPECT_LE(m.coverage, m.visible_coverage);
    std::ifstream in(options.out_dir / m.mode / "report.json");
    ASSERT_TRUE(in) << "no report.json for " << m.mode;
    const auto report = nlohmann::json::parse(in);
    EXPECT_EQ(report["c2c"]["count"].get<size_t>(), m.points);
    // The summary counts the points of the cloud it wrote.
    const PointCloud compared = ReadPly(options.out_dir / m.mode / "compared.ply");
    EXPECT_EQ(compared.size(), m.points);
    EXPECT_TRUE(std::filesystem::exists(options.out_dir / m.mode / "histogram.png"));
  }
  // The stages the demo reports, in order (reconstruction's two from the scan pipeline; stereo
  // first, before the projector mode's cloud takes memory). The reference is built on a thread of
  // its own alongside the stages after it: its row is marked, holds its own time and is left out
  // of the table's total.
  std::vector<std::string> stage_names;
  for (const auto& s : result.stages) stage_names.push_back(s.name);
  EXPECT_EQ(stage_names, (std::vector<std::string>{
                             "load rig, build scene, patterns", "simulate (ray cast + patterns)",
                             "reference: sample ground truth", "write ImageSet",
                             "lit visible surface, free the scan", "read ImageSet + decode",
                             "reconstruct stereo", "reconstruct projector",
                             "compare + report (2 modes at once)"}));
  double main_thread_wall = 0;
  for (const auto& s : result.stages) {
    EXPECT_EQ(s.concurrent, s.name == "reference: sample ground truth") << s.name;
    EXPECT_GT(s.wall_s, 0) << s.name;
    if (!s.concurrent) main_thread_wall += s.wall_s;
  }
  EXPECT_GT(result.stages[2].cpu_s, 0);
  const std::string table = result.Table();
  EXPECT_NE(table.find("reference: sample ground truth"), std::string::npos) << table;
  EXPECT_NE(table.find("not added to the total"), std::string::npos) << table;
  char total[64];
  std::snprintf(total, sizeof(total), "total                          %8.3f", main_thread_wall);
  EXPECT_NE(table.find(total), std::string::npos) << table;
  const ImageSet scan = ImageSet::Open(options.out_dir / "scan");
  EXPECT_EQ(scan.CameraNames(), (std::vector<std::string>{"left", "right"}));
  EXPECT_EQ(scan.PatternCount(), 38);
  EXPECT_EQ(scan.records().front().source, ImageSource::kVirtual);
  EXPECT_TRUE(std::filesystem::exists(options.out_dir / "ground_truth.ply"));
  EXPECT_TRUE(std::filesystem::exists(options.out_dir / "demo.json"));

  // The scan's provenance holds the settings the demo ran with, and the scan renders again from
  // its folder alone into identical images (the demo renders in memory, the redo with
  // SimulateScan).
  const std::optional<ScanProvenance> provenance = ReadScanProvenance(scan);
  ASSERT_TRUE(provenance.has_value());
  EXPECT_EQ(provenance->generator, "slshadow demo");
  const ScanSettings settings = ScanSettingsFromProvenance(*provenance, "manifest.json");
  EXPECT_EQ(settings.reconstruct.method, TriangulationMethod::kMidpoint);
  EXPECT_EQ(settings.compare.threshold_mm, options.threshold_mm);
  EXPECT_EQ(settings.simulate.writer.encoding, ImageEncoding::kPgm);
  RedoVirtualScan(options.out_dir / "scan", dir / "redo");
  const ImageSet redo = ImageSet::Open(dir / "redo");
  ASSERT_EQ(redo.records().size(), scan.records().size());
  for (const ImageRecord& r : scan.records()) {
    ASSERT_EQ(cv::norm(scan.Load(r.camera, r.pattern_index), redo.Load(r.camera, r.pattern_index),
                       cv::NORM_INF),
              0)
        << r.camera << " " << r.pattern_index;
  }
}

TEST(Demo, RefusesToReplaceAFolderThatIsNotADemoOutput) {
  testing::TempDir dir;
  std::filesystem::create_directories(dir / "mine");
  { std::ofstream(dir / "mine" / "notes.txt") << "keep me"; }
  DemoOptions options;
  options.out_dir = dir / "mine";
  EXPECT_THROW(RunDemoJob(options), Error);
  EXPECT_TRUE(std::filesystem::exists(dir / "mine" / "notes.txt"));
  options.out_dir = dir / "x";
  options.method = "guess";
  EXPECT_THROW(RunDemoJob(options), Error);
  EXPECT_FALSE(std::filesystem::exists(dir / "x"));
}

}  // namespace
}  // namespace slshadow::pipeline
