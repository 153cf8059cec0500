#include "core/progress.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>

namespace slshadow {

namespace {
thread_local std::shared_ptr<const ProgressObserver> thread_observer;
}  // namespace

ScopedProgressObserver::ScopedProgressObserver(ProgressObserver observer)
    : previous_(std::move(thread_observer)) {
  thread_observer = std::make_shared<const ProgressObserver>(std::move(observer));
}

ScopedProgressObserver::~ScopedProgressObserver() { thread_observer = std::move(previous_); }

Progress::Progress(std::string task, int64_t total, bool print)
    : task_(std::move(task)),
      total_(total),
      start_(std::chrono::steady_clock::now()),
      last_print_(start_),
      observer_(thread_observer) {
  const char* env = std::getenv("SLSHADOW_PROGRESS");
  enabled_ = print && (env ? std::strcmp(env, "0") != 0 : ::isatty(STDERR_FILENO) == 1);
}

Progress::~Progress() {
  if (shown_) Print(done_.load(), true);
}

double Progress::ElapsedSeconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
}

void Progress::Advance(int64_t steps) {
  const int64_t done = done_ += steps;
  if (observer_) {
    std::lock_guard<std::mutex> lock(mutex_);
    const int64_t latest = done_.load();
    if (latest > observed_) {
      observed_ = latest;
      (*observer_)(task_, latest, total_);
    }
  }
  if (!enabled_) return;
  const auto now = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(mutex_);
  if (now - last_print_ < std::chrono::milliseconds(250) && done < total_) return;
  last_print_ = now;
  Print(done, false);
}

void Progress::Print(int64_t done, bool final) {
  if (!enabled_) return;
  shown_ = true;
  const double pct =
      total_ > 0 ? 100.0 * static_cast<double>(done) / static_cast<double>(total_) : 100.0;
  std::fprintf(stderr, "\r%s: %3.0f%% (%lld/%lld), %.1f s%s", task_.c_str(), pct,
               static_cast<long long>(done), static_cast<long long>(total_), ElapsedSeconds(),
               final ? "\n" : "");
  std::fflush(stderr);
}

}  // namespace slshadow
