// One sweep job run (workflows/studies/sweep.h `sweep run`): render, decode, reconstruct and
// compare, with what a geometry group's jobs share kept from one job to the next
// (workflows/studies/sweep_reuse.h). Included only by workflows/studies/sweep.cc and
// workflows/studies/sweep_job.cc.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <memory>
#include <string>

namespace slshadow::studies::internal {

// The geometry group of a job: what the Simulator's geometry buffers depend on (jobs of one
// group share them).
std::string GeometryKey(const nlohmann::json& job);

// Runs the jobs of a shard one after the other, keeping the last geometry group's simulator,
// noise-free images, image buffers and ground-truth scorer for the next job of that group.
class SweepJobRunner {
 public:
  SweepJobRunner();
  ~SweepJobRunner();

  // The result of `job` (read from `file`, named in errors): its figures per mode and its
  // timings (docs/formats.md, "Study YAML ... and sweep folders"). `group_jobs_left`: the jobs of
  // this job's geometry group still to run in the shard, this one included
  // (GroundTruthScorer::Prepare's hint).
  // Throws slshadow::Error naming the file.
  nlohmann::json Run(const nlohmann::json& job, const std::filesystem::path& file,
                     int group_jobs_left);

  // Geometry groups traced so far (a new group: a new Simulator).
  int geometry_traces() const { return traces_; }

 private:
  struct Group;
  std::unique_ptr<Group> group_;
  int traces_ = 0;
};

}  // namespace slshadow::studies::internal
