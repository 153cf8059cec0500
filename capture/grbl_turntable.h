// A turntable driven by a GRBL 1.1 controller over a serial port (USB serial: /dev/ttyUSB0,
// /dev/ttyACM0), through termios; the protocol words are capture/grbl_protocol.h.
//
// Opening: the port raw at the configured baud; a soft reset (ctrl-x) and its welcome
// "Grbl 1.x..." within startup_timeout_ms (other firmware, or 0.9, is refused); a status report
// (`?`) that has the configured axis in MPos; the settings ($$): reports must be in millimetres
// ($13=0), and homing: true needs homing enabled ($22=1). A controller in alarm after the reset
// is left for Home() to clear (homing: true), unlocked with $X (unlock: true), or refused. Then
// G21 G90.
//
// The table angle is the axis' machine position (MPos) times degrees_per_unit: moves are
// `G90 G53 G0 <axis><units>` (or G1 with F at feed_deg_per_min), in machine coordinates, so work
// offsets (G54, G92) another program left do not shift the angle. MoveTo sends the move, waits for
// its ok, then polls `?` every poll_interval_ms until the controller is Idle with MPos within
// tolerance_deg of the target, then waits settle_ms. Failures (TurntableError, one line naming
// the device and the angle): error:N with its documented meaning (kDeviceError); ALARM:N pushed at
// any time, or an Alarm state (kAlarm); no ok / error or no status report within
// reply_timeout_ms (kTimeout); the target not reached within move_timeout_ms (kTimeout; a feed
// hold `!` is sent so the table stops, and the object stays usable); the port vanishing
// (kDisconnected). After a lost reply or status report, a homing cycle that did not end, a
// controller that reset itself or a vanished port the stream is out of step: the object refuses
// every further command and Status() is kFault; open a new one (its soft reset starts afresh).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "capture/grbl_protocol.h"
#include "capture/turntable.h"

namespace slshadow::capture {

namespace internal {
class SerialPort;
}  // namespace internal

class GrblTurntable : public Turntable {
 public:
  // Opens and sets up the controller as above; `config.backend` must be "grbl".
  explicit GrblTurntable(const TurntableConfig& config);
  ~GrblTurntable() override;

  void Home() override;
  void MoveTo(double angle_deg) override;
  TurntableStatus Status() override;
  std::string Describe() const override;

  // The firmware version of the welcome ("1.1h").
  const std::string& FirmwareVersion() const { return version_; }

 private:
  // Helpers below run with mutex_ held; they throw TurntableError with a bare message that
  // Guarded() prefixes with the device and the request.
  template <typename F>
  auto Guarded(const std::string& request, F&& body);
  void CheckUsable() const;
  // Marks the object unusable (the stream is out of step: a lost reply, a stuck port) and throws.
  [[noreturn]] void Broken(TurntableFault fault, const std::string& message);
  void Write(const std::string& bytes);  // through Broken on a port that takes no output
  void Handle(const std::string& line);
  bool Pump(std::chrono::steady_clock::time_point deadline, const auto& done);
  grbl::Line Command(const std::string& line, int64_t timeout_ms);
  grbl::StatusReport Query();
  double PositionDeg(const grbl::StatusReport& report) const;
  std::string AlarmText() const;

  TurntableConfig config_;
  int axis_index_ = 0;
  std::string version_;
  std::mutex mutex_;
  std::unique_ptr<internal::SerialPort> port_;
  // Stream state, updated by Handle().
  bool line_pending_ = false;               // a line command waits for its ok / error
  std::optional<grbl::Line> line_reply_;    // its answer, once it came
  std::optional<std::string> status_line_;  // the last status report since the last `?`
  int alarms_ = 0, last_alarm_ = 0;         // ALARM:N lines seen, and the last N
  int resets_ = 0;                          // welcome lines seen
  std::map<int, std::string> settings_;     // $N=value lines
  // Unusable after a lost reply or a vanished port: why (empty while usable), and what.
  std::string fault_;
  TurntableFault fault_kind_ = TurntableFault::kTimeout;
  double last_position_deg_ = 0;
};

}  // namespace slshadow::capture
