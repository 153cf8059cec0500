// Per-stage wall time, CPU time and peak memory, as the benchmark paper in ../shared/seeds/
// reports for every module. A StageMeter measures from construction to Stop(): wall seconds,
// process CPU seconds (user + system, all threads; CPU / wall > 1 means parallel work), and the
// peak resident set size during the stage (Linux: VmHWM is reset at the stage's start by writing
// "5" to /proc/self/clear_refs; where that is not permitted, the process peak so far is
// reported and `peak_is_process_wide` is set).
#pragma once

#include <chrono>
#include <string>
#include <vector>

namespace slshadow {

struct StageMeasurement {
  std::string name;
  double wall_s = 0;
  double cpu_s = 0;
  double peak_rss_mb = 0;
  bool peak_is_process_wide = false;
  // Ran on a thread of its own, alongside the stages after it: wall and CPU are that thread's
  // (ThreadCpuSeconds), already part of the process CPU of the stages it overlapped, so a table's
  // total leaves them out; it has no peak of its own (peak_rss_mb is 0).
  bool concurrent = false;
};

class StageMeter {
 public:
  explicit StageMeter(std::string name);
  StageMeasurement Stop() const;

 private:
  std::string name_;
  std::chrono::steady_clock::time_point start_wall_;
  double start_cpu_s_;
  bool peak_reset_;
};

// Wall and process CPU seconds since construction (or Restart()), for stages inside a measured
// job (a reconstruction's rays, triangulation, filters): unlike StageMeter it leaves the peak
// memory counter alone, so it does not disturb an enclosing StageMeter.
class StageTimer {
 public:
  StageTimer() { Restart(); }
  void Restart();
  // Stores the wall and CPU seconds since construction or the last Restart().
  void Elapsed(double* wall_s, double* cpu_s) const;

 private:
  std::chrono::steady_clock::time_point start_wall_;
  double start_cpu_s_ = 0;
};

// Current process CPU time (user + system), seconds.
double ProcessCpuSeconds();
// CPU time of the calling thread (user + system), seconds.
double ThreadCpuSeconds();
// Current and peak resident set size of this process, MB (0 when unknown).
double CurrentRssMb();
double PeakRssMb();

// A fixed-width table of measurements: stage, wall s, CPU s, CPU/wall, peak RSS MB. Concurrent
// stages are marked "+" and a footnote says so; the total sums the others only.
std::string FormatStageTable(const std::vector<StageMeasurement>& stages);

}  // namespace slshadow
