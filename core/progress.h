// Progress on long work, printed to stderr as "task: 45% (9/20), 3.1 s" at most a few times a
// second, and only when stderr is a terminal or SLSHADOW_PROGRESS=1 (so logs and tests stay
// clean). Thread-safe.
//
// An observer (e.g. the Python module's progress callback) installed on a thread with
// ScopedProgressObserver sees every Progress constructed on that thread while it is installed:
// observer(task, done, total) after each Advance, from the thread that advanced, with `done`
// increasing from one call to the next (calls are serialised). An exception it throws leaves
// Advance.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>

namespace slshadow {

using ProgressObserver = std::function<void(const std::string& task, int64_t done, int64_t total)>;

class ScopedProgressObserver {
 public:
  explicit ScopedProgressObserver(ProgressObserver observer);
  ~ScopedProgressObserver();  // restores the thread's previous observer
  ScopedProgressObserver(const ScopedProgressObserver&) = delete;
  ScopedProgressObserver& operator=(const ScopedProgressObserver&) = delete;

 private:
  std::shared_ptr<const ProgressObserver> previous_;
};

class Progress {
 public:
  // print false: only an observer sees it (for work inside other work, e.g. the passes of one
  // simulation, whose lines would clutter a terminal).
  Progress(std::string task, int64_t total, bool print = true);
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
  std::shared_ptr<const ProgressObserver> observer_;  // the constructing thread's, or null
  int64_t observed_ = 0;                              // the last `done` the observer saw
};

}  // namespace slshadow
