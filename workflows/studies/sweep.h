// Sweeps: a study (config/studies/*.yaml, docs/formats.md "Study YAML") planned into independent
// job files, run in shards by any scheduler (one process, GNU parallel, Slurm job arrays), merged
// into one result. Each job is a virtual scan of a scene by a rig with one pattern spec, decoded,
// reconstructed in a set of modes and compared with the scene's ground truth.
//
//   PlanSweep   STUDY.yaml -> JOBS/plan.json + JOBS/jobs/<id>.json (everything a job needs: scene
//               tree, rig, pattern spec, decode / reconstruct / compare options, the axis values)
//   RunSweepShard  JOBS/ shard I of N -> JOBS/results/<id>.json, each written atomically; a job
//               whose result exists is skipped, so an interrupted shard re-runs only what is
//               missing
//   MergeSweep  JOBS/ -> RESULT/results.csv + results.json (+ timings.csv, which is not
//   reproducible)
//   RunStudy    STUDY.yaml -> RESULT/ (the three in one process, jobs in RESULT/jobs/: planned
//               when missing, else resumed)
//
// Determinism: jobs carry fixed seeds (the noise layer's seed is part of the scene tree), and the
// shard of a job depends only on the plan and N, so results.csv and results.json are identical
// byte for byte whether the jobs ran in one process or in any number of shards, in any order.
//
// Geometry reuse: jobs whose scene differs only in radiometry and in layers that do not change
// geometry (everything but supersampling and projector defocus), with the same rig, form a
// geometry group. A shard runs its jobs group by group and traces each group once
// (sim::Simulator: BVH, camera rays, geometry buffers), and samples the ground truth once.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

namespace slshadow::studies {

// ---- Plan.

struct SweepPlanSummary {
  std::string study;  // the study's name
  int jobs = 0;
  int geometry_groups = 0;
  std::vector<std::string> axes;  // axis names, first the slowest
  // "study NAME: N jobs (G geometry groups) in JOBS_DIR", one line with its newline.
  std::string BriefReport(const std::filesystem::path& jobs_dir) const;
};

// Reads the study file and writes the plan at `jobs_dir` (which must not exist; written to a
// temporary sibling and renamed, so it appears complete or not at all). Every job is checked by
// the codecs that will read it (scene, rig, pattern spec, decode / reconstruct / compare options)
// before anything is written. Throws slshadow::Error naming the file, the field and the value.
SweepPlanSummary PlanSweep(const std::filesystem::path& study_file,
                           const std::filesystem::path& jobs_dir);

// ---- Run.

struct SweepRunOptions {
  int shard_index = 0;  // 0 .. shard_count - 1
  int shard_count = 1;
  bool verbose = false;  // one line per job
  void Check() const;
};

// Parses "I/N" (0 <= I < N); throws slshadow::Error naming `what` and the value.
void ParseShard(const std::string& text, const std::string& what, SweepRunOptions* options);

struct SweepRunSummary {
  int assigned = 0;      // jobs of this shard
  int already_done = 0;  // skipped: their result existed
  int ran = 0;
  int geometry_traces = 0;  // geometry groups traced (Simulator set-ups)
  double wall_s = 0;
  std::string BriefReport() const;
};

// The jobs of shard I of N: the plan's jobs ordered by geometry group (in order of first
// appearance), then by id, cut into N contiguous blocks of sizes differing by at most one.
std::vector<int> ShardJobs(const std::filesystem::path& jobs_dir, int shard_index, int shard_count);

// Runs the shard's jobs that have no result yet. Throws slshadow::Error on a malformed plan or
// job file (naming it); a job's result is written only when the job completed.
SweepRunSummary RunSweepShard(const std::filesystem::path& jobs_dir,
                              const SweepRunOptions& options);

// ---- Merge.

struct SweepMergeSummary {
  int jobs = 0;
  int rows = 0;                    // results.csv rows (one per job and mode)
  std::vector<std::string> front;  // "mode: id (axis values)" of the jobs on the Pareto front
  // A whole-part study (study key `whole_part`, workflows/studies/whole_part.h): `front` is that of
  // scan time against merged RMS, `coverage_front` that of scan time against coverage.
  bool whole_part = false;
  std::vector<std::string> coverage_front;
  // With the study key `curves`: "series, mode: metric > limit at x = value" per curve and limit.
  std::vector<std::string> break_points;
  // With the study key `effects`: "series, mode: value needed / not needed at T mm (off in the full
  // model | on alone: RMS .. mm, p95 .. mm; costs .. ms)" per layer (value) and mode.
  std::vector<std::string> effects;
  // With the study key `vdi2634`: "series, mode: PF .. PS .. SD .. F .." per series and mode.
  std::vector<std::string> acceptance;
  // With the study key `monte_carlo`: the uncertainty's summary and its 2-sigma coverage.
  std::vector<std::string> uncertainty;
  std::filesystem::path out_dir;
  // What `slshadow sweep merge` prints: the rows written, the Pareto front, then each of the
  // break points, the layer effects, the VDI/VDE 2634-2 figures and the uncertainty the study
  // asked for, each under a line naming its files in out_dir. Lines end in a newline.
  std::string FullReport() const;
};

// Reads every job's result (in id order) and writes at `out_dir` (created if missing; each file
// atomically): results.csv (one row per job and mode: id, the axis values, the accuracy figures),
// results.json (the plan's study and per job its axis values and accuracy), timings.csv (wall and
// CPU seconds per stage and job: measured, so not reproducible), and from those times pareto.csv
// (per job and mode: seconds to decode the cameras the mode reads and reconstruct it, RMS mm,
// whether on the mode's Pareto front) and
// time_vs_rms.png (the front marked and labelled with the axis values). Throws slshadow::Error
// naming the missing jobs (at most 10) when some have no result.
SweepMergeSummary MergeSweep(const std::filesystem::path& jobs_dir,
                             const std::filesystem::path& out_dir);

// ---- Plan, run and merge in one process.

struct SweepStudySummary {
  // True when `out_dir`/jobs held a plan already (a previous call): only its jobs without a result
  // ran. False: planned now, and `plan` describes it.
  bool resumed = false;
  SweepPlanSummary plan;
  std::filesystem::path jobs_dir;  // out_dir / "jobs"
  SweepRunSummary run;
  SweepMergeSummary merge;
};

// Plans the study into `out_dir`/jobs (kept, so that a second call resumes it), runs the shard of
// `options` (by default all jobs) and merges into `out_dir`. A plan that exists must come from the
// same study (its study_config); otherwise slshadow::Error names both files. Throws as PlanSweep,
// RunSweepShard and MergeSweep do. `planned`, if given, is called once the plan is written or found
// (resumed and plan set, run and merge not yet), before the jobs run: a command prints it then.
SweepStudySummary RunStudy(const std::filesystem::path& study_file,
                           const std::filesystem::path& out_dir, const SweepRunOptions& options,
                           const std::function<void(const SweepStudySummary&)>& planned = nullptr);

}  // namespace slshadow::studies
