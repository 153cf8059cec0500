#include "capture/turntable.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <functional>

#include "capture/grbl_protocol.h"
#include "capture/grbl_turntable.h"
#include "capture/manual_turntable.h"
#include "core/config.h"
#include "core/string_printf.h"

namespace slshadow::capture {
namespace {

const std::vector<int>& Bauds() {
  static const std::vector<int> bauds = {9600,   19200,  38400,  57600,  115200,
                                         230400, 460800, 500000, 921600, 1000000};
  return bauds;
}

// Every range rule of TurntableConfig, once: `fail(field, problem)` reports the first violation.
void CheckFields(const TurntableConfig& c,
                 const std::function<void(const char*, const std::string&)>& fail) {
  const auto& known = KnownTurntableBackends();
  if (std::find(known.begin(), known.end(), c.backend) == known.end())
    fail("backend", "unknown backend (expected grbl, manual or none)");
  if (c.backend != "grbl") return;
  if (c.port.empty()) fail("port", "must name the serial port, e.g. /dev/ttyUSB0");
  if (std::find(Bauds().begin(), Bauds().end(), c.baud) == Bauds().end())
    fail("baud",
         "must be one of 9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, "
         "921600, 1000000");
  if (c.axis.size() != 1 || grbl::AxisIndex(c.axis[0]) < 0)
    fail("axis", "must be one axis letter: X, Y, Z, A, B or C");
  if (!std::isfinite(c.degrees_per_unit) || c.degrees_per_unit == 0)
    fail("degrees_per_unit", "must be a finite, non-zero number of degrees per firmware unit");
  if (!std::isfinite(c.feed_deg_per_min) || c.feed_deg_per_min < 0)
    fail("feed_deg_per_min", "must be >= 0 degrees per minute (0: rapid moves, G0)");
  if (!std::isfinite(c.tolerance_deg) || c.tolerance_deg <= 0 || c.tolerance_deg > 10)
    fail("tolerance_deg", "must be in (0, 10] degrees");
  const std::pair<const char*, int64_t> timeouts[] = {{"move_timeout_ms", c.move_timeout_ms},
                                                      {"home_timeout_ms", c.home_timeout_ms},
                                                      {"reply_timeout_ms", c.reply_timeout_ms},
                                                      {"startup_timeout_ms", c.startup_timeout_ms}};
  for (const auto& [field, ms] : timeouts) {
    if (ms <= 0 || ms > 3600000) fail(field, "must be in (0, 3600000] milliseconds");
  }
  if (c.poll_interval_ms <= 0 || c.poll_interval_ms > 10000)
    fail("poll_interval_ms", "must be in (0, 10000] milliseconds");
  if (c.settle_ms < 0 || c.settle_ms > 600000)
    fail("settle_ms", "must be in [0, 600000] milliseconds");
}

// backend none: no table, one view at 0 deg.
class NoneTurntable : public Turntable {
 public:
  explicit NoneTurntable(std::string where) : where_(std::move(where)) {}
  void Home() override {}
  void MoveTo(double angle_deg) override {
    if (angle_deg == 0) return;
    throw TurntableError(TurntableFault::kRefused,
                         StringPrintf("%s: move to %.3f deg: there is no turntable (backend none: "
                                      "a single view at 0 deg); add a turntable with backend "
                                      "grbl or manual to the devices file",
                                      Describe().c_str(), angle_deg));
  }
  TurntableStatus Status() override { return {TurntableState::kIdle, 0.0, "no turntable"}; }
  std::string Describe() const override { return where_ + ": none"; }

