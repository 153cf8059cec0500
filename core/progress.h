// Progress on long work, printed to stderr as "task: 45% (9/20), 3.1 s" at most a few times a
// second, and only when stderr is a terminal or SLSHADOW_PROGRESS=1 (so logs and tests stay
// clean). Thread-safe.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace slshadow {

class Progress {
 public:
  Progress(std::string task, int64_t total);
  ~Progress();  // prints the final line when anything was shown
  void Advance(int64_t steps = 1);
  double ElapsedSeconds() const;

 private:
  void Print(int64_t done, bool final);
  std::string task_;
  int64_t total_;
  std::atomic<int64_t> done_{0};
  bool enabled_;
  bool shown_ = false;
  std::chrono::steady_clock::time_point start_, last_print_;
  std::mutex mutex_;
};

}  // namespace slshadow
