#include "capture/grbl_turntable.h"

#include <cmath>
#include <thread>

#include "capture/internal/serial_port.h"
#include "core/string_printf.h"

namespace slshadow::capture {
namespace {

using Clock = std::chrono::steady_clock;

Clock::time_point After(int64_t ms) { return Clock::now() + std::chrono::milliseconds(ms); }

TurntableState StateOf(const std::string& grbl_state) {
  if (grbl_state == "Idle") return TurntableState::kIdle;
  if (grbl_state == "Run" || grbl_state == "Jog") return TurntableState::kMoving;
  if (grbl_state == "Home") return TurntableState::kHoming;
  if (grbl_state == "Alarm") return TurntableState::kAlarm;
  // Hold, Door, Check (G-code check mode), Sleep: neither ready nor moving.
  return TurntableState::kHold;
}

std::string StateText(const grbl::StatusReport& report) {
  return report.substate < 0 ? report.state : report.state + ":" + std::to_string(report.substate);
}

[[noreturn]] void Fail(TurntableFault fault, const std::string& message) {
  throw TurntableError(fault, message);
}

}  // namespace

template <typename F>
auto GrblTurntable::Guarded(const std::string& request, F&& body) {
  try {
    return body();
  } catch (const TurntableError& e) {
    std::lock_guard<std::mutex> lock(mutex_);
    if (fault_.empty() && e.fault() == TurntableFault::kDisconnected) {
      fault_ = e.what();
      fault_kind_ = e.fault();
    }
    throw TurntableError(e.fault(), Describe() + ": " + request + ": " + e.what());
  }
}

GrblTurntable::GrblTurntable(const TurntableConfig& config) : config_(config) {
  config_.Check();
  axis_index_ = grbl::AxisIndex(config_.axis[0]);
  Guarded("open", [&] {
    std::lock_guard<std::mutex> lock(mutex_);
    port_ = std::make_unique<internal::SerialPort>(config_.port, config_.baud);
    port_->DiscardInput();
    Write(std::string(1, grbl::kSoftReset));
    const int resets = resets_;
    if (!Pump(After(config_.startup_timeout_ms), [&] { return resets_ != resets; })) {
      Fail(TurntableFault::kTimeout,
           StringPrintf("no welcome (\"Grbl 1.1...\") within %lld ms of a soft reset (ctrl-x): is "
                        "a GRBL 1.1 controller on %s at %d baud?",
                        static_cast<long long>(config_.startup_timeout_ms), config_.port.c_str(),
                        config_.baud));
    }
    if (version_.rfind("1.", 0) != 0) {
      Fail(TurntableFault::kRefused,
           "the controller runs Grbl " + version_ + "; slshadow speaks the interface of GRBL 1.1");
    }
    const grbl::StatusReport report = Query();
    last_position_deg_ = PositionDeg(report);
    settings_.clear();
    Command("$$", config_.reply_timeout_ms);
    if (settings_.count(13) && settings_[13] != "0") {
      Fail(TurntableFault::kRefused, "the controller reports positions in inches ($13=" +
                                         settings_[13] + "): set $13=0 (millimetres)");
    }
    if (config_.homing && settings_.count(22) && settings_[22] == "0") {
      Fail(TurntableFault::kRefused,
           config_.where +
               ".homing is true but homing is disabled in the firmware ($22=0): set "
               "$22=1, or homing: false");
    }
    if (report.state == "Alarm") {
      if (config_.homing) return;  // Home() clears it; G21 G90 follow the homing cycle
      if (!config_.unlock) {
        const std::string why = last_alarm_ ? " (" + AlarmText() + ")"
                                : settings_[22] == "1"
                                    ? " (homing is enabled in the firmware, $22=1)"
                                    : "";
        Fail(TurntableFault::kAlarm, "the controller is in alarm after its reset" + why + ": set " +
                                         config_.where +
                                         ".homing: true to home it, or unlock: true to unlock it "
                                         "($X) without homing");
      }
      Command("$X", config_.reply_timeout_ms);
    }
    Command("G21 G90", config_.reply_timeout_ms);
  });
}

GrblTurntable::~GrblTurntable() = default;

std::string GrblTurntable::Describe() const {
  return config_.where + ": grbl on " + config_.port + " (axis " + config_.axis + ")";
}

void GrblTurntable::CheckUsable() const {
  if (!fault_.empty()) {
    Fail(fault_kind_, "unusable after an earlier failure (" + fault_ + "); reopen the turntable");
  }
}

void GrblTurntable::Broken(TurntableFault fault, const std::string& message) {
  if (fault_.empty()) {
    fault_ = message;
    fault_kind_ = fault;
  }
  Fail(fault, message);
}

void GrblTurntable::Write(const std::string& bytes) {
  try {
    port_->Write(bytes, After(config_.reply_timeout_ms));
  } catch (const TurntableError& e) {
    Broken(e.fault(), e.what());
  }
}

std::string GrblTurntable::AlarmText() const {
  return "ALARM:" + std::to_string(last_alarm_) + ", " + grbl::AlarmMeaning(last_alarm_);
}

void GrblTurntable::Handle(const std::string& text) {
  const grbl::Line line = grbl::ClassifyLine(text);
  switch (line.kind) {
    case grbl::LineKind::kOk:
    case grbl::LineKind::kError:
      if (line_pending_) {
        line_reply_ = line;
        line_pending_ = false;
      }
      break;
    case grbl::LineKind::kStatus:
      status_line_ = text;
      break;
    case grbl::LineKind::kAlarm:
      ++alarms_;
      last_alarm_ = line.code;
      break;
    case grbl::LineKind::kWelcome:
      ++resets_;
      version_ = grbl::WelcomeVersion(text);
      line_pending_ = false;  // a reset drops the line being executed
      break;
    case grbl::LineKind::kSetting:
      settings_[line.code] = line.text;
      break;
    case grbl::LineKind::kMessage:
    case grbl::LineKind::kOther:
      break;  // feedback a turntable does not need ([MSG:...], [GC:...], startup lines)
  }
}

bool GrblTurntable::Pump(Clock::time_point deadline, const auto& done) {
  while (!done()) {
    const std::optional<std::string> line = port_->ReadLine(deadline);
    if (!line) return done();
    Handle(*line);
  }
  return true;
}

grbl::Line GrblTurntable::Command(const std::string& text, int64_t timeout_ms) {
  CheckUsable();
  line_reply_.reset();
  line_pending_ = true;
  const int alarms = alarms_, resets = resets_;
  Write(text + "\n");
  const bool answered = Pump(After(timeout_ms), [&] {
    return line_reply_.has_value() || alarms_ != alarms || resets_ != resets;
  });
  if (alarms_ != alarms) Fail(TurntableFault::kAlarm, "\"" + text + "\" raised " + AlarmText());
  if (resets_ != resets)
    Broken(TurntableFault::kDeviceError, "the controller reset itself during \"" + text + "\"");
  if (!answered) {
    Broken(TurntableFault::kTimeout, StringPrintf("no reply to \"%s\" within %lld ms", text.c_str(),
                                                  static_cast<long long>(timeout_ms)));
  }
  if (line_reply_->kind == grbl::LineKind::kError) {
    Fail(TurntableFault::kDeviceError,
         "\"" + text + "\" answered error:" + std::to_string(line_reply_->code) + " (" +
             grbl::ErrorMeaning(line_reply_->code) + ")");
  }
  return *line_reply_;
}

grbl::StatusReport GrblTurntable::Query() {
  CheckUsable();
  status_line_.reset();
  Write(std::string(1, grbl::kStatusQuery));
  if (!Pump(After(config_.reply_timeout_ms), [&] { return status_line_.has_value(); })) {
    Broken(TurntableFault::kTimeout,
           StringPrintf("no status report within %lld ms of a status query (?)",
                        static_cast<long long>(config_.reply_timeout_ms)));
  }
  const std::optional<grbl::StatusReport> report = grbl::ParseStatusReport(*status_line_);
  if (!report) Fail(TurntableFault::kDeviceError, "malformed status report " + *status_line_);
  return *report;
}

double GrblTurntable::PositionDeg(const grbl::StatusReport& report) const {
  const auto axes = static_cast<int>(report.machine_position.size());
  if (axes == 0) {
    Fail(TurntableFault::kRefused,
         "the status report has no machine position (MPos): set the report mask $10=1");
  }
  if (axis_index_ >= axes) {
    Fail(TurntableFault::kRefused,
         StringPrintf("the controller reports %d axes, none is %s (stock GRBL 1.1 has X, Y, Z): "
                      "set %s.axis",
                      axes, config_.axis.c_str(), config_.where.c_str()));
  }
  return report.machine_position[static_cast<size_t>(axis_index_)] * config_.degrees_per_unit;
}

void GrblTurntable::Home() {
  if (!config_.homing) return;
  Guarded("home", [&] {
    const int64_t ms = config_.home_timeout_ms;
    const Clock::time_point deadline = After(ms);
    int alarms = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      CheckUsable();
      alarms = alarms_;
      line_reply_.reset();
      line_pending_ = true;
      Write("$H\n");
    }
    // $H is answered when the cycle ends; poll meanwhile, so Status() answers between polls.
    for (;;) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        Pump(After(std::min(config_.poll_interval_ms, ms)),
             [&] { return line_reply_.has_value() || alarms_ != alarms; });
        if (alarms_ != alarms) Fail(TurntableFault::kAlarm, "homing raised " + AlarmText());
        if (line_reply_) {
          if (line_reply_->kind == grbl::LineKind::kError) {
            Fail(TurntableFault::kDeviceError,
                 "\"$H\" answered error:" + std::to_string(line_reply_->code) + " (" +
                     grbl::ErrorMeaning(line_reply_->code) + ")");
          }
          break;
        }
        if (Clock::now() >= deadline) {
          Broken(TurntableFault::kTimeout,
                 StringPrintf("the homing cycle did not end within %lld ms",
                              static_cast<long long>(ms)));
        }
        last_position_deg_ = PositionDeg(Query());
        if (alarms_ != alarms) Fail(TurntableFault::kAlarm, "homing raised " + AlarmText());
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(config_.poll_interval_ms));
    }
    std::lock_guard<std::mutex> lock(mutex_);
    Command("G21 G90", config_.reply_timeout_ms);
    last_position_deg_ = PositionDeg(Query());
  });
}

