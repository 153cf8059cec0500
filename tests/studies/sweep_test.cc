// Sweeps (workflows/studies/sweep.h): plan, shards, merge. Oracles: the merged result of one
// process against that of shards run in another order, through GNU parallel and through a
// single-node Slurm (byte for byte); resumption runs only missing jobs; the accuracy of noisy scans
// of the demo part against its ground truth; bad input.
#include "workflows/studies/sweep.h"
#include "workflows/pipeline/significance.h"

#include "core/error.h"
#include "core/file_util.h"
#include "tests/testing/temp_dir.h"

#include <gtest/gtest.h>
#include <sys/wait.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

namespace slshadow::studies {
namespace {
namespace fs = std::filesystem;
using testing::SourceDir;
using testing::TempDir;

// 2 noise seeds x 2 triangulation methods on the quarter-resolution demo rig: 4 jobs.
void WriteSmallStudy(const fs::path& file) {
  std::ofstream(file)
      << "format: slshadow-study\nversion: 1\nname: small\n"
      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "modes: [projector, stereo]\n"
         "compare: {threshold_mm: 0.5}\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6}\n"
         "axes:\n"
         "  - {name: seed, set: scene.layers.noise.seed, values: [11, 12]}\n"
         "  - {name: method, set: reconstruct.method, values: [midpoint, optimal]}\n";
}

SweepRunOptions Shard(int i, int n) {
  SweepRunOptions o;
  o.shard_index = i;
  o.shard_count = n;
  return o;
}

TEST(Sweep, ShardsInAnyOrderMergeToTheOneProcessResultAndResumeOnlyMissingJobs) {
  TempDir tmp;
  WriteSmallStudy(tmp / "study.yaml");
  const SweepPlanSummary plan = PlanSweep(tmp / "study.yaml", tmp / "one");
  EXPECT_EQ(plan.jobs, 4);
  EXPECT_EQ(plan.geometry_groups, 1);
  const SweepRunSummary one = RunSweepShard(tmp / "one", Shard(0, 1));
  EXPECT_EQ(one.ran, 4);
  EXPECT_EQ(one.geometry_traces, 1);  // noise and method do not change geometry
  MergeSweep(tmp / "one", tmp / "one_result");

  PlanSweep(tmp / "study.yaml", tmp / "sharded");
  int ran = 0;
  for (int i : {2, 0, 1}) ran += RunSweepShard(tmp / "sharded", Shard(i, 3)).ran;
  EXPECT_EQ(ran, 4);
  MergeSweep(tmp / "sharded", tmp / "sharded_result");
  const std::string csv = ReadTextFile(tmp / "one_result/results.csv");
  EXPECT_EQ(csv, ReadTextFile(tmp / "sharded_result/results.csv"));
  EXPECT_EQ(ReadTextFile(tmp / "one_result/results.json"),
            ReadTextFile(tmp / "sharded_result/results.json"));

  // The figures: noisy scans of the demo part, 2 modes per job.
  const nlohmann::json merged =
      nlohmann::json::parse(ReadTextFile(tmp / "one_result/results.json"));
  ASSERT_EQ(merged["jobs"].size(), 4u);
  for (const auto& job : merged["jobs"]) {
    ASSERT_EQ(job["modes"].size(), 2u);
    for (const auto& m : job["modes"]) {
      EXPECT_GT(m["visible_coverage"].get<double>(), 0.9) << job.dump();
      EXPECT_GT(m["rms_mm"].get<double>(), 0.01) << job.dump();  // noise is on
      EXPECT_LT(m["rms_mm"].get<double>(), 0.15) << job.dump();
      EXPECT_LT(m["outlier_fraction"].get<double>(), 0.01) << job.dump();
    }
  }
  // Another seed is another noise realisation: the projector-mode RMS of seeds 11 and 12 differ.
  EXPECT_EQ(merged["jobs"][0]["params"]["seed"], 11);
  EXPECT_EQ(merged["jobs"][2]["params"]["seed"], 12);
  EXPECT_NE(merged["jobs"][0]["modes"][0]["rms_mm"], merged["jobs"][2]["modes"][0]["rms_mm"]);
  EXPECT_EQ(std::count(csv.begin(), csv.end(), '\n'), 1 + 8);

  // The Pareto front (measured times): flagged rows are dominated by no row of their mode, the
  // others by at least one; each mode has a front; the chart is written.
  {
    std::istringstream in(ReadTextFile(tmp / "one_result/pareto.csv"));
    std::string line;
    std::getline(in, line);
    struct Row {
      std::string mode;
      double t, rms;
      bool front;
    };
    std::vector<Row> rows;
    while (std::getline(in, line)) {
      std::vector<std::string> f;
      std::stringstream ls(line);
      for (std::string x; std::getline(ls, x, ',');) f.push_back(x);
      // The last field, the key, is empty off the front (and then not split off).
      ASSERT_EQ(f.size(), f[5] == "1" ? 7u : 6u) << line;
      if (f[5] == "1") {
        EXPECT_EQ(f[6][0], f[1] == "projector" ? 'P' : 'S') << line;
      }
      rows.push_back({f[1], std::stod(f[3]), std::stod(f[4]), f[5] == "1"});
    }
    ASSERT_EQ(rows.size(), 8u);
    for (const auto& p : rows) {
      bool dominated = false;
      for (const auto& q : rows) {
        dominated |=
            q.mode == p.mode && q.t <= p.t && q.rms <= p.rms && (q.t < p.t || q.rms < p.rms);
      }
      EXPECT_EQ(p.front, !dominated) << p.mode << " " << p.t << " " << p.rms;
    }
    for (const char* mode : {"projector", "stereo"}) {
      EXPECT_TRUE(std::any_of(rows.begin(), rows.end(),
                              [&](const Row& r) { return r.mode == mode && r.front; }));
    }
    EXPECT_GT(fs::file_size(tmp / "one_result/time_vs_rms.png"), 1000u);
  }

  // An interrupted shard: one result lost; the merge names it, a re-run runs only it.
  fs::remove(tmp / "sharded/results/000001.json");
  try {
    MergeSweep(tmp / "sharded", tmp / "partial");
    ADD_FAILURE() << "merge with a missing result did not throw";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("000001"), std::string::npos) << e.what();
  }
  const SweepRunSummary again = RunSweepShard(tmp / "sharded", Shard(0, 1));
  EXPECT_EQ(again.ran, 1);
  EXPECT_EQ(again.already_done, 3);
  MergeSweep(tmp / "sharded", tmp / "sharded_result");
  EXPECT_EQ(csv, ReadTextFile(tmp / "sharded_result/results.csv"));
}

// RunStudy (`slshadow sweep study`): plans, runs and merges; called again it resumes the plan and
// runs only the jobs without a result, merging to the same files; another study's plan is refused.
TEST(Sweep, RunStudyPlansOnceThenResumesOnlyMissingJobs) {
  TempDir tmp;
  WriteSmallStudy(tmp / "study.yaml");
  // `planned` is called once, after planning and before any job ran (what the command prints).
  int calls = 0;
  const SweepStudySummary first =
      RunStudy(tmp / "study.yaml", tmp / "out", SweepRunOptions{}, [&](const SweepStudySummary& p) {
        ++calls;
        EXPECT_FALSE(p.resumed);
        EXPECT_EQ(p.plan.jobs, 4);
        EXPECT_TRUE(fs::exists(tmp / "out/jobs/plan.json"));
        EXPECT_FALSE(fs::exists(tmp / "out/jobs/results/000000.json"));
      });
  EXPECT_EQ(calls, 1);
  EXPECT_FALSE(first.resumed);
  EXPECT_EQ(first.plan.jobs, 4);
  EXPECT_EQ(first.jobs_dir, tmp / "out" / "jobs");
  EXPECT_EQ(first.run.ran, 4);
  EXPECT_EQ(first.merge.rows, 8);
  const std::string csv = ReadTextFile(tmp / "out/results.csv");
  const std::string json = ReadTextFile(tmp / "out/results.json");

  const SweepStudySummary second = RunStudy(tmp / "study.yaml", tmp / "out", SweepRunOptions{});
  EXPECT_TRUE(second.resumed);
  EXPECT_EQ(second.run.ran, 0);
  EXPECT_EQ(second.run.already_done, 4);
  EXPECT_EQ(ReadTextFile(tmp / "out/results.csv"), csv);

  fs::remove(tmp / "out/jobs/results/000002.json");
  const SweepStudySummary third =
      RunStudy(tmp / "study.yaml", tmp / "out", SweepRunOptions{}, [&](const SweepStudySummary& p) {
        ++calls;
        EXPECT_TRUE(p.resumed);
        EXPECT_FALSE(fs::exists(tmp / "out/jobs/results/000002.json"));
      });
  EXPECT_EQ(calls, 2);
  EXPECT_TRUE(third.resumed);
  EXPECT_EQ(third.run.ran, 1);
  EXPECT_EQ(ReadTextFile(tmp / "out/results.csv"), csv);
  EXPECT_EQ(ReadTextFile(tmp / "out/results.json"), json);

  std::string other = ReadTextFile(tmp / "study.yaml");
  other.replace(other.find("name: small"), 11, "name: other");
  WriteTextFileAtomically(tmp / "other.yaml", other);
  try {
    RunStudy(tmp / "other.yaml", tmp / "out", SweepRunOptions{});
    ADD_FAILURE() << "resumed another study's plan";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("another study"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("other.yaml"), std::string::npos) << e.what();
  }
}

TEST(Sweep, ShardsAreContiguousDisjointAndCoverEveryJob) {
  TempDir tmp;
  WriteSmallStudy(tmp / "study.yaml");
  PlanSweep(tmp / "study.yaml", tmp / "jobs");
  for (int n : {1, 3, 4, 7}) {
    std::vector<int> all;
    for (int i = 0; i < n; ++i) {
      const std::vector<int> ids = ShardJobs(tmp / "jobs", i, n);
      EXPECT_LE(ids.size(), 4u / static_cast<size_t>(n) + 1);
      all.insert(all.end(), ids.begin(), ids.end());
    }
    std::sort(all.begin(), all.end());
    EXPECT_EQ(all, (std::vector<int>{0, 1, 2, 3})) << n << " shards";
  }
}

// The quick study through GNU parallel: 3 shards on 2 job slots, then merge; equal byte for byte
// to the one-process result.
TEST(Sweep, GnuParallelShardsMergeToTheOneProcessResult) {
  ASSERT_EQ(std::system("parallel --version > /dev/null 2>&1"), 0)
      << "GNU parallel is not installed (scripts/setup.sh installs it)";
  TempDir tmp;
  const fs::path study = SourceDir() / "config/studies/noise_quick.yaml";
  PlanSweep(study, tmp / "one");
  RunSweepShard(tmp / "one", Shard(0, 1));
  MergeSweep(tmp / "one", tmp / "one_result");

  const std::string bin = SLSHADOW_BINARY;
  const std::string jobs = (tmp / "par").string(), result = (tmp / "par_result").string();
  ASSERT_EQ(
      std::system(
          (bin + " sweep plan " + study.string() + " --out " + jobs + " > /dev/null").c_str()),
      0);
  const std::string cmd = "parallel --will-cite --halt now,fail=1 -j 2 --joblog " +
                          (tmp / "joblog").string() + " " + bin + " sweep run " + jobs +
                          " --shard {}/3 ::: 2 1 0 > /dev/null";
  ASSERT_EQ(std::system(cmd.c_str()), 0) << cmd;
  ASSERT_EQ(
      std::system((bin + " sweep merge " + jobs + " --out " + result + " > /dev/null").c_str()), 0);
  EXPECT_EQ(ReadTextFile(tmp / "one_result/results.csv"),
            ReadTextFile(tmp / "par_result/results.csv"));
  EXPECT_EQ(ReadTextFile(tmp / "one_result/results.json"),
            ReadTextFile(tmp / "par_result/results.json"));
  const std::string joblog = ReadTextFile(tmp / "joblog");
  EXPECT_EQ(std::count(joblog.begin(), joblog.end(), '\n'), 1 + 3) << joblog;  // header + 3 shards
}

// The small study through a real single-node Slurm (Debian's slurm-wlm and munge), configured
// and started by tests/studies/slurm_sweep.sh in a temporary folder inside a private network
// namespace (loopback only) and stopped afterwards: the shards as an `sbatch --array`, the merge as
// a job depending on them (afterok). Equal byte for byte to the one-process result. Skips (refused
// by the skip gate of scripts/run-tests.sh: not on tests/skip_allowlist.txt), naming what failed,
// when Slurm or MUNGE cannot start here.
TEST(Sweep, SlurmArrayShardsAndDependentMergeGiveTheOneProcessResult) {
  if (std::system("unshare -n true > /dev/null 2>&1") != 0) {
    GTEST_SKIP() << "cannot make a private network namespace (unshare -n) for the Slurm daemons";
  }
  TempDir tmp;
  WriteSmallStudy(tmp / "study.yaml");
  PlanSweep(tmp / "study.yaml", tmp / "one");
  RunSweepShard(tmp / "one", Shard(0, 1));
  MergeSweep(tmp / "one", tmp / "one_result");

  PlanSweep(tmp / "study.yaml", tmp / "slurm");
  const fs::path log = tmp / "slurm_sweep.log";
  const std::string cmd =
      "unshare -n bash " + (SourceDir() / "tests/studies/slurm_sweep.sh").string() + " " +
      SLSHADOW_BINARY + " " + (tmp / "slurm").string() + " " + (tmp / "slurm_result").string() +
      " " + (tmp / "slurm_work").string() + " 2 > " + log.string() + " 2>&1";
  const int status = std::system(cmd.c_str());
  const int code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  const std::string output = ReadTextFile(log);
  if (code == 77) GTEST_SKIP() << output;
  ASSERT_EQ(code, 0) << cmd << "\n" << output;
  EXPECT_EQ(ReadTextFile(tmp / "one_result/results.csv"),
            ReadTextFile(tmp / "slurm_result/results.csv"));
  EXPECT_EQ(ReadTextFile(tmp / "one_result/results.json"),
            ReadTextFile(tmp / "slurm_result/results.json"));
  // Each array task took its thread budget from Slurm's allocation (--cpus-per-task=1).
  EXPECT_EQ(output, "threads: 1 (SLURM_CPUS_PER_TASK)\nthreads: 1 (SLURM_CPUS_PER_TASK)\n");
}

// Study 2's machinery on three read-noise levels up to one where stereo reconstructs nothing: the
// shard does not stop (graceful failure: the empty cloud's figures are null, no NaN anywhere), the
// error grows with the noise, and each break point is where the curve crosses its limit, linearly
// interpolated (recomputed here from results.json).
TEST(Sweep, CurvesAndBreakPointsAgainstOneAxis) {
  TempDir tmp;
  std::ofstream(tmp / "study.yaml")
      << "format: slshadow-study\nversion: 1\nname: curves\n"
      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "patterns: " << (SourceDir() / "config/patterns/multi_frequency.yaml").string() << "\n"
      << "modes: [projector, stereo]\n"
         "compare: {threshold_mm: 0.5}\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6, seed: 1}\n"
         "axes:\n"
         "  - {name: read_noise_e, set: scene.layers.noise.read_noise_e, values: [5, 300, 1500]}\n"
         "curves: {x: read_noise_e, limits: {p95_mm: 0.5, visible_coverage: 0.8}}\n";
  PlanSweep(tmp / "study.yaml", tmp / "jobs");
  EXPECT_EQ(RunSweepShard(tmp / "jobs", Shard(0, 1)).ran, 3);
  const SweepMergeSummary merged = MergeSweep(tmp / "jobs", tmp / "result");
  EXPECT_EQ(merged.break_points.size(), 4u);  // 2 modes x 2 limits
  const std::string json_text = ReadTextFile(tmp / "result/results.json");
  const std::string csv = ReadTextFile(tmp / "result/results.csv");
  for (const std::string* text : {&json_text, &csv}) {
    EXPECT_EQ(text->find("nan"), std::string::npos);
    EXPECT_EQ(text->find("inf"), std::string::npos);
  }
  const nlohmann::json jobs = nlohmann::json::parse(json_text)["jobs"];
  ASSERT_EQ(jobs.size(), 3u);
  // figure[mode][job]
  std::map<std::string, std::vector<nlohmann::json>> by_mode;
  for (const auto& job : jobs) {
    for (const auto& m : job["modes"]) by_mode[m["mode"].get<std::string>()].push_back(m);
  }
  const double xs[3] = {5, 300, 1500};
  const std::string breaks = ReadTextFile(tmp / "result/break_points.csv");
  for (const auto& [mode, figures] : by_mode) {
    ASSERT_EQ(figures.size(), 3u);
    ASSERT_FALSE(figures[0]["p95_mm"].is_null()) << mode;
    ASSERT_FALSE(figures[1]["p95_mm"].is_null()) << mode;
    EXPECT_GT(figures[1]["p95_mm"].get<double>(), figures[0]["p95_mm"].get<double>()) << mode;
    EXPECT_LT(figures[0]["p95_mm"].get<double>(), 0.5) << mode;
    for (const auto& f : figures) {
      if (f["points"].get<int>() == 0) {
        EXPECT_TRUE(f["p95_mm"].is_null());
        EXPECT_EQ(f["visible_coverage"].get<double>(), 0.0);
      }
    }
    // The p95 break: the first x whose p95 is beyond 0.5 or missing.
    size_t i = 1;
    while (i < 3 && !figures[i]["p95_mm"].is_null() && figures[i]["p95_mm"].get<double>() <= 0.5)
      ++i;
    std::string expected = mode + ",p95_mm,0.5,";
    if (i == 3) {
      expected += "never,";
    } else {
      const double v0 = figures[i - 1]["p95_mm"].get<double>();
      const double t = figures[i]["p95_mm"].is_null()
                           ? 1.0
                           : (0.5 - v0) / (figures[i]["p95_mm"].get<double>() - v0);
      char buf[64];
      std::snprintf(buf, sizeof(buf), "%.10g", xs[i - 1] + t * (xs[i] - xs[i - 1]));
      expected += std::string("broke,") + buf;
    }
    EXPECT_NE(breaks.find(expected + "\n"), std::string::npos) << expected << "\n" << breaks;
  }
  // The highest noise breaks stereo entirely here: the case above that must not crash the shard.
  EXPECT_EQ(by_mode["stereo"][2]["points"].get<int>(), 0) << by_mode["stereo"][2].dump();
  for (const char* chart : {"curves_p95_mm.png", "curves_p95_mm.svg", "curves_visible_coverage.png",
                            "time_vs_rms.svg"}) {
    EXPECT_GT(fs::file_size(tmp / "result" / chart), 1000u) << chart;
  }
}

// `worse: decreasing`: darker parts are worse, so the curve runs from the brightest albedo down and
// the break lies between the last albedo inside the limit and the first beyond it. At albedo 0.02
// the part is under the shadow threshold (only the table is left).
TEST(Sweep, BreakPointsWhenSmallerValuesAreWorse) {
  TempDir tmp;
  std::ofstream(tmp / "study.yaml")
      << "format: slshadow-study\nversion: 1\nname: dark\n"
      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "modes: [projector]\n"
         "set:\n  scene.layers.noise: {full_well_e: 10000, read_noise_e: 6, seed: 1}\n"
         "axes:\n  - {name: albedo, set: scene.objects.0.albedo, values: [0.02, 0.7, 0.2]}\n"
         "curves: {x: albedo, worse: decreasing, limits: {visible_coverage: 0.9}}\n";
  PlanSweep(tmp / "study.yaml", tmp / "jobs");
  EXPECT_EQ(RunSweepShard(tmp / "jobs", Shard(0, 1)).ran, 3);
  MergeSweep(tmp / "jobs", tmp / "result");
  const nlohmann::json jobs =
      nlohmann::json::parse(ReadTextFile(tmp / "result/results.json"))["jobs"];
  ASSERT_EQ(jobs.size(), 3u);
  std::map<double, double> coverage;  // albedo -> visible coverage
  for (const auto& job : jobs)
    coverage[job["params"]["albedo"].get<double>()] = job["modes"][0]["visible_coverage"];
  ASSERT_GT(coverage[0.7], 0.9);
  ASSERT_GT(coverage[0.2], 0.9);
  ASSERT_LT(coverage[0.02], 0.9);
  const double t = (0.9 - coverage[0.2]) / (coverage[0.02] - coverage[0.2]);
  char buf[64];
  std::snprintf(buf, sizeof(buf), "%.10g", 0.2 + t * (0.02 - 0.2));
  const std::string breaks = ReadTextFile(tmp / "result/break_points.csv");
  EXPECT_NE(breaks.find(std::string("projector,visible_coverage,0.9,broke,") + buf + "\n"),
            std::string::npos)
      << buf << "\n"
      << breaks;
  std::ofstream(tmp / "bad.yaml") << ReadTextFile(tmp / "study.yaml")
                                         .replace(
                                             ReadTextFile(tmp / "study.yaml").find("decreasing"),
                                             10, "downwards");
  try {
    PlanSweep(tmp / "bad.yaml", tmp / "jobs2");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("curves.worse: must be 'increasing'"), std::string::npos)
        << e.what();
  }
}

