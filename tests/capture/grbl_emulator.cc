#include "tests/capture/grbl_emulator.h"

#include <fcntl.h>
#include <poll.h>
#include <pty.h>
#include <termios.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <stdexcept>

namespace slshadow::capture::testing {
namespace {

bool StartsWith(const std::string& s, const std::string& prefix) {
  return s.compare(0, prefix.size(), prefix) == 0;
}

std::string Format(const std::vector<double>& values) {
  std::string s;
  char buf[32];
  for (size_t i = 0; i < values.size(); ++i) {
    std::snprintf(buf, sizeof buf, "%s%.3f", i ? "," : "", values[i]);
    s += buf;
  }
  return s;
}

}  // namespace

GrblEmulator::GrblEmulator() : GrblEmulator(Options{}) {}

GrblEmulator::GrblEmulator(Options options) : options_(std::move(options)) {
  const auto axes = static_cast<size_t>(options_.axes);
  options_.work_offset.resize(axes, 0.0);
  position_.assign(axes, 0.0);
  start_ = target_ = position_;
  // Just powered up (or reset by DTR as the port opened): homing enabled locks it in alarm
  // (HOMING_INIT_LOCK) until $H or $X.
  if (options_.homing_enabled) state_ = "Alarm";
  char name[256] = {};
  if (::openpty(&master_, &slave_, name, nullptr, nullptr) != 0)
    throw std::runtime_error("openpty failed");
  port_ = name;
  // A real serial port is raw (no echo, no line editing); so is the slave end here.
  termios tio{};
  ::tcgetattr(slave_, &tio);
  ::cfmakeraw(&tio);
  ::tcsetattr(slave_, TCSANOW, &tio);
  ::fcntl(master_, F_SETFL, ::fcntl(master_, F_GETFL) | O_NONBLOCK);
  thread_ = std::thread([this] { Run(); });
}

GrblEmulator::~GrblEmulator() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  thread_.join();
  if (master_ >= 0) ::close(master_);
  ::close(slave_);
}

void GrblEmulator::Run() {
  auto last = std::chrono::steady_clock::now();
  for (;;) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (stop_) return;
      if (vanish_ && master_ >= 0) {
        ::close(master_);
        master_ = -1;
        changed_.notify_all();
      }
    }
    if (master_ < 0) {
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
      continue;
    }
    pollfd p{master_, POLLIN, 0};
    const int ready = ::poll(&p, 1, 2);
    std::lock_guard<std::mutex> lock(mutex_);
    if (ready > 0 && (p.revents & POLLIN)) {
      char buf[256];
      const ssize_t n = ::read(master_, buf, sizeof buf);
      for (ssize_t i = 0; i < n; ++i) OnByte(buf[i]);
    }
    const auto now = std::chrono::steady_clock::now();
    Advance(std::chrono::duration<double>(now - last).count());
    last = now;
    changed_.notify_all();
  }
}

void GrblEmulator::Send(const std::string& text) {
  if (silent_ || master_ < 0) return;
  const ssize_t n = ::write(master_, text.data(), text.size());
  (void)n;  // a full buffer loses the text, as an overrun serial line would
}

void GrblEmulator::OnByte(char c) {
  switch (c) {
    case '?':
      ++status_queries_;
      if (!drop_status_) SendStatus();
      return;
    case '!':
      ++feed_holds_;
      if (state_ == "Run") state_ = "Hold:0";
      return;
    case '~':
      if (StartsWith(state_, "Hold")) state_ = "Run";
      return;
    case 0x18:
      SoftReset();
      return;
    case '\n':
    case '\r': {
      const std::string line = partial_;
      partial_.clear();
      lines_.push_back(line);
      Execute(line);
      return;
    }
    default:
      partial_ += c;
  }
}

void GrblEmulator::SendStatus() {
  std::vector<double> reported = position_;
  const double scale = options_.report_inches ? 1.0 / 25.4 : 1.0;
  for (double& v : reported) v *= scale;
  std::string s = "<" + state_ + "|MPos:" + Format(reported) + "|FS:" +
                  std::to_string(static_cast<int>(state_ == "Run" ? speed_units_per_s_ * 60 : 0)) +
                  ",0";
  if (reports_++ % 10 == 0) s += "|WCO:" + Format(options_.work_offset);
  Send(s + ">\r\n");
}

