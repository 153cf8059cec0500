// The process thread budget (core/threads.h): applied to OpenCV and TBB as read back from each
// library, and resolved from --threads or SLURM_CPUS_PER_TASK.
#include "core/threads.h"

#include "core/error.h"

#include <gtest/gtest.h>
#include <tbb/global_control.h>
#include <opencv2/core/utility.hpp>

#include <cstdlib>
#include <string>

namespace slshadow {
namespace {

TEST(ThreadBudget, AppliesToOpenCvAndTbb) {
  SetThreadBudget(1);
  EXPECT_EQ(ThreadBudget(), 1);
  EXPECT_EQ(cv::getNumThreads(), 1);
  EXPECT_EQ(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism), 1u);
  SetThreadBudget(2);
  EXPECT_EQ(ThreadBudget(), 2);
  EXPECT_EQ(cv::getNumThreads(), 2);
  EXPECT_EQ(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism), 2u);
  EXPECT_THROW(SetThreadBudget(0), Error);
  EXPECT_EQ(ThreadBudget(), 2);  // unchanged by the refused value
}

TEST(ThreadBudget, ResolvesFromTheCommandLineThenSlurm) {
  std::string source;
  unsetenv("SLURM_CPUS_PER_TASK");
  EXPECT_EQ(ResolveThreadBudget(0, &source), 0);
  EXPECT_EQ(source, "default");
  setenv("SLURM_CPUS_PER_TASK", "3", 1);
  EXPECT_EQ(ResolveThreadBudget(0, &source), 3);
  EXPECT_EQ(source, "SLURM_CPUS_PER_TASK");
  EXPECT_EQ(ResolveThreadBudget(5, &source), 5);
  EXPECT_EQ(source, "--threads");
  setenv("SLURM_CPUS_PER_TASK", "3x", 1);
  try {
    ResolveThreadBudget(0);
    ADD_FAILURE() << "no error for SLURM_CPUS_PER_TASK=3x";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("SLURM_CPUS_PER_TASK: '3x'"), std::string::npos)
        << e.what();
  }
  setenv("SLURM_CPUS_PER_TASK", "0", 1);
  EXPECT_THROW(ResolveThreadBudget(0), Error);
  unsetenv("SLURM_CPUS_PER_TASK");
}

}  // namespace
}  // namespace slshadow
