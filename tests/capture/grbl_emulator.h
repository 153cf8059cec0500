// An emulated GRBL 1.1 controller on a pseudo-terminal, for tests of the GRBL turntable through the
// real termios path: the backend opens port() (the pty's slave) exactly as it opens /dev/ttyUSB0;
// a thread answers on the master as grbl/grbl's doc/markdown/interface.md and commands.md state.
//
// Emulated: the power-up state (Alarm when homing is enabled, $22=1: HOMING_INIT_LOCK); the
// welcome "Grbl 1.1h ['$' for help]" on a soft reset (ctrl-x), after ALARM:3 when the reset stopped
// a move; an alarm survives the reset, with "[MSG:'$H'|'$X' to unlock]"; one `ok` or `error:N` per
// line (empty lines too); status reports
// "<State|MPos:...|FS:...>" for each real-time `?`, with WCO every tenth; feed hold `!` and
// resume `~`; $$ (settings $10, $13, $22, $27, $100..), $X (unlock), $H (homing cycle: ok when it
// ends), G0 / G1 with F, G20 / G21, G90 / G91, G53, G54 moves of X Y Z (A B C with more axes) at a
// constant speed in real time; error:9 for G-code in alarm, error:20 for unsupported words,
// error:22 for G1 without a feed rate, error:3 for unknown $ commands, error:5 for $H with homing
// disabled.
#pragma once

#include <chrono>
#include <condition_variable>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace slshadow::capture::testing {

class GrblEmulator {
 public:
  struct Options {
    int axes = 3;                     // X Y Z; 4..6 adds A B C
    double rapid_units_per_s = 4000;  // G0 speed (units per second)
    bool homing_enabled = false;      // $22
    bool report_inches = false;       // $13
    double home_position = -1.0;      // MPos of every axis after homing (GRBL: minus the pull-off)
    double homing_units_per_s = 2000;
    std::string version = "1.1h";
    std::vector<double> work_offset;  // G54 offset per axis (default zeros)
  };
  GrblEmulator();
  explicit GrblEmulator(Options options);
  ~GrblEmulator();
  GrblEmulator(const GrblEmulator&) = delete;
  GrblEmulator& operator=(const GrblEmulator&) = delete;

  // The slave end's path (/dev/pts/N) for the backend to open.
  const std::string& port() const { return port_; }

  // Faults; each takes effect from the next matching event on.
  void ErrorOn(const std::string& line_prefix, int code);  // such lines get error:N, not executed
  void DropReplyTo(const std::string& line_prefix);  // such lines are executed, never answered
  void DropStatusReports(bool drop);                 // `?` goes unanswered
  void Silence(bool silent);                         // nothing at all is answered
  // The next move (or homing cycle) pushes ALARM:code once it is `fraction` of the way, stops and
  // stays in Alarm.
  void AlarmDuringNextMove(int code, double fraction);
  // Every move ends Idle at `fraction` of its way (a stalled motor, lost steps).
  void StopMovesShort(double fraction);
  // Motion halts (the state stays Run / Home) while frozen.
  void FreezeMotion(bool frozen);
  // Closes the master: the slave sees a hang-up, as when a USB serial adapter is unplugged.
  void Vanish();

  // Observations.
  std::vector<std::string> Lines() const;  // the lines received, in order
  // Waits until a received line starts with `prefix` (counting lines already received); false
  // after `timeout`.
  bool WaitForLine(const std::string& prefix, std::chrono::milliseconds timeout) const;
  double MachinePosition(int axis) const;
  void SetMachinePosition(int axis, double units);
  std::string State() const;  // "Idle", "Run", "Hold:0", "Home", "Alarm"
  int soft_resets() const;
  int status_queries() const;
  int feed_holds() const;

 private:
  void Run();
  void OnByte(char c);
  void Execute(const std::string& line);
  void ExecuteGcode(const std::string& line, bool answer);
  void StartMotion(const std::vector<double>& target, double units_per_s, bool homing);
  void Advance(double dt_s);
  void SoftReset();
  void Send(const std::string& text);
  void SendStatus();

  Options options_;
  std::string port_;
  int master_ = -1, slave_ = -1;
  std::thread thread_;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  bool stop_ = false, vanish_ = false;
  // Controller state.
  std::string state_ = "Idle";
  std::vector<double> position_, start_, target_;
  double speed_units_per_s_ = 0;
  bool homing_ = false;
  bool absolute_ = true, inches_ = false;
  double feed_ = 0;  // units per minute; 0: not set
  int motion_mode_ = 0;
  int reports_ = 0;
  std::string partial_;
  // Faults.
  std::map<std::string, int> error_on_;
  std::vector<std::string> drop_reply_;
  bool drop_status_ = false, silent_ = false, frozen_ = false;
  int alarm_code_ = 0;
  double alarm_fraction_ = 0, short_fraction_ = 1;
  // Observations.
  std::vector<std::string> lines_;
  int soft_resets_ = 0, status_queries_ = 0, feed_holds_ = 0;
};

}  // namespace slshadow::capture::testing
