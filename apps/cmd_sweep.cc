// slshadow sweep plan STUDY.yaml --out JOBS/ | run JOBS/ [--shard I/N] | merge JOBS/ --out RESULT/
//               | study STUDY.yaml --out RESULT/ (the three in one process)
#include "apps/commands.h"
#include "core/error.h"
#include "core/threads.h"

#include <CLI/CLI.hpp>
#include "workflows/studies/sweep.h"

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>

namespace slshadow::app {
int RunSweep(int argc, char** argv) {
  CLI::App app{
      "Sweeps: a study (config/studies/*.yaml, docs/formats.md 'Study YAML') as independent jobs,\n"
      "run in shards by any scheduler, merged into one result (docs/sweeps.md for GNU parallel and "
      "Slurm):\n"
      "  sweep plan STUDY.yaml --out JOBS/    write one file per job (JOBS/jobs/*.json)\n"
      "  sweep run JOBS/ [--shard I/N]        run shard I of N (default 0/1: all); jobs with a "
      "result are skipped\n"
      "  sweep merge JOBS/ --out RESULT/      RESULT/results.csv, results.json (reproducible), "
      "timings.csv\n"
      "  sweep study STUDY.yaml --out RESULT/  plan into RESULT/jobs/ (kept: a second call resumes "
      "it), run every job, merge into RESULT/\n"
      "Merged results are identical byte for byte whatever the sharding.",
      argv[0]};
  app.require_subcommand(1);
  std::string study, jobs, out, shard = "0/1";
  bool verbose = false;
  int threads = 0;
  CLI::App* plan = app.add_subcommand("plan", "write the jobs of a study");
  plan->add_option("study", study, "study YAML")->required();
  plan->add_option("--out", out, "jobs folder (must not exist)")->required();
  CLI::App* run = app.add_subcommand("run", "run one shard of the jobs");
  run->add_option("jobs", jobs, "jobs folder written by sweep plan")->required();
  run->add_option("--shard", shard,
                  "I/N: shard I (0-based) of N; SLURM_ARRAY_TASK_ID / COUNT are not read")
      ->capture_default_str();
  run->add_flag("--verbose", verbose, "one line per job");
  run->add_option(
      "--threads", threads,
      "threads for OpenCV, TBB and Ceres (default: SLURM_CPUS_PER_TASK when set, else all cores)");
  CLI::App* merge = app.add_subcommand("merge", "merge the results of all jobs");
  merge->add_option("jobs", jobs, "jobs folder")->required();
  merge->add_option("--out", out, "result folder")->required();
  CLI::App* whole = app.add_subcommand("study", "plan, run and merge a study in one process");
  whole->add_option("study", study, "study YAML")->required();
  whole->add_option("--out", out, "result folder (its jobs in RESULT/jobs/)")->required();
  whole->add_flag("--verbose", verbose, "one line per job");
  whole->add_option("--threads", threads,
                    "threads for OpenCV, TBB and Ceres (default: SLURM_CPUS_PER_TASK when set, "
                    "else all cores)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  studies::SweepRunOptions options;
  if (plan->parsed()) std::fputs(studies::PlanSweep(study, out).BriefReport(out).c_str(), stdout);
  if (run->parsed() || whole->parsed()) {
    studies::ParseShard(shard, "--shard", &options);
    options.verbose = verbose;
    std::string source;
    const int budget = ResolveThreadBudget(threads, &source);
    if (budget > 0) SetThreadBudget(budget);
    std::printf("threads: %d (%s)\n", ThreadBudget(), source.c_str());
  }
  studies::SweepRunSummary ran;
  studies::SweepMergeSummary merged;
  if (whole->parsed()) {
    const studies::SweepStudySummary s =
        studies::RunStudy(study, out, options, [](const studies::SweepStudySummary& p) {
          if (p.resumed) {
            std::printf("resuming %s\n", p.jobs_dir.string().c_str());
          } else {
            std::fputs(p.plan.BriefReport(p.jobs_dir).c_str(), stdout);
          }
          std::fflush(stdout);
        });
    ran = s.run;
    merged = s.merge;
  }
  if (run->parsed()) ran = studies::RunSweepShard(jobs, options);
  if (run->parsed() || whole->parsed()) {
    std::printf("shard %d/%d: %s\n", options.shard_index, options.shard_count,
                ran.BriefReport().c_str());
  }
  if (merge->parsed()) merged = studies::MergeSweep(jobs, out);
  if (merge->parsed() || whole->parsed()) std::fputs(merged.FullReport().c_str(), stdout);
  return EXIT_SUCCESS;
}

}  // namespace slshadow::app
