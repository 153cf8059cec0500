#include "core/stage_meter.h"

#include <sys/resource.h>
#include <time.h>

#include <algorithm>
#include <cstdio>
#include <fstream>
#include <sstream>

namespace slshadow {
namespace {

double ReadStatusKb(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string prefix = std::string(key) + ":";
  while (std::getline(in, line)) {
    if (line.rfind(prefix, 0) == 0) {
      std::istringstream s(line.substr(prefix.size()));
      double kb = 0;
      s >> kb;
      return kb;
    }
  }
  return 0;
}

bool ResetPeakRss() {
  std::ofstream out("/proc/self/clear_refs");
  if (!out) return false;
  out << "5";
  out.close();
  return static_cast<bool>(out);
}

}  // namespace

double ProcessCpuSeconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_utime.tv_sec + usage.ru_stime.tv_sec) +
         1e-6 * static_cast<double>(usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

double ThreadCpuSeconds() {
  timespec t{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

double CurrentRssMb() { return ReadStatusKb("VmRSS") / 1024.0; }
double PeakRssMb() { return ReadStatusKb("VmHWM") / 1024.0; }

StageMeter::StageMeter(std::string name)
    : name_(std::move(name)),
      start_wall_(std::chrono::steady_clock::now()),
      start_cpu_s_(ProcessCpuSeconds()),
      peak_reset_(ResetPeakRss()) {}

StageMeasurement StageMeter::Stop() const {
  StageMeasurement m;
  m.name = name_;
  m.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_wall_).count();
  m.cpu_s = ProcessCpuSeconds() - start_cpu_s_;
  m.peak_rss_mb = PeakRssMb();
  m.peak_is_process_wide = !peak_reset_;
  return m;
}

std::string FormatStageTable(const std::vector<StageMeasurement>& stages) {
  std::string out = "stage                          wall (s)   CPU (s)  CPU/wall  peak RSS (MB)\n";
  char buf[160];
  double wall = 0, cpu = 0, peak = 0;
  bool any_concurrent = false;
  for (const auto& s : stages) {
    if (s.concurrent) {
      std::snprintf(buf, sizeof(buf), "%-30s %8.3f  %8.3f  %8.2f  %13s +\n", s.name.c_str(),
                    s.wall_s, s.cpu_s, s.wall_s > 0 ? s.cpu_s / s.wall_s : 0.0, "-");
      out += buf;
      any_concurrent = true;
      continue;
    }
    std::snprintf(buf, sizeof(buf), "%-30s %8.3f  %8.3f  %8.2f  %13.0f%s\n", s.name.c_str(),
                  s.wall_s, s.cpu_s, s.wall_s > 0 ? s.cpu_s / s.wall_s : 0.0, s.peak_rss_mb,
                  s.peak_is_process_wide ? " *" : "");
    out += buf;
    wall += s.wall_s;
    cpu += s.cpu_s;
    peak = std::max(peak, s.peak_rss_mb);
  }
  std::snprintf(buf, sizeof(buf), "%-30s %8.3f  %8.3f  %8.2f  %13.0f\n", "total", wall, cpu,
                wall > 0 ? cpu / wall : 0.0, peak);
  out += buf;
  if (any_concurrent) {
    out +=
        "+ on a thread of its own, alongside the stages after it: its wall and CPU time are its "
        "thread's, already inside theirs (not added to the total)\n";
  }
  return out;
}

void StageTimer::Restart() {
  start_wall_ = std::chrono::steady_clock::now();
  start_cpu_s_ = ProcessCpuSeconds();
}

void StageTimer::Elapsed(double* wall_s, double* cpu_s) const {
  *cpu_s = ProcessCpuSeconds() - start_cpu_s_;
  *wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_wall_).count();
}

}  // namespace slshadow