// Study 3's machinery: an axis of layer mappings with labels, each against the baseline `none`,
// and with `full`, each switched off in the full model (the planned "without_" values).
// effects.csv's and layers.csv's changes are the differences of results.json's figures, `needed`
// their comparison with max(3 sigma, tolerance) (workflows/pipeline/significance.h, sigma from the
// change on each image band). Also: the study's `set` reaches the scene a files axis puts in each
// job.
TEST(Sweep, EffectsOfEachAxisValueAgainstABaselineAndInTheFullModel) {
  TempDir tmp;
  std::ofstream(tmp / "study.yaml")
      << "format: slshadow-study\nversion: 1\nname: effects\n"
      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "scene: " << (SourceDir() / "config/scenes/flat_plane.yaml").string() << "\n"
      << "modes: [projector]\n"
         "axes:\n"
         "  - name: layer\n"
         "    set: scene.layers\n"
         "    labels: [none, ambient, gamma, all]\n"
         "    values: [{}, {ambient: {level: 0.05}}, {projector_response: {gamma: 2.2}},\n"
         "             {ambient: {level: 0.05}, projector_response: {gamma: 2.2}}]\n"
         "effects: {axis: layer, baseline: none, full: all, tolerance_mm: 0.002}\n"
         "pareto: {by: layer, time: cpu}\n";
  PlanSweep(tmp / "study.yaml", tmp / "jobs");
  // The one-layer-off values: the full model without each layer's keys.
  const nlohmann::json job5 = nlohmann::json::parse(ReadTextFile(tmp / "jobs/jobs/000005.json"));
  EXPECT_EQ(job5["params"]["layer"], "without_gamma");
  EXPECT_TRUE(job5["scene"]["layers"].contains("ambient"));
  EXPECT_FALSE(job5["scene"]["layers"].contains("projector_response"));
  RunSweepShard(tmp / "jobs", Shard(0, 1));
  const SweepMergeSummary merged = MergeSweep(tmp / "jobs", tmp / "result");
  ASSERT_EQ(merged.effects.size(), 2u);  // ambient, gamma
  EXPECT_NE(merged.effects[0].find("ambient"), std::string::npos) << merged.effects[0];
  EXPECT_NE(merged.effects[0].find("off in the full model"), std::string::npos);
  const nlohmann::json jobs =
      nlohmann::json::parse(ReadTextFile(tmp / "result/results.json"))["jobs"];
  ASSERT_EQ(jobs.size(), 6u);
  EXPECT_EQ(jobs[2]["params"]["layer"], "gamma");
  EXPECT_EQ(jobs[4]["params"]["layer"], "without_ambient");
  const auto figure = [&](int job, const char* key) {
    return jobs[job]["modes"][0][key].get<double>();
  };
  const auto g = [](double v, int digits = 10) {
    char buf[64];
    std::snprintf(buf, sizeof(buf), "%.*g", digits, v);
    return std::string(buf);
  };
  // An effect of `with` against `without`: its changes, thresholds and verdict, as CSV fields.
  const auto effect = [&](int with, int without) {
    std::string fields, needed = "0";
    for (const char* metric : {"rms", "p95"}) {
      const std::string fig = std::string(metric) + "_mm",
                        bands = std::string(metric) + "_bands_mm";
      const double d = figure(with, fig.c_str()) - figure(without, fig.c_str());
      // Paired: the change on each of the 8 image bands.
      std::vector<double> band_d;
      for (int b = 0; b < 8; ++b) {
        band_d.push_back(jobs[with]["modes"][0][bands][b].get<double>() -
                         jobs[without]["modes"][0][bands][b].get<double>());
      }
      const double sigma = pipeline::BandSigma(band_d);
      EXPECT_GT(sigma, 0);
      EXPECT_LT(sigma, 0.05);
      if (std::abs(d) > std::max(3 * sigma, 0.002)) needed = "1";
      fields += g(d) + ",";
    }
    return std::make_pair(fields, needed);
  };
  const std::string csv = ReadTextFile(tmp / "result/effects.csv");
  std::istringstream lines(csv);
  std::string line;
  std::getline(lines, line);
  EXPECT_EQ(line,
            "series,mode,layer,kind,rms_mm,rms_sigma_mm,p95_mm,p95_sigma_mm,d_rms_mm,d_p95_mm,"
            "threshold_rms_mm,threshold_p95_mm,needed,render_s,model_cpu_s");
  const char* kinds[] = {"baseline", "alone", "alone", "full", "off", "off"};
  for (int job = 0; job < 6; ++job) {
    ASSERT_TRUE(std::getline(lines, line));
    std::string expected = ",projector," + jobs[job]["params"]["layer"].get<std::string>() + "," +
                           kinds[job] + "," + g(figure(job, "rms_mm")) + "," +
                           g(figure(job, "rms_sigma_mm")) + "," + g(figure(job, "p95_mm")) + "," +
                           g(figure(job, "p95_sigma_mm")) + ",";
    // alone / full against the baseline; off: the full model (job 3) against the job.
    if (job > 0) expected += (job < 4 ? effect(job, 0) : effect(3, job)).first;
    EXPECT_EQ(line.substr(0, expected.size()), expected) << line;
  }
  const std::string layers = ReadTextFile(tmp / "result/layers.csv");
  std::istringstream layer_lines(layers);
  std::getline(layer_lines, line);
  EXPECT_EQ(line,
            "series,mode,layer,alone_d_rms_mm,alone_d_p95_mm,alone_needed,off_d_rms_mm,"
            "off_d_p95_mm,off_threshold_rms_mm,off_threshold_p95_mm,off_needed,needed,cost_ms");
  for (int layer = 1; layer <= 2; ++layer) {  // ambient (off: job 4), gamma (off: job 5)
    ASSERT_TRUE(std::getline(layer_lines, line));
    const auto alone = effect(layer, 0), off = effect(3, layer + 3);
    const std::string expected = ",projector," + jobs[layer]["params"]["layer"].get<std::string>() +
                                 "," + alone.first + alone.second + "," + off.first;
    EXPECT_EQ(line.substr(0, expected.size()), expected) << line;
    // The verdict is the off one.
    const size_t cost = line.rfind(',');
    EXPECT_EQ(line.substr(cost - 2, 3), "," + off.second + ",") << line;
  }
  EXPECT_FALSE(std::getline(layer_lines, line));

  // A front per mode and layer: one job each, so each is on its front. Its time is the method's
  // CPU seconds (pareto.time: cpu), with 17 digits.
  const std::string pareto = ReadTextFile(tmp / "result/pareto.csv");
  const nlohmann::json result2 =
      nlohmann::json::parse(ReadTextFile(tmp / "jobs/results/000002.json"));
  const double cpu = result2["timing"]["method_cpu_s"]["projector"].get<double>();
  EXPECT_GT(cpu, 0);
  char cpu_text[64];
  std::snprintf(cpu_text, sizeof(cpu_text), ",%.17g,", cpu);
  EXPECT_NE(pareto.find("000002,projector,000002" + std::string(cpu_text)), std::string::npos)
      << pareto << cpu_text;
  EXPECT_EQ(pareto.substr(0, pareto.find('\n')), "id,mode,label,time_s,rms_mm,on_front,group,key");
  EXPECT_NE(pareto.find(",1,projector gamma,"), std::string::npos) << pareto;
  EXPECT_EQ(merged.front.size(), 6u);

  // `set` under a tree a files axis replaces: applied to each file's tree; not where an axis sets
  // that path or one under it.
  std::ofstream(tmp / "files.yaml")
      << "format: slshadow-study\nversion: 1\nname: files\n"
      << "rig: " << (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() << "\n"
      << "set:\n  scene.layers.noise: {full_well_e: 9000, read_noise_e: 7}\n"
      << "  scene.radiometry.exposure: 0.5\n"
      << "axes:\n"
      << "  - {name: scene, set: scene, files: ["
      << (SourceDir() / "config/scenes/flat_plane.yaml").string() << ", "
      << (SourceDir() / "config/scenes/ball_bar.yaml").string() << "]}\n"
      << "  - {name: exposure, set: scene.radiometry.exposure, values: [0.6]}\n";
  PlanSweep(tmp / "files.yaml", tmp / "files_jobs");
  for (const char* id : {"000000", "000001"}) {
    const nlohmann::json job =
        nlohmann::json::parse(ReadTextFile(tmp / "files_jobs/jobs" / (std::string(id) + ".json")));
    EXPECT_EQ(job["scene"]["layers"]["noise"]["full_well_e"], 9000) << id;
    EXPECT_EQ(job["scene"]["radiometry"]["exposure"], 0.6) << id;  // the axis, not `set`
  }
}

void ExpectPlanError(const TempDir& tmp, const std::string& yaml, const std::string& needle) {
  const fs::path file = tmp / "bad.yaml";
  std::ofstream(file) << "format: slshadow-study\nversion: 1\nname: bad\n" << yaml;
  try {
    PlanSweep(file, tmp / "bad_jobs");
    ADD_FAILURE() << "no error for:\n" << yaml;
  } catch (const Error& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("bad.yaml"), std::string::npos) << what;
    EXPECT_NE(what.find(needle), std::string::npos) << what;
  }
  EXPECT_FALSE(fs::exists(tmp / "bad_jobs"));
}

