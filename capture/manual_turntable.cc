#include "capture/manual_turntable.h"

#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstring>
#include <optional>

#include "core/string_printf.h"

namespace slshadow::capture {
namespace {

void WriteAll(int fd, const std::string& text) {
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return;  // a closed terminal: the prompt is lost, the read below says so
    done += static_cast<size_t>(n);
  }
}

// One line from `fd` without its newline; nullopt at end of input. Reads byte by byte so that
// nothing after the newline is taken from a shared stdin.
std::optional<std::string> ReadLine(int fd) {
  std::string line;
  for (;;) {
    char c = 0;
    const ssize_t n = ::read(fd, &c, 1);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return std::nullopt;
    if (c == '\n') return line;
    if (c != '\r') line += c;
  }
}

std::string Trimmed(const std::string& s) {
  const size_t begin = s.find_first_not_of(" \t");
  if (begin == std::string::npos) return "";
  return s.substr(begin, s.find_last_not_of(" \t") - begin + 1);
}

}  // namespace

ManualTurntable::ManualTurntable(const TurntableConfig& config, ManualTurntableIo io)
    : config_(config), io_(io) {
  config_.Check();
}

std::string ManualTurntable::Describe() const {
  return config_.where + ": manual (the operator turns the table)";
}

void ManualTurntable::Ask(const std::string& what, const std::string& request, double angle_deg) {
  double from_deg = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    from_deg = position_deg_;
  }
  const std::string prompt =
      StringPrintf("slshadow: turntable: %s (now at %.3f deg), ", what.c_str(), from_deg);
  if (config_.auto_confirm) {
    WriteAll(io_.out_fd, prompt + "auto-confirmed\n");
  } else {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      waiting_ = true;
    }
    WriteAll(io_.out_fd, prompt + "then press Enter (q to abort): ");
    const std::optional<std::string> line = ReadLine(io_.in_fd);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      waiting_ = false;
    }
    if (!line) {
      throw TurntableError(
          TurntableFault::kAborted,
          Describe() + ": " + request + ": the input closed before the operator confirmed");
    }
    const std::string answer = Trimmed(*line);
    if (answer == "q" || answer == "quit" || answer == "abort") {
      throw TurntableError(TurntableFault::kAborted,
                           Describe() + ": " + request + ": aborted by the operator");
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  position_deg_ = angle_deg;
}

void ManualTurntable::Home() { Ask("set the table to its zero mark (0 deg)", "home", 0.0); }

void ManualTurntable::MoveTo(double angle_deg) {
  const std::string request = StringPrintf("move to %.3f deg", angle_deg);
  if (!std::isfinite(angle_deg)) {
    throw TurntableError(TurntableFault::kRefused,
                         Describe() + ": " + request + ": not a finite angle");
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (angle_deg == position_deg_) return;
  }
  Ask(StringPrintf("turn the table to %.3f deg", angle_deg), request, angle_deg);
}

TurntableStatus ManualTurntable::Status() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (waiting_) return {TurntableState::kMoving, position_deg_, "waiting for the operator"};
  return {TurntableState::kIdle, position_deg_, "as the operator confirmed"};
}

}  // namespace slshadow::capture
