// The parts of GRBL 1.1's serial interface a turntable needs, as grbl/grbl documents them
// (doc/markdown/interface.md, commands.md, settings.md): the lines the controller sends and the
// meaning of its error and alarm codes. No I/O here (capture/grbl_turntable.h talks to the port).
//
// Every line the host sends is answered by exactly one `ok` or `error:N`; besides these the
// controller pushes `ALARM:N`, `[MSG:...]` and other bracketed feedback, its welcome
// `Grbl 1.1h ['$' for help]` after a reset, and a status report `<State|MPos:x,y,z|...>` for each
// real-time `?` byte (sent without a newline).
#pragma once

#include <optional>
#include <string>
#include <vector>

namespace slshadow::capture::grbl {

// Real-time command bytes: acted on at once, never answered by ok.
inline constexpr char kStatusQuery = '?';
inline constexpr char kFeedHold = '!';
inline constexpr char kCycleStart = '~';
inline constexpr char kSoftReset = 0x18;  // ctrl-x

enum class LineKind {
  kOk,       // "ok"
  kError,    // "error:N"
  kAlarm,    // "ALARM:N"
  kStatus,   // "<...>"
  kWelcome,  // "Grbl 1.1h ['$' for help]" (the controller has just reset)
  kSetting,  // "$N=value" (an answer to $$)
  kMessage,  // "[...]" feedback (MSG, GC, HLP, echo, ...) and "ALARM" / startup lines we skip
  kOther
};

struct Line {
  LineKind kind = LineKind::kOther;
  int code = 0;      // kError / kAlarm: N; kSetting: the setting number
  std::string text;  // the whole line (no CR / LF); kSetting: the value
};
// Classifies one line received from the controller (CR / LF already stripped).
Line ClassifyLine(const std::string& line);

// A real-time status report: "<Idle|MPos:0.000,0.000,0.000|FS:0,0>".
struct StatusReport {
  std::string state;                     // Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep
  int substate = -1;                     // "Hold:0" -> 0, "Door:2" -> 2; -1 when none
  std::vector<double> machine_position;  // MPos, one value per axis (empty when not reported)
  std::vector<double> work_position;     // WPos, when the report mask ($10) asks for it instead
  std::optional<double> feed;            // FS or F field: current feed rate
};
// nullopt when `line` is not a well-formed status report.
std::optional<StatusReport> ParseStatusReport(const std::string& line);

// The firmware version in a welcome line ("1.1h"), or "" when `line` is not a welcome.
std::string WelcomeVersion(const std::string& line);

// The documented meaning of error:N and ALARM:N (grbl doc/csv/error_codes_en_US.csv,
// alarm_codes_en_US.csv), e.g. ErrorMeaning(22) = "feed rate has not yet been set or is
// undefined"; an unknown code gives "undocumented error code N" / "undocumented alarm code N".
std::string ErrorMeaning(int code);
std::string AlarmMeaning(int code);

// The index of an axis letter in MPos (X 0, Y 1, Z 2, A 3, B 4, C 5), or -1.
int AxisIndex(char letter);

}  // namespace slshadow::capture::grbl