void GrblEmulator::SoftReset() {
  ++soft_resets_;
  partial_.clear();
  const bool in_motion = state_ == "Run" || state_ == "Home" || StartsWith(state_, "Hold");
  target_ = start_ = position_;
  homing_ = false;
  absolute_ = true;
  inches_ = false;
  feed_ = 0;
  motion_mode_ = 0;
  if (in_motion) {
    Send("ALARM:3\r\n");
    state_ = "Alarm";
  }
  Send("\r\nGrbl " + options_.version + " ['$' for help]\r\n");
  // An alarm survives the reset (grbl protocol_main_loop); otherwise the controller is idle.
  if (state_ == "Alarm") {
    Send("[MSG:'$H'|'$X' to unlock]\r\n");
  } else {
    state_ = "Idle";
  }
}

void GrblEmulator::Execute(const std::string& line) {
  for (const auto& [prefix, code] : error_on_) {
    if (StartsWith(line, prefix)) {
      Send("error:" + std::to_string(code) + "\r\n");
      return;
    }
  }
  bool answer = true;
  for (const auto& prefix : drop_reply_) {
    if (StartsWith(line, prefix)) answer = false;
  }
  auto reply = [&](const std::string& text) {
    if (answer) Send(text + "\r\n");
  };
  if (line.empty()) return reply("ok");
  if (line == "$$") {
    Send("$0=10\r\n$1=25\r\n$10=1\r\n$13=" + std::string(options_.report_inches ? "1" : "0") +
         "\r\n$20=0\r\n$21=0\r\n$22=" + std::string(options_.homing_enabled ? "1" : "0") +
         "\r\n$27=1.000\r\n$100=80.000\r\n$110=500.000\r\n");
    return reply("ok");
  }
  if (line == "$X") {
    if (state_ == "Alarm") {
      state_ = "Idle";
      Send("[MSG:Caution: Unlocked]\r\n");
    }
    return reply("ok");
  }
  if (line == "$H") {
    if (!options_.homing_enabled) return reply("error:5");
    std::vector<double> home(position_.size(), options_.home_position);
    StartMotion(home, options_.homing_units_per_s, /*homing=*/true);
    if (!answer) homing_ = false;  // the cycle runs, its ok is lost
    return;                        // ok when the cycle ends (Advance)
  }
  if (line[0] == '$') return reply("error:3");
  if (state_ == "Alarm") return reply("error:9");
  ExecuteGcode(line, answer);
}

void GrblEmulator::ExecuteGcode(const std::string& line, bool answer) {
  static const std::string kAxes = "XYZABC";
  bool machine = false;
  int motion = motion_mode_;
  double feed = feed_;
  bool absolute = absolute_, inches = inches_;
  std::vector<std::optional<double>> words(position_.size());
  bool has_axis = false;
  auto reply = [&](const std::string& text) {
    if (answer) Send(text + "\r\n");
  };
  size_t i = 0;
  while (i < line.size()) {
    const char letter = static_cast<char>(std::toupper(static_cast<unsigned char>(line[i])));
    if (letter == ' ') {
      ++i;
      continue;
    }
    if (letter < 'A' || letter > 'Z') return reply("error:1");
    char* end = nullptr;
    const double value = std::strtod(line.c_str() + i + 1, &end);
    if (end == line.c_str() + i + 1) return reply("error:2");
    i = static_cast<size_t>(end - line.c_str());
    const size_t axis = kAxes.find(letter);
    if (letter == 'G') {
      const int g = static_cast<int>(std::lround(value * 10));
      if (g == 0 || g == 10) {
        motion = g / 10;
      } else if (g == 200 || g == 210) {
        inches = g == 200;
      } else if (g == 900 || g == 910) {
        absolute = g == 900;
      } else if (g == 530) {
        machine = true;
      } else if (g != 540) {
        return reply("error:20");
      }
    } else if (letter == 'F') {
      if (value < 0) return reply("error:4");
      feed = value;
    } else if (axis != std::string::npos && axis < position_.size()) {
      words[axis] = value;
      has_axis = true;
    } else {
      return reply("error:20");
    }
  }
  if (machine && motion != 0 && motion != 1) return reply("error:30");
  if (has_axis && motion == 1 && feed <= 0) return reply("error:22");
  motion_mode_ = motion;
  feed_ = feed;
  absolute_ = absolute;
  inches_ = inches;
  if (has_axis) {
    std::vector<double> target = position_;
    for (size_t a = 0; a < words.size(); ++a) {
      if (!words[a]) continue;
      const double v = *words[a] * (inches ? 25.4 : 1.0);
      target[a] = absolute ? v + (machine ? 0.0 : options_.work_offset[a]) : position_[a] + v;
    }
    const double speed = motion == 0 ? options_.rapid_units_per_s : feed / 60.0;
    StartMotion(target, speed, /*homing=*/false);
  }
  reply("ok");
}

