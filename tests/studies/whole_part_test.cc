// The whole-part study (workflows/studies/whole_part.h): the quick study
// (config/studies/whole_part_quick.yaml) run end to end through the sweep machinery, its tables
// checked against oracles: coverage grows with the views, the fronts are the brute-force fronts
// and monotone, the modelled acquisition is views x patterns x exposure, a job's figures equal the
// multi-view library's own calls (virtual project, merge, CAD comparison) on the same inputs, and a
// merge of the same results is identical byte for byte, and shards run by GNU parallel through the
// command line give the tables one process gives.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/config.h"
#include "core/file_util.h"
#include "patterns/pattern_spec.h"
#include "tests/studies/sweep_cli.h"
#include "tests/testing/error_of.h"
#include "tests/testing/read_csv.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/project_merge.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/virtual_project.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/studies/sweep.h"
#include "workflows/studies/whole_part.h"

namespace slshadow::studies {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;
using testing::ReadCsv;
using testing::SourceDir;
using testing::TempDir;

// Brute force: on the front when no other point of the mode is at least as fast and as good and
// better in one.
void ExpectBruteForceFront(const std::vector<std::map<std::string, std::string>>& rows,
                           const std::string& figure, bool higher_is_better,
                           const std::string& flag) {
  std::vector<std::pair<double, double>> front;  // (time, figure) of the front
  for (const auto& p : rows) {
    const double t = std::stod(p.at("scan_time_s")), v = std::stod(p.at(figure));
    bool dominated = false;
    for (const auto& q : rows) {
      if (&q == &p || q.at("mode") != p.at("mode")) continue;
      const double tq = std::stod(q.at("scan_time_s")), vq = std::stod(q.at(figure));
      const bool as_good = higher_is_better ? vq >= v : vq <= v;
      if (tq <= t && as_good && (tq < t || vq != v)) dominated = true;
    }
    EXPECT_EQ(p.at(flag), dominated ? "0" : "1") << p.at("id") << " " << figure;
    if (!dominated) front.emplace_back(t, v);
  }
  // Monotone: faster points on the front are worse.
  ASSERT_FALSE(front.empty());
  std::sort(front.begin(), front.end());
  for (size_t i = 1; i < front.size(); ++i) {
    EXPECT_LT(front[i - 1].first, front[i].first);
    if (higher_is_better) {
      EXPECT_LT(front[i - 1].second, front[i].second);
    } else {
      EXPECT_GT(front[i - 1].second, front[i].second);
    }
  }
}

class WholePartStudy : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new TempDir();
    SweepRunOptions options;
    summary_ = new SweepStudySummary(
        RunStudy(SourceDir() / "config/studies/whole_part_quick.yaml", *tmp_ / "result", options));
  }
  static void TearDownTestSuite() {
    delete summary_;
    delete tmp_;
  }
  static fs::path Result() { return *tmp_ / "result"; }
  static TempDir* tmp_;
  static SweepStudySummary* summary_;
};
TempDir* WholePartStudy::tmp_ = nullptr;
SweepStudySummary* WholePartStudy::summary_ = nullptr;

TEST_F(WholePartStudy, CoverageGrowsWithTheViews) {
  EXPECT_EQ(summary_->plan.jobs, 12);
  EXPECT_TRUE(summary_->merge.whole_part);
  const auto rows = ReadCsv(Result() / "results.csv");
  ASSERT_EQ(rows.size(), 12u);
  // Per codec and phase steps: coverage of the part's reachable surface, and of the surface off
  // the table, grow with every added view; every view is merged.
  std::map<std::string, std::map<int, std::map<std::string, std::string>>> series;
  for (const auto& r : rows) {
    series[r.at("codec") + " " + r.at("steps")][std::stoi(r.at("views"))] = r;
    EXPECT_EQ(r.at("views_merged"), r.at("views")) << r.at("id");
  }
  ASSERT_EQ(series.size(), 4u);
  for (const auto& [name, by_views] : series) {
    ASSERT_EQ(by_views.size(), 3u) << name;
    double previous = 0, previous_total = 0;
    for (const auto& [views, r] : by_views) {
      const double coverage = std::stod(r.at("coverage"));
      const double total = std::stod(r.at("coverage_total"));
      EXPECT_GT(coverage, previous + 0.02) << name << ", " << views << " views";
      EXPECT_GT(total, previous_total) << name << ", " << views << " views";
      EXPECT_LE(coverage, 1.0);
      previous = coverage;
      previous_total = total;
    }
  }
}

