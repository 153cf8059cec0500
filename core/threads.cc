#include "core/threads.h"

#include "core/error.h"

#include <tbb/global_control.h>
#include <opencv2/core/utility.hpp>

#include <atomic>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <thread>

namespace slshadow {
namespace {

std::atomic<int> g_budget{0};
std::mutex g_mutex;
std::unique_ptr<tbb::global_control> g_tbb;  // lives until exit (or the next SetThreadBudget)

}  // namespace

void SetThreadBudget(int threads) {
  SLSHADOW_THROW_IF(threads < 1, "thread budget: must be at least 1 (got ", threads, ")");
  std::lock_guard<std::mutex> lock(g_mutex);
  cv::setNumThreads(threads);
  g_tbb.reset();
  g_tbb = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                static_cast<size_t>(threads));
  g_budget = threads;
}

int ThreadBudget() {
  const int b = g_budget.load();
  if (b > 0) return b;
  const unsigned hw = std::thread::hardware_concurrency();
  return hw > 0 ? static_cast<int>(hw) : 1;
}

int ResolveThreadBudget(int requested, std::string* source) {
  if (requested > 0) {
    if (source) *source = "--threads";
    return requested;
  }
  const char* slurm = std::getenv("SLURM_CPUS_PER_TASK");
  if (slurm && *slurm) {
    char* end = nullptr;
    const long n = std::strtol(slurm, &end, 10);
    SLSHADOW_THROW_IF(*end != '\0' || n < 1 || n > 4096, "SLURM_CPUS_PER_TASK: '", slurm,
                      "' is not a positive thread count");
    if (source) *source = "SLURM_CPUS_PER_TASK";
    return static_cast<int>(n);
  }
  if (source) *source = "default";
  return 0;
}

}  // namespace slshadow