void GrblEmulator::StartMotion(const std::vector<double>& target, double units_per_s, bool homing) {
  start_ = position_;
  target_ = target;
  if (!homing) {
    for (size_t a = 0; a < target_.size(); ++a)
      target_[a] = start_[a] + short_fraction_ * (target_[a] - start_[a]);
  }
  speed_units_per_s_ = units_per_s;
  homing_ = homing;
  state_ = homing ? "Home" : "Run";
}

void GrblEmulator::Advance(double dt_s) {
  if (state_ != "Run" && state_ != "Home") return;
  if (frozen_) return;
  double travel = 0, length = 0;
  bool arrived = true;
  for (size_t a = 0; a < position_.size(); ++a) {
    const double left = target_[a] - position_[a];
    const double step = std::min(std::abs(left), speed_units_per_s_ * dt_s);
    position_[a] += std::copysign(step, left);
    if (std::abs(target_[a] - position_[a]) > 1e-9) arrived = false;
    travel = std::max(travel, std::abs(position_[a] - start_[a]));
    length = std::max(length, std::abs(target_[a] - start_[a]));
  }
  if (alarm_code_ != 0 && (travel >= alarm_fraction_ * length || arrived)) {
    Send("ALARM:" + std::to_string(alarm_code_) + "\r\n");
    alarm_code_ = 0;
    state_ = "Alarm";
    homing_ = false;
    return;
  }
  if (!arrived) return;
  position_ = target_;
  state_ = "Idle";
  if (homing_) {
    homing_ = false;
    Send("ok\r\n");
  }
}

void GrblEmulator::ErrorOn(const std::string& line_prefix, int code) {
  std::lock_guard<std::mutex> lock(mutex_);
  error_on_[line_prefix] = code;
}

void GrblEmulator::DropReplyTo(const std::string& line_prefix) {
  std::lock_guard<std::mutex> lock(mutex_);
  drop_reply_.push_back(line_prefix);
}

void GrblEmulator::DropStatusReports(bool drop) {
  std::lock_guard<std::mutex> lock(mutex_);
  drop_status_ = drop;
}

void GrblEmulator::Silence(bool silent) {
  std::lock_guard<std::mutex> lock(mutex_);
  silent_ = silent;
}

void GrblEmulator::AlarmDuringNextMove(int code, double fraction) {
  std::lock_guard<std::mutex> lock(mutex_);
  alarm_code_ = code;
  alarm_fraction_ = fraction;
}

void GrblEmulator::StopMovesShort(double fraction) {
  std::lock_guard<std::mutex> lock(mutex_);
  short_fraction_ = fraction;
}

void GrblEmulator::FreezeMotion(bool frozen) {
  std::lock_guard<std::mutex> lock(mutex_);
  frozen_ = frozen;
}

void GrblEmulator::Vanish() {
  std::unique_lock<std::mutex> lock(mutex_);
  vanish_ = true;
  changed_.wait(lock, [&] { return master_ < 0; });
}

std::vector<std::string> GrblEmulator::Lines() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return lines_;
}

bool GrblEmulator::WaitForLine(const std::string& prefix, std::chrono::milliseconds timeout) const {
  std::unique_lock<std::mutex> lock(mutex_);
  return changed_.wait_for(lock, timeout, [&] {
    for (const auto& line : lines_) {
      if (StartsWith(line, prefix)) return true;
    }
    return false;
  });
}

double GrblEmulator::MachinePosition(int axis) const {
  std::lock_guard<std::mutex> lock(mutex_);
  return position_.at(static_cast<size_t>(axis));
}

void GrblEmulator::SetMachinePosition(int axis, double units) {
  std::lock_guard<std::mutex> lock(mutex_);
  position_.at(static_cast<size_t>(axis)) = units;
  start_ = target_ = position_;
}

std::string GrblEmulator::State() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return state_;
}

int GrblEmulator::soft_resets() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return soft_resets_;
}

int GrblEmulator::status_queries() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return status_queries_;
}

int GrblEmulator::feed_holds() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return feed_holds_;
}

}  // namespace slshadow::capture::testing