 private:
  std::string where_;
};

}  // namespace

std::string ToString(TurntableState state) {
  switch (state) {
    case TurntableState::kIdle:
      return "idle";
    case TurntableState::kMoving:
      return "moving";
    case TurntableState::kHoming:
      return "homing";
    case TurntableState::kHold:
      return "hold";
    case TurntableState::kAlarm:
      return "alarm";
    case TurntableState::kFault:
      return "fault";
  }
  return "unknown";
}

std::string ToString(TurntableFault fault) {
  switch (fault) {
    case TurntableFault::kRefused:
      return "refused";
    case TurntableFault::kDeviceError:
      return "device-error";
    case TurntableFault::kAlarm:
      return "alarm";
    case TurntableFault::kTimeout:
      return "timeout";
    case TurntableFault::kDisconnected:
      return "disconnected";
    case TurntableFault::kAborted:
      return "aborted";
  }
  return "unknown";
}

const std::vector<std::string>& KnownTurntableBackends() {
  static const std::vector<std::string> names = {"grbl", "manual", "none"};
  return names;
}

void TurntableConfig::Check() const {
  CheckFields(*this, [&](const char* field, const std::string& problem) {
    SLSHADOW_THROW(where, ".", field, ": ", problem);
  });
}

TurntableConfig TurntableConfigFromConfig(const ConfigNode& node, const std::string& where) {
  static const std::vector<std::string> kGrblKeys = {"port",
                                                     "baud",
                                                     "axis",
                                                     "degrees_per_unit",
                                                     "feed_deg_per_min",
                                                     "tolerance_deg",
                                                     "move_timeout_ms",
                                                     "home_timeout_ms",
                                                     "reply_timeout_ms",
                                                     "startup_timeout_ms",
                                                     "poll_interval_ms",
                                                     "settle_ms",
                                                     "homing",
                                                     "unlock"};
  std::vector<std::string> allowed = {"backend", "auto_confirm"};
  allowed.insert(allowed.end(), kGrblKeys.begin(), kGrblKeys.end());
  node.RejectUnknownKeys(allowed);
  TurntableConfig c;
  c.where = where;
  c.backend = node["backend"].AsString();
  CheckFields(c, [&](const char* field, const std::string& problem) { node[field].Fail(problem); });
  for (const std::string& key : kGrblKeys) {
    if (node.Has(key) && c.backend != "grbl") node[key].Fail("only for backend grbl");
  }
  if (node.Has("auto_confirm") && c.backend != "manual")
    node["auto_confirm"].Fail("only for backend manual");
  c.auto_confirm = node.GetBool("auto_confirm", c.auto_confirm);
  if (c.backend == "grbl") {
    c.port = node.GetString("port", c.port);
    const int64_t baud = node.GetInt("baud", c.baud);
    c.baud = baud > 0 && baud <= 100000000 ? static_cast<int>(baud) : -1;
    if (node.Has("axis")) {
      c.axis = node["axis"].AsString();
      for (char& ch : c.axis) ch = static_cast<char>(std::toupper(static_cast<unsigned char>(ch)));
    }
    c.degrees_per_unit = node.GetDouble("degrees_per_unit", c.degrees_per_unit);
    c.feed_deg_per_min = node.GetDouble("feed_deg_per_min", c.feed_deg_per_min);
    c.tolerance_deg = node.GetDouble("tolerance_deg", c.tolerance_deg);
    c.move_timeout_ms = node.GetInt("move_timeout_ms", c.move_timeout_ms);
    c.home_timeout_ms = node.GetInt("home_timeout_ms", c.home_timeout_ms);
    c.reply_timeout_ms = node.GetInt("reply_timeout_ms", c.reply_timeout_ms);
    c.startup_timeout_ms = node.GetInt("startup_timeout_ms", c.startup_timeout_ms);
    c.poll_interval_ms = node.GetInt("poll_interval_ms", c.poll_interval_ms);
    c.settle_ms = node.GetInt("settle_ms", c.settle_ms);
    c.homing = node.GetBool("homing", c.homing);
    c.unlock = node.GetBool("unlock", c.unlock);
  }
  CheckFields(c, [&](const char* field, const std::string& problem) { node[field].Fail(problem); });
  return c;
}

std::unique_ptr<Turntable> OpenTurntable(const TurntableConfig& config) {
  config.Check();
  // One case per turntable backend.
  if (config.backend == "grbl") return std::make_unique<GrblTurntable>(config);
  if (config.backend == "manual") return std::make_unique<ManualTurntable>(config);
  return std::make_unique<NoneTurntable>(config.where);
}

}  // namespace slshadow::capture
