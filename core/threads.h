// One thread budget for the whole process: OpenCV's parallel_for_ (cv::setNumThreads), TBB (a
// process-wide tbb::global_control, used by the simulator) and Ceres (calib/: Solver::Options and
// EvaluateOptions num_threads read ThreadBudget()). Set it once, early, from the command line or
// the scheduler's allocation; e.g. `slshadow sweep run --threads 4`, or SLURM_CPUS_PER_TASK under
// Slurm, so that shards sharing a machine do not each start one thread per core.
#pragma once

#include <string>

namespace slshadow {

// Applies `threads` (>= 1) to OpenCV, TBB and Ceres. Throws slshadow::Error when threads < 1.
void SetThreadBudget(int threads);

// The budget set by SetThreadBudget, or, when none was set, the number of hardware threads.
int ThreadBudget();

// The budget a command should use: `requested` when > 0; else SLURM_CPUS_PER_TASK when set (a
// positive integer; anything else throws slshadow::Error naming the variable and its value); else
// 0, meaning "leave the libraries' defaults". `source`, if not null, receives where the value came
// from ("--threads", "SLURM_CPUS_PER_TASK" or "default").
int ResolveThreadBudget(int requested, std::string* source = nullptr);

}  // namespace slshadow