TEST_F(WholePartStudy, FrontsAreTheBruteForceFrontsAndMonotone) {
  const auto points = ReadCsv(Result() / "pareto.csv");
  ASSERT_EQ(points.size(), 12u);
  for (const auto& p : points) {
    EXPECT_NEAR(std::stod(p.at("scan_time_s")),
                std::stod(p.at("acquisition_s")) + std::stod(p.at("processing_s")), 1e-9);
    EXPECT_GT(std::stod(p.at("processing_s")), 0.0);
  }
  ExpectBruteForceFront(points, "coverage", true, "on_coverage_front");
  ExpectBruteForceFront(points, "rms_mm", false, "on_rms_front");
  EXPECT_FALSE(summary_->merge.coverage_front.empty());
  EXPECT_FALSE(summary_->merge.front.empty());
  for (const char* f : {"time_vs_coverage.png", "time_vs_coverage.svg", "time_vs_rms.png",
                        "time_vs_rms.svg", "results.json", "timings.csv"})
    EXPECT_TRUE(fs::exists(Result() / f)) << f;
  EXPECT_NE(summary_->merge.FullReport().find("scan time against coverage"), std::string::npos);
}

// The modelled acquisition: views x the pattern spec's image count x the scene's exposure
// (the demo scene's 10 ms), the spec loaded here from the codec file with the job's steps.
TEST_F(WholePartStudy, AcquisitionIsViewsTimesPatternsTimesExposure) {
  for (const auto& r : ReadCsv(Result() / "results.csv")) {
    PatternSpec spec =
        pipeline::LoadPatternSpecOrDemo(SourceDir() / "config/studies" / r.at("codec"));
    spec.phase_steps = std::stoi(r.at("steps"));
    spec.projector_width = 320;  // the study's `set`
    spec.projector_height = 200;
    EXPECT_EQ(std::stoi(r.at("patterns")), spec.NumImages()) << r.at("id");
    EXPECT_NEAR(std::stod(r.at("acquisition_s")),
                std::stoi(r.at("views")) * spec.NumImages() * 0.010, 1e-9)
        << r.at("id");
  }
}

// Job 000004 (2 views, Gray code + phase shift, 4 steps) against the multi-view library called
// directly on the same inputs: the turntable set-up of the quarter rig and the demo scene, the
// virtual project, the merge with the study's options (scaled4_demo_rig.yaml, the pattern spec
// sized to its 320x200 projector).
TEST_F(WholePartStudy, JobEqualsTheMultiviewLibrary) {
  const json result =
      json::parse(ReadTextFile(Result() / "jobs/results/000004.json")).at("modes").at(0);
  const multiview::TurntableSetup setup = multiview::MakeTurntableSetup(
      pipeline::LoadRigOrDemo(SourceDir() / "config/studies/scaled4_demo_rig.yaml"),
      pipeline::LoadSceneOrDemo(""));
  PatternSpec spec =
      pipeline::LoadPatternSpecOrDemo(SourceDir() / "config/patterns/graycode_phase.yaml");
  spec.phase_steps = 4;
  spec.projector_width = 320;  // the study's `set`
  spec.projector_height = 200;
  const TempDir tmp;
  multiview::SimulateProject(setup.scene, setup.rig, spec, multiview::FullTurnViews(2),
                             tmp / "project");
  multiview::ProjectMergeOptions options;
  options.mode = ReconstructMode::kStereo;
  options.poses = multiview::PoseSource::kAxis;
  options.cad.threshold_mm = 0.5;
  options.cad.samples = 20000;
  options.mesh = false;
  const TriangleMesh cad = multiview::PartSurface(setup.scene);
  const multiview::ProjectMergeResult r = multiview::MergeProject(tmp / "project", &cad, options);
  ASSERT_TRUE(r.cad.has_value());
  EXPECT_EQ(result.at("points").get<size_t>(), r.cad->merged_points);
  EXPECT_DOUBLE_EQ(result.at("rms_mm").get<double>(), r.cad->merged_c2m.rms_mm);
  EXPECT_DOUBLE_EQ(result.at("coverage_views").get<double>(), r.cad->coverage_reachable);
  EXPECT_DOUBLE_EQ(result.at("coverage_total").get<double>(), r.cad->coverage_total);
  std::vector<double> rms;
  for (const auto& v : r.cad->views) rms.push_back(v.c2m.rms_mm);
  std::sort(rms.begin(), rms.end());
  EXPECT_DOUBLE_EQ(result.at("single_view_rms_mm").get<double>(), rms[0]);  // median of 2: lower
}

