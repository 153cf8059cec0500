#include "capture/grbl_protocol.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>

namespace slshadow::capture::grbl {
namespace {

// A whole-string integer, or nullopt.
std::optional<int> ToInt(const std::string& s) {
  if (s.empty() || s.size() > 6) return std::nullopt;
  for (char c : s) {
    if (c < '0' || c > '9') return std::nullopt;
  }
  return std::atoi(s.c_str());
}

std::optional<double> ToDouble(const std::string& s) {
  if (s.empty()) return std::nullopt;
  char* end = nullptr;
  errno = 0;
  const double v = std::strtod(s.c_str(), &end);
  if (errno != 0 || end != s.c_str() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

std::vector<std::string> Split(const std::string& s, char sep) {
  std::vector<std::string> parts;
  size_t begin = 0;
  for (;;) {
    const size_t end = s.find(sep, begin);
    parts.push_back(s.substr(begin, end == std::string::npos ? std::string::npos : end - begin));
    if (end == std::string::npos) return parts;
    begin = end + 1;
  }
}

std::optional<std::vector<double>> Numbers(const std::string& s) {
  std::vector<double> values;
  for (const std::string& part : Split(s, ',')) {
    const auto v = ToDouble(part);
    if (!v) return std::nullopt;
    values.push_back(*v);
  }
  return values;
}

bool StartsWith(const std::string& s, const std::string& prefix) {
  return s.compare(0, prefix.size(), prefix) == 0;
}

}  // namespace

Line ClassifyLine(const std::string& line) {
  Line out;
  out.text = line;
  if (line == "ok") {
    out.kind = LineKind::kOk;
  } else if (StartsWith(line, "error:") && ToInt(line.substr(6))) {
    out.kind = LineKind::kError;
    out.code = *ToInt(line.substr(6));
  } else if (StartsWith(line, "ALARM:") && ToInt(line.substr(6))) {
    out.kind = LineKind::kAlarm;
    out.code = *ToInt(line.substr(6));
  } else if (line.size() >= 2 && line.front() == '<' && line.back() == '>') {
    out.kind = LineKind::kStatus;
  } else if (!WelcomeVersion(line).empty()) {
    out.kind = LineKind::kWelcome;
  } else if (line.size() > 1 && line[0] == '$' && line.find('=') != std::string::npos &&
             ToInt(line.substr(1, line.find('=') - 1))) {
    out.kind = LineKind::kSetting;
    out.code = *ToInt(line.substr(1, line.find('=') - 1));
    out.text = line.substr(line.find('=') + 1);
  } else if (!line.empty() && (line[0] == '[' || line[0] == '>')) {
    out.kind = LineKind::kMessage;
  }
  return out;
}

std::optional<StatusReport> ParseStatusReport(const std::string& line) {
  if (line.size() < 3 || line.front() != '<' || line.back() != '>') return std::nullopt;
  const std::vector<std::string> fields = Split(line.substr(1, line.size() - 2), '|');
  StatusReport report;
  const std::vector<std::string> state = Split(fields[0], ':');
  if (state.size() > 2 || state[0].empty()) return std::nullopt;
  report.state = state[0];
  if (state.size() == 2) {
    const auto sub = ToInt(state[1]);
    if (!sub) return std::nullopt;
    report.substate = *sub;
  }
  for (size_t i = 1; i < fields.size(); ++i) {
    const size_t colon = fields[i].find(':');
    if (colon == std::string::npos) continue;  // a field without values (none documented)
    const std::string key = fields[i].substr(0, colon);
    const std::string value = fields[i].substr(colon + 1);
    if (key == "MPos" || key == "WPos") {
      const auto v = Numbers(value);
      if (!v) return std::nullopt;
      (key == "MPos" ? report.machine_position : report.work_position) = *v;
    } else if (key == "FS" || key == "F") {
      const auto v = Numbers(value);
      if (!v || v->empty()) return std::nullopt;
      report.feed = (*v)[0];
    }
    // Bf, Ln, WCO, Ov, Pn, A: not needed by a turntable.
  }
  return report;
}

std::string WelcomeVersion(const std::string& line) {
  // "Grbl 1.1h ['$' for help]"
  if (!StartsWith(line, "Grbl ")) return "";
  const size_t end = line.find(' ', 5);
  const std::string version =
      line.substr(5, end == std::string::npos ? std::string::npos : end - 5);
  if (version.empty() || version[0] < '0' || version[0] > '9') return "";
  return version;
}

std::string ErrorMeaning(int code) {
  switch (code) {
    case 1:
      return "expected command letter: a G-code word has no letter";
    case 2:
      return "bad number format: a G-code word value is missing or not a number";
    case 3:
      return "invalid statement: the '$' system command is not recognised or supported";
    case 4:
      return "negative value received for an expected positive value";
    case 5:
      return "homing cycle failure: homing is not enabled in the settings ($22)";
    case 6:
      return "minimum step pulse time must be greater than 3 usec";
    case 7:
      return "EEPROM read failed: affected settings restored to their defaults";
    case 8:
      return "'$' command cannot be used unless the controller is idle";
    case 9:
      return "G-code commands are locked out during alarm or jog state";
    case 10:
      return "soft limits cannot be enabled without homing also enabled";
    case 11:
      return "line overflow: maximum characters per line exceeded, line not executed";
    case 12:
      return "a '$' setting value makes the step rate exceed the maximum supported";
    case 13:
      return "safety door detected as opened and door state initiated";
    case 14:
      return "build info or startup line exceeds the EEPROM line length limit";
    case 15:
      return "jog target exceeds machine travel: jog command ignored";
    case 16:
      return "jog command has no '=' or contains prohibited G-code";
    case 17:
      return "laser mode requires PWM output";
    case 20:
      return "unsupported or invalid G-code command found in block";
    case 21:
      return "more than one G-code command from the same modal group found in block";
    case 22:
      return "feed rate has not yet been set or is undefined";
    case 23:
      return "G-code command in block requires an integer value";
    case 24:
      return "more than one G-code command that requires axis words found in block";
    case 25:
      return "repeated G-code word found in block";
    case 26:
      return "no axis words found in block for a G-code command or modal state that needs them";
    case 27:
      return "line number value is invalid";
    case 28:
      return "G-code command is missing a required value word";
    case 29:
      return "G59.x work coordinate systems are not supported";
    case 30:
      return "G53 only allowed with G0 and G1 motion modes";
    case 31:
      return "axis words found in block when no command or modal state uses them";
    case 32:
      return "G2 and G3 arcs require at least one in-plane axis word";
    case 33:
      return "motion command target is invalid";
    case 34:
      return "arc radius value is invalid";
    case 35:
      return "G2 and G3 arcs require at least one in-plane offset word";
    case 36:
      return "unused value words found in block";
    case 37:
      return "G43.1 dynamic tool length offset is not assigned to the configured tool length axis";
    case 38:
      return "tool number greater than the maximum supported value";
    default:
      return "undocumented error code " + std::to_string(code);
  }
}

std::string AlarmMeaning(int code) {
  switch (code) {
    case 1:
      return "hard limit triggered: machine position is likely lost, re-homing is recommended";
    case 2:
      return "soft limit: the motion target exceeds machine travel (position retained)";
    case 3:
      return "reset while in motion: machine position is likely lost, re-homing is recommended";
    case 4:
      return "probe fail: the probe is not in the expected initial state";
    case 5:
      return "probe fail: the probe did not contact the workpiece within the programmed travel";
    case 6:
      return "homing fail: the active homing cycle was reset";
    case 7:
      return "homing fail: the safety door was opened during the homing cycle";
    case 8:
      return "homing fail: pull-off travel failed to clear the limit switch";
    case 9:
      return "homing fail: could not find the limit switch within the search distance";
    default:
      return "undocumented alarm code " + std::to_string(code);
  }
}

int AxisIndex(char letter) {
  static const std::string kAxes = "XYZABC";
  const size_t i = kAxes.find(letter);
  return i == std::string::npos ? -1 : static_cast<int>(i);
}

}  // namespace slshadow::capture::grbl