TEST(Sweep, BadStudiesAreRejectedNamingFileAndFieldAndWriteNothing) {
  TempDir tmp;
  const std::string rig =
      "rig: " + (SourceDir() / "config/studies/quarter_demo_rig.yaml").string() + "\n";
  ExpectPlanError(tmp, rig + "colour: red\n", "colour");
  ExpectPlanError(tmp, rig + "modes: [projector, sideways]\n", "sideways");
  ExpectPlanError(tmp, rig + "axes:\n  - {name: s, set: layers.noise.seed, values: [1]}\n",
                  "layers.noise.seed");
  ExpectPlanError(tmp,
                  rig +
                      "axes:\n  - {name: s, set: scene.layers.noise.seed, values: [1], range: "
                      "{first: 1, count: 2}}\n",
                  "exactly one of");
  ExpectPlanError(
      tmp, rig + "axes:\n  - {name: m, set: reconstruct.method, values: [midpoint, bogus]}\n",
      "bogus");
  ExpectPlanError(tmp, rig + "axes:\n  - {name: g, set: decode.shadow_threshold, values: [-3]}\n",
                  "shadow_threshold");
  const std::string noise_axis =
      "axes:\n  - {name: r, set: scene.layers.noise.read_noise_e, values: [5, 50]}\n";
  ExpectPlanError(tmp, rig + noise_axis + "curves: {x: q}\n", "'q' is not an axis");
  ExpectPlanError(tmp, rig + noise_axis + "pareto: {by: q}\n", "'q' is not an axis");
  ExpectPlanError(tmp, rig + noise_axis + "pareto: {time: cpus}\n", "pareto.time: must be");
  ExpectPlanError(tmp, rig + noise_axis + "effects: {axis: r, baseline: 7, tolerance_mm: 0.1}\n",
                  "baseline");
  const std::string layer_axis =
      "axes:\n  - {name: l, set: scene.layers, labels: [none, amb, all], values: [{}, {ambient: "
      "{level: 0.1}}, {projector_response: {gamma: 2}}]}\n";
  ExpectPlanError(
      tmp, rig + layer_axis + "effects: {axis: l, baseline: none, full: most, tolerance_mm: 0.1}\n",
      "effects.full: is not a value");
  ExpectPlanError(
      tmp, rig + layer_axis + "effects: {axis: l, baseline: none, full: all, tolerance_mm: 0.1}\n",
      "value 'amb' sets 'ambient', which the full model 'all' does not");
  ExpectPlanError(tmp,
                  rig +
                      "axes:\n  - {name: r, set: scene.layers.noise.read_noise_e, values: [5, "
                      "50], labels: [low]}\n",
                  "one label per value");
  ExpectPlanError(tmp, rig + noise_axis + "curves: {x: r, limits: {p99_mm: 1}}\n", "p99_mm");
  ExpectPlanError(tmp,
                  rig + "axes:\n  - {name: m, set: reconstruct.method, values: [midpoint]}\n" +
                      "curves: {x: m}\n",
                  "not a number");
  ExpectPlanError(tmp,
                  rig +
                      "axes:\n  - {name: t, set: scene.objects.0.albedo, values: [0.5, 0.6], "
                      "labels: [1, .nan]}\n",
                  "axes[0].labels[1]: a label must be a name or a finite number");
  // Numeric labels (e.g. angles for rotation vectors) can be a curve's x.
  std::ofstream(tmp / "labels.yaml")
      << "format: slshadow-study\nversion: 1\nname: labels\n"
      << rig
      << "axes:\n  - {name: t, set: scene.objects.0.albedo, values: [0.5, 0.6], "
         "labels: [10, 20.5]}\ncurves: {x: t}\n";
  PlanSweep(tmp / "labels.yaml", tmp / "labels_jobs");
  const nlohmann::json job =
      nlohmann::json::parse(ReadTextFile(tmp / "labels_jobs/jobs/000001.json"));
  EXPECT_EQ(job["params"]["t"], 20.5);
  EXPECT_EQ(job["scene"]["objects"][0]["albedo"], 0.6);

  WriteSmallStudy(tmp / "study.yaml");
  fs::create_directories(tmp / "exists");
  EXPECT_THROW(PlanSweep(tmp / "study.yaml", tmp / "exists"), Error);
  SweepRunOptions o;
  EXPECT_THROW(ParseShard("3/3", "--shard", &o), Error);
  EXPECT_THROW(ParseShard("1/0", "--shard", &o), Error);
  EXPECT_THROW(ParseShard("1-2", "--shard", &o), Error);
  EXPECT_THROW(ParseShard("1/2x", "--shard", &o), Error);
  ParseShard("1/2", "--shard", &o);
  EXPECT_EQ(o.shard_index, 1);
  EXPECT_EQ(o.shard_count, 2);
}

}  // namespace
}  // namespace slshadow::studies
