// The turntable seam of capture/: a rotary table that turns the part between the views of a
// multi-view scan. Backends: GRBL 1.1 over a serial port (capture/grbl_turntable.h), "manual" (an
// operator turns the table when asked, capture/manual_turntable.h) and "none" (no table: one view).
// Backend types (termios, file descriptors) never appear in this header.
//
// Angles are degrees of table rotation as the device counts them (GRBL: the axis' machine
// position times degrees_per_unit), absolute, not wrapped: 370 is one turn past 10. The offset and
// scale between this count and the true rotation about the rig's axis are calibrated (calib/).
//
// Life cycle: OpenTurntable(config) -> Home() (once, where the table can be referenced) ->
// { MoveTo(angle) }*. Errors: a device that cannot be opened, refuses a command, raises an
// alarm, does not answer or vanishes throws TurntableError, one line naming the device and the
// request ("FILE: turntable: grbl on /dev/ttyUSB0 (axis X): move to 90.000 deg: ALARM:1 ...").
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/error.h"

namespace slshadow {
class ConfigNode;
}  // namespace slshadow

namespace slshadow::capture {

enum class TurntableState {
  kIdle,    // at rest, ready for a move
  kMoving,  // turning (GRBL Run or Jog)
  kHoming,  // in its homing cycle
  kHold,    // paused by a feed hold or an open safety door (GRBL Hold, Door); resumes on its own
            // command, not slshadow's
  kAlarm,   // the firmware locked itself (limit hit, homing failed, homing required, reset in a
            // move): needs Home() or an unlock
  kFault    // unusable: the port vanished or a reply never came; reopen the device
};
// "idle", "moving", "homing", "hold", "alarm", "fault".
std::string ToString(TurntableState state);
// Moving or homing: a move is under way.
inline bool Busy(TurntableState state) {
  return state == TurntableState::kMoving || state == TurntableState::kHoming;
}

struct TurntableStatus {
  TurntableState state = TurntableState::kIdle;
  double position_deg = 0;  // table angle the device reports; the last known one for kFault
  std::string detail;       // device words: "Hold:0", "ALARM:1 (hard limit ...)", why kFault
};

// What went wrong, for a caller that reacts differently (a scan keeps its views and stops).
enum class TurntableFault {
  kRefused,       // bad request for this device (a move with backend none, a non-finite angle),
                  // or a controller set up in a way slshadow cannot use; nothing was moved
  kDeviceError,   // the firmware answered a command with an error (GRBL error:N)
  kAlarm,         // the firmware raised an alarm (GRBL ALARM:N) or is locked in alarm
  kTimeout,       // a reply, a status report or the end of a move did not come in time
  kDisconnected,  // the port could not be opened, or vanished (end of file, EIO, hang-up)
  kAborted        // the operator aborted (manual backend), or its input closed
};
// "refused", "device-error", "alarm", "timeout", "disconnected", "aborted".
std::string ToString(TurntableFault fault);

// The one exception type of turntable backends; what() is one line naming the device.
class TurntableError : public Error {
 public:
  TurntableError(TurntableFault fault, const std::string& message)
      : Error(message), fault_(fault) {}
  TurntableFault fault() const { return fault_; }

 private:
  TurntableFault fault_;
};

// The `turntable:` entry of devices.yaml (docs/formats.md, "Devices YAML"); defaults in-line.
struct TurntableConfig {
  std::string backend = "none";  // "grbl", "manual", "none"
  // grbl: the serial port and its speed (8N1, raw, no flow control).
  std::string port = "/dev/ttyUSB0";
  int baud = 115200;
  // grbl: the axis letter the table is wired to (X, Y, Z; A, B, C on firmware with more axes).
  std::string axis = "X";
  // grbl: table degrees per firmware unit (GRBL counts "mm"; $100..$102 steps per unit set how
  // many motor steps one unit is). Non-zero; negative reverses the direction.
  double degrees_per_unit = 1.0;
  // grbl: table speed of a move, degrees per minute; 0 moves at the firmware's rapid rate (G0).
  double feed_deg_per_min = 0;
  double tolerance_deg = 0.01;        // grbl: a move has arrived when |position - target| <= this
  int64_t move_timeout_ms = 60000;    // grbl: longest wait for one move, from command to arrival
  int64_t home_timeout_ms = 120000;   // grbl: longest wait for the homing cycle ($H)
  int64_t reply_timeout_ms = 2000;    // grbl: longest wait for an ok / error or a status report
  int64_t startup_timeout_ms = 5000;  // grbl: longest wait for the welcome after a reset
  int64_t poll_interval_ms = 100;     // grbl: status queries (`?`) while a move runs
  int64_t settle_ms = 0;              // grbl: wait after arrival before MoveTo returns
  // grbl: Home() runs the homing cycle ($H); needs homing enabled in the firmware ($22=1).
  bool homing = false;
  // grbl: without homing, unlock ($X) a controller found in alarm after its reset, instead of
  // refusing to open (the table's position is then what the controller kept across the reset).
  bool unlock = false;
  // manual: print the prompt but do not wait for Enter (scripts; the table is assumed turned).
  bool auto_confirm = false;
  std::string where = "turntable";  // "FILE: turntable", for messages
  // Throws slshadow::Error naming `where` and the field on a value out of range.
  void Check() const;
};

// Backend names the devices.yaml schema knows: "grbl", "manual", "none".
const std::vector<std::string>& KnownTurntableBackends();
// Reads a `turntable:` node; `where` names it in messages ("FILE: turntable").
TurntableConfig TurntableConfigFromConfig(const ConfigNode& node, const std::string& where);

class Turntable {
 public:
  virtual ~Turntable() = default;
  // References the table: grbl with homing: true runs the homing cycle ($H) and waits for it
  // (home_timeout_ms), which also clears an alarm; manual asks the operator to set the table to
  // its zero mark (the position is then 0); none, and grbl with homing: false, do nothing.
  virtual void Home() = 0;
  // Turns the table to the absolute angle and returns when it is there (within the backend's
  // tolerance and after its settle time). Throws TurntableError naming the device and the angle.
  virtual void MoveTo(double angle_deg) = 0;
  // Asks the device now. Never throws for a device fault: an unreachable device is kFault with
  // the reason in `detail`. Callable from another thread while MoveTo or Home() runs (grbl
  // answers between its own polls).
  virtual TurntableStatus Status() = 0;
  // One line naming the device: "FILE: turntable: grbl on /dev/ttyUSB0 (axis X)".
  virtual std::string Describe() const = 0;

  double PositionDeg() { return Status().position_deg; }
  TurntableState State() { return Status().state; }
};

// Opens the table of `config` (config.Check() first): grbl opens the port, resets the controller
// and waits for its welcome (see capture/grbl_turntable.h); manual talks on stderr / stdin.
// Throws TurntableError (kDisconnected, kTimeout, kRefused, kAlarm) naming the device.
std::unique_ptr<Turntable> OpenTurntable(const TurntableConfig& config);

}  // namespace slshadow::capture