// Merging the same results again gives the same reproducible tables.
TEST_F(WholePartStudy, MergeIsReproducible) {
  const TempDir tmp;
  MergeSweep(Result() / "jobs", tmp / "again");
  for (const char* f : {"results.csv", "results.json"})
    EXPECT_EQ(ReadTextFile(tmp / "again" / f), ReadTextFile(Result() / f)) << f;
}

// A small whole-part study (views 1 and 3, axis poses), run in this process and through
// the command line in 2 shards by GNU parallel (in reverse order): the merged tables are identical
// byte for byte.
TEST(WholePartStudyShards, GnuParallelShardsEqualOneProcess) {
  ASSERT_EQ(std::system("parallel --version > /dev/null 2>&1"), 0)
      << "GNU parallel is not installed (scripts/setup.sh installs it)";
  const TempDir tmp;
  const fs::path study = tmp / "study.yaml";
  WriteTextFileAtomically(
      study, "format: slshadow-study\nversion: 1\nname: whole-part-shards\nrig: " +
                 (SourceDir() / "config/studies/scaled4_demo_rig.yaml").string() +
                 "\npatterns: " + (SourceDir() / "config/patterns/multi_frequency.yaml").string() +
                 "\nmodes: [stereo]\ncompare: {threshold_mm: 0.5}\n"
                 "set: {patterns.projector_width: 320, patterns.projector_height: 200, "
                 "patterns.phase_steps: 4}\n"
                 "whole_part: {poses: axis, reference_views: 12, cad: {samples: 5000}}\n"
                 "axes: [{name: views, set: whole_part.views, values: [1, 3]}]\n");
  SweepRunOptions options;
  const SweepStudySummary one = RunStudy(study, tmp / "one", options);
  EXPECT_EQ(one.plan.jobs, 2);
  const std::string failed = testing::SweepThroughGnuParallel(SLSHADOW_BINARY, study, tmp / "jobs",
                                                              tmp / "shards", "1 0", 2);
  ASSERT_EQ(failed, "");
  for (const char* f : {"results.csv", "results.json"})
    EXPECT_EQ(ReadTextFile(tmp / "shards" / f), ReadTextFile(tmp / "one" / f)) << f;
  // The work folders of the jobs are gone.
  EXPECT_FALSE(fs::exists(tmp / "jobs/work/000000/project"));
  const auto rows = ReadCsv(tmp / "one/results.csv");
  ASSERT_EQ(rows.size(), 2u);
  EXPECT_EQ(rows[1].at("views_merged"), "3");
  EXPECT_GT(std::stod(rows[1].at("coverage")), std::stod(rows[0].at("coverage")));
}

TEST(WholePartStudyPlan, BadInputNamesTheField) {
  const TempDir tmp;
  const fs::path study = tmp / "study.yaml";
  WriteTextFileAtomically(study,
                          "format: slshadow-study\nversion: 1\nname: bad\n"
                          "whole_part: {views: 0}\n");
  EXPECT_NE(testing::ErrorOf([&] { PlanSweep(study, tmp / "jobs"); }).find("views"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(tmp / "jobs"));
  WriteTextFileAtomically(study,
                          "format: slshadow-study\nversion: 1\nname: bad\n"
                          "whole_part: {part_object: nothing}\n");
  EXPECT_NE(testing::ErrorOf([&] { PlanSweep(study, tmp / "jobs"); }).find("nothing"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(tmp / "jobs"));
}

}  // namespace
}  // namespace slshadow::studies