void GrblTurntable::MoveTo(double angle_deg) {
  const std::string request = StringPrintf("move to %.3f deg", angle_deg);
  if (!std::isfinite(angle_deg)) {
    throw TurntableError(TurntableFault::kRefused,
                         Describe() + ": " + request + ": not a finite angle");
  }
  Guarded(request, [&] {
    const double target_units = angle_deg / config_.degrees_per_unit;
    int alarms = 0, resets = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      const grbl::StatusReport report = Query();
      last_position_deg_ = PositionDeg(report);
      if (report.state == "Alarm") {
        Fail(TurntableFault::kAlarm,
             "the controller is in alarm" + (last_alarm_ ? " (" + AlarmText() + ")" : "") +
                 ": home it first (" + config_.where + ".homing: true) or unlock it ($X)");
      }
      if (report.state != "Idle") {
        Fail(TurntableFault::kRefused,
             "the controller is not idle (" + StateText(report) + "): resume or reset it first");
      }
      alarms = alarms_;
      resets = resets_;
      const std::string axis_word = StringPrintf("%s%.4f", config_.axis.c_str(), target_units);
      if (config_.feed_deg_per_min > 0) {
        const double feed = config_.feed_deg_per_min / std::abs(config_.degrees_per_unit);
        Command(StringPrintf("G90 G53 G1 %s F%.3f", axis_word.c_str(), feed),
                config_.reply_timeout_ms);
      } else {
        Command("G90 G53 G0 " + axis_word, config_.reply_timeout_ms);
      }
    }
    const Clock::time_point deadline = After(config_.move_timeout_ms);
    for (;;) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        const grbl::StatusReport report = Query();
        const double at_deg = PositionDeg(report);
        last_position_deg_ = at_deg;
        if (alarms_ != alarms) {
          Fail(TurntableFault::kAlarm,
               StringPrintf("%s (the table stopped at %.3f deg)", AlarmText().c_str(), at_deg));
        }
        if (report.state == "Alarm") {
          Fail(TurntableFault::kAlarm,
               StringPrintf("the controller went into alarm at %.3f deg", at_deg));
        }
        if (resets_ != resets) {
          Broken(TurntableFault::kDeviceError,
                 StringPrintf("the controller reset itself during the move, at %.3f deg", at_deg));
        }
        if (report.state == "Idle" && std::abs(at_deg - angle_deg) <= config_.tolerance_deg) break;
        if (Clock::now() >= deadline) {
          Write(std::string(1, grbl::kFeedHold));
          try {
            Query();  // the hold is acted on before this `?`: the table has stopped when we throw
          } catch (const TurntableError&) {
            // the timeout below is the error to report
          }
          Fail(TurntableFault::kTimeout,
               StringPrintf("not reached within %lld ms: the controller reports %s at %.3f deg "
                            "(a feed hold was sent)",
                            static_cast<long long>(config_.move_timeout_ms),
                            StateText(report).c_str(), at_deg));
        }
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(config_.poll_interval_ms));
    }
    if (config_.settle_ms > 0)
      std::this_thread::sleep_for(std::chrono::milliseconds(config_.settle_ms));
  });
}

TurntableStatus GrblTurntable::Status() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!fault_.empty()) return {TurntableState::kFault, last_position_deg_, fault_};
  try {
    const grbl::StatusReport report = Query();
    last_position_deg_ = PositionDeg(report);
    TurntableStatus status{StateOf(report.state), last_position_deg_, StateText(report)};
    if (status.state == TurntableState::kAlarm && last_alarm_) {
      status.detail += " (" + AlarmText() + ")";
    }
    return status;
  } catch (const TurntableError& e) {
    if (fault_.empty() && e.fault() == TurntableFault::kDisconnected) {
      fault_ = e.what();
      fault_kind_ = e.fault();
    }
    return {TurntableState::kFault, last_position_deg_, e.what()};
  }
}

}  // namespace slshadow::capture
