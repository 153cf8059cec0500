#include "capture/stop_on_interrupt.h"

#include <csignal>

namespace slshadow::capture {
namespace {

std::atomic<bool> g_stop{false};
extern "C" void RaiseStop(int) { g_stop.store(true); }

}  // namespace

StopOnInterrupt::StopOnInterrupt() {
  g_stop = false;
  previous_ = std::signal(SIGINT, RaiseStop);
}

StopOnInterrupt::~StopOnInterrupt() { std::signal(SIGINT, previous_); }

const std::atomic<bool>* StopOnInterrupt::flag() const { return &g_stop; }

}  // namespace slshadow::capture
