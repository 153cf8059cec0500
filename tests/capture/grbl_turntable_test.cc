// The GRBL turntable against an emulated GRBL 1.1 controller on a pseudo-terminal (the backend's
// real termios path): open, homing, moves, read-back and busy state; every fault (error:N, an
// alarm mid-move, a move that never arrives, a lost reply, a lost status report, the port
// vanishing, no welcome) ends in one message naming the device and the request. The protocol
// parsing (capture/grbl_protocol.h) is tested on the documented line formats.
#include "capture/grbl_turntable.h"

#include <algorithm>
#include <functional>
#include <optional>
#include <thread>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "capture/grbl_protocol.h"
#include "tests/capture/grbl_emulator.h"
#include "tests/testing/error_of.h"

namespace slshadow::capture {
namespace {

using testing::GrblEmulator;
using ::testing::HasSubstr;
using ::testing::StartsWith;

constexpr auto kLong = std::chrono::seconds(20);  // bounds waits for what a test proves

TurntableConfig ConfigFor(const GrblEmulator& emulator) {
  TurntableConfig c;
  c.backend = "grbl";
  c.port = emulator.port();
  c.where = "rig.yaml: turntable";
  c.poll_interval_ms = 5;
  c.reply_timeout_ms = 10000;
  c.startup_timeout_ms = 10000;
  c.move_timeout_ms = 20000;
  return c;
}

std::string Device(const GrblEmulator& emulator, const std::string& axis = "X") {
  return "rig.yaml: turntable: grbl on " + emulator.port() + " (axis " + axis + ")";
}

// The TurntableError `f` throws (fails the test when it throws none).
TurntableError ErrorOf(const std::function<void()>& f) {
  return slshadow::testing::ExceptionOf<TurntableError>(
      f, TurntableError(TurntableFault::kRefused, ""));
}

int Count(const std::vector<std::string>& lines, const std::string& line) {
  return static_cast<int>(std::count(lines.begin(), lines.end(), line));
}

TEST(GrblProtocol, ClassifiesTheDocumentedLines) {
  EXPECT_EQ(grbl::ClassifyLine("ok").kind, grbl::LineKind::kOk);
  const grbl::Line error = grbl::ClassifyLine("error:22");
  EXPECT_EQ(error.kind, grbl::LineKind::kError);
  EXPECT_EQ(error.code, 22);
  const grbl::Line alarm = grbl::ClassifyLine("ALARM:9");
  EXPECT_EQ(alarm.kind, grbl::LineKind::kAlarm);
  EXPECT_EQ(alarm.code, 9);
  EXPECT_EQ(grbl::ClassifyLine("<Idle|MPos:0.000,0.000,0.000|FS:0,0>").kind,
            grbl::LineKind::kStatus);
  EXPECT_EQ(grbl::ClassifyLine("Grbl 1.1h ['$' for help]").kind, grbl::LineKind::kWelcome);
  const grbl::Line setting = grbl::ClassifyLine("$13=0");
  EXPECT_EQ(setting.kind, grbl::LineKind::kSetting);
  EXPECT_EQ(setting.code, 13);
  EXPECT_EQ(setting.text, "0");
  EXPECT_EQ(grbl::ClassifyLine("[MSG:'$H'|'$X' to unlock]").kind, grbl::LineKind::kMessage);
  EXPECT_EQ(grbl::ClassifyLine("error:").kind, grbl::LineKind::kOther);
  EXPECT_EQ(grbl::ClassifyLine("okay").kind, grbl::LineKind::kOther);
  EXPECT_EQ(grbl::WelcomeVersion("Grbl 1.1h ['$' for help]"), "1.1h");
  EXPECT_EQ(grbl::WelcomeVersion("Grbl 0.9j ['$' for help]"), "0.9j");
  EXPECT_EQ(grbl::WelcomeVersion("Grblx"), "");
}

TEST(GrblProtocol, ParsesStatusReports) {
  const auto idle = grbl::ParseStatusReport("<Idle|MPos:1.000,-2.500,3.250|FS:0,0|WCO:0,0,0>");
  ASSERT_TRUE(idle);
  EXPECT_EQ(idle->state, "Idle");
  EXPECT_EQ(idle->substate, -1);
  EXPECT_EQ(idle->machine_position, (std::vector<double>{1.0, -2.5, 3.25}));
  EXPECT_EQ(idle->feed, 0.0);
  const auto hold = grbl::ParseStatusReport("<Hold:1|MPos:0.000,0.000,0.000,90.000|Bf:15,128>");
  ASSERT_TRUE(hold);
  EXPECT_EQ(hold->state, "Hold");
  EXPECT_EQ(hold->substate, 1);
  EXPECT_EQ(hold->machine_position.size(), 4u);
  const auto run = grbl::ParseStatusReport("<Run|WPos:5.000,0.000,0.000|F:500>");
  ASSERT_TRUE(run);
  EXPECT_TRUE(run->machine_position.empty());
  EXPECT_EQ(run->work_position[0], 5.0);
  EXPECT_EQ(run->feed, 500.0);
  EXPECT_FALSE(grbl::ParseStatusReport("<Idle|MPos:1.0,x,3>"));
  EXPECT_FALSE(grbl::ParseStatusReport("<Idle:x|MPos:1,2,3>"));
  EXPECT_FALSE(grbl::ParseStatusReport("Idle|MPos:1,2,3"));
}

TEST(GrblProtocol, NamesErrorAndAlarmCodes) {
  EXPECT_EQ(grbl::ErrorMeaning(9), "G-code commands are locked out during alarm or jog state");
  EXPECT_EQ(grbl::ErrorMeaning(22), "feed rate has not yet been set or is undefined");
  EXPECT_EQ(grbl::ErrorMeaning(99), "undocumented error code 99");
  EXPECT_THAT(grbl::AlarmMeaning(1), StartsWith("hard limit triggered"));
  EXPECT_THAT(grbl::AlarmMeaning(9), HasSubstr("could not find the limit switch"));
  EXPECT_EQ(grbl::AlarmMeaning(42), "undocumented alarm code 42");
  EXPECT_EQ(grbl::AxisIndex('X'), 0);
  EXPECT_EQ(grbl::AxisIndex('A'), 3);
  EXPECT_EQ(grbl::AxisIndex('Q'), -1);
}

TEST(GrblTurntable, OpensWithASoftResetAndSetsMillimetresAndAbsoluteMoves) {
  GrblEmulator emulator;
  GrblTurntable table(ConfigFor(emulator));
  EXPECT_EQ(emulator.soft_resets(), 1);
  EXPECT_EQ(table.FirmwareVersion(), "1.1h");
  EXPECT_EQ(emulator.Lines(), (std::vector<std::string>{"$$", "G21 G90"}));
  EXPECT_GE(emulator.status_queries(), 1);
  const TurntableStatus status = table.Status();
  EXPECT_EQ(status.state, TurntableState::kIdle);
  EXPECT_EQ(status.position_deg, 0.0);
  EXPECT_EQ(status.detail, "Idle");
  EXPECT_EQ(table.Describe(), Device(emulator));
}

TEST(GrblTurntable, HomesThenMovesToSeveralAnglesAndReadsThemBack) {
  GrblEmulator::Options options;
  options.homing_enabled = true;  // the controller starts in alarm: homing required
  options.home_position = -1.0;   // minus the pull-off, as GRBL sets it
  GrblEmulator emulator(options);
  TurntableConfig config = ConfigFor(emulator);
  config.homing = true;
  config.degrees_per_unit = 2.0;  // one firmware unit is two table degrees
  auto table = OpenTurntable(config);
  EXPECT_EQ(table->State(), TurntableState::kAlarm);  // left for Home() to clear
  table->Home();
  EXPECT_EQ(Count(emulator.Lines(), "$H"), 1);
  EXPECT_EQ(table->State(), TurntableState::kIdle);
  EXPECT_EQ(table->PositionDeg(), -2.0);
  for (const double angle : {0.0, 30.0, 90.0, 359.5, 720.0, 45.25}) {
    table->MoveTo(angle);
    EXPECT_NEAR(table->PositionDeg(), angle, config.tolerance_deg) << angle;
    EXPECT_NEAR(emulator.MachinePosition(0), angle / 2, 1e-9) << angle;
    EXPECT_EQ(table->State(), TurntableState::kIdle);
  }
  const auto lines = emulator.Lines();
  EXPECT_EQ(Count(lines, "G90 G53 G0 X15.0000"), 1);
  EXPECT_EQ(Count(lines, "G90 G53 G0 X179.7500"), 1);
  EXPECT_EQ(Count(lines, "G90 G53 G0 X22.6250"), 1);
}

TEST(GrblTurntable, FeedRateMovesAreG1InFirmwareUnitsPerMinute) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.degrees_per_unit = 2.0;
  config.feed_deg_per_min = 36000;
  auto table = OpenTurntable(config);
  table->MoveTo(90);
  EXPECT_EQ(Count(emulator.Lines(), "G90 G53 G1 X45.0000 F18000.000"), 1);
  EXPECT_NEAR(table->PositionDeg(), 90.0, config.tolerance_deg);
}

TEST(GrblTurntable, AnglesAreMachinePositionsWhateverTheWorkOffset) {
  GrblEmulator::Options options;
  options.work_offset = {10.0, 0.0, 0.0};  // a G54 offset another program left
  GrblEmulator emulator(options);
  auto table = OpenTurntable(ConfigFor(emulator));
  table->MoveTo(30);
  EXPECT_NEAR(emulator.MachinePosition(0), 30.0, 1e-9);
  EXPECT_NEAR(table->PositionDeg(), 30.0, 1e-9);
}

TEST(GrblTurntable, DrivesTheConfiguredAxisOfAFourAxisController) {
  GrblEmulator::Options options;
  options.axes = 4;
  GrblEmulator emulator(options);
  TurntableConfig config = ConfigFor(emulator);
  config.axis = "A";
  auto table = OpenTurntable(config);
  table->MoveTo(45);
  EXPECT_NEAR(emulator.MachinePosition(3), 45.0, 1e-9);
  EXPECT_EQ(emulator.MachinePosition(0), 0.0);
  EXPECT_EQ(table->Describe(), Device(emulator, "A"));
}

TEST(GrblTurntable, ReportsBusyWhileMoving) {
  GrblEmulator emulator;
  auto table = OpenTurntable(ConfigFor(emulator));
  emulator.FreezeMotion(true);  // the move stays under way until released
  std::thread mover([&] { table->MoveTo(90); });
  ASSERT_TRUE(emulator.WaitForLine("G90 G53 G0 X90", kLong));
  const TurntableStatus moving = table->Status();  // answered between the mover's polls
  EXPECT_EQ(moving.state, TurntableState::kMoving);
  EXPECT_TRUE(Busy(moving.state));
  EXPECT_EQ(moving.detail, "Run");
  EXPECT_EQ(moving.position_deg, 0.0);
  emulator.FreezeMotion(false);
  mover.join();
  EXPECT_EQ(table->State(), TurntableState::kIdle);
  EXPECT_NEAR(table->PositionDeg(), 90.0, 0.01);
}

TEST(GrblTurntable, AnErrorOnTheMoveNamesTheCodeItsMeaningAndTheAngle) {
  GrblEmulator emulator;
  auto table = OpenTurntable(ConfigFor(emulator));
  emulator.ErrorOn("G90 G53", 20);
  const TurntableError e = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(e.fault(), TurntableFault::kDeviceError);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": move to 90.000 deg: \"G90 G53 G0 X90.0000\" answered error:20 "
                          "(unsupported or invalid G-code command found in block)")
                             .c_str());
  EXPECT_EQ(table->State(), TurntableState::kIdle);  // still usable
}

TEST(GrblTurntable, AnAlarmMidMoveStopsTheMoveAndLocksTheTable) {
  GrblEmulator emulator;
  auto table = OpenTurntable(ConfigFor(emulator));
  emulator.AlarmDuringNextMove(1, 0.5);
  const TurntableError e = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(e.fault(), TurntableFault::kAlarm);
  EXPECT_THAT(e.what(), StartsWith(Device(emulator) + ": move to 90.000 deg: ALARM:1, hard limit "
                                                      "triggered: machine position is likely "
                                                      "lost, re-homing is recommended (the table "
                                                      "stopped at "));
  const double stopped = emulator.MachinePosition(0);
  EXPECT_GE(stopped, 45.0);
  EXPECT_LT(stopped, 90.0);
  const TurntableStatus status = table->Status();
  EXPECT_EQ(status.state, TurntableState::kAlarm);
  EXPECT_THAT(status.detail, HasSubstr("ALARM:1"));
  const TurntableError again = ErrorOf([&] { table->MoveTo(180); });
  EXPECT_EQ(again.fault(), TurntableFault::kAlarm);
  EXPECT_THAT(again.what(), HasSubstr("move to 180.000 deg: the controller is in alarm (ALARM:1"));
  EXPECT_THAT(again.what(), HasSubstr("home it first"));
}

TEST(GrblTurntable, AMoveThatStopsShortTimesOutAndHoldsTheTable) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.move_timeout_ms = 500;  // the stall is permanent: any timeout ends the same way
  auto table = OpenTurntable(config);
  emulator.StopMovesShort(0.5);
  const TurntableError e = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(e.fault(), TurntableFault::kTimeout);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": move to 90.000 deg: not reached within 500 ms: the controller "
                          "reports Idle at 45.000 deg (a feed hold was sent)")
                             .c_str());
  EXPECT_EQ(emulator.feed_holds(), 1);
  EXPECT_EQ(table->State(), TurntableState::kIdle);  // still in sync: usable
}

TEST(GrblTurntable, AMoveThatNeverEndsTimesOutAndIsHeld) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.move_timeout_ms = 500;
  auto table = OpenTurntable(config);
  emulator.FreezeMotion(true);
  const TurntableError e = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(e.fault(), TurntableFault::kTimeout);
  EXPECT_THAT(e.what(), HasSubstr("move to 90.000 deg: not reached within 500 ms: the controller "
                                  "reports Run at 0.000 deg (a feed hold was sent)"));
  EXPECT_EQ(emulator.State(), "Hold:0");
  EXPECT_EQ(table->State(), TurntableState::kHold);
  const TurntableError held = ErrorOf([&] { table->MoveTo(10); });
  EXPECT_EQ(held.fault(), TurntableFault::kRefused);
  EXPECT_THAT(held.what(), HasSubstr("the controller is not idle (Hold:0)"));
}

TEST(GrblTurntable, ALostReplyTimesOutAndTheTableRefusesFurtherCommands) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.reply_timeout_ms = 1000;
  auto table = OpenTurntable(config);
  emulator.DropReplyTo("G90 G53");
  const TurntableError e = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(e.fault(), TurntableFault::kTimeout);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": move to 90.000 deg: no reply to \"G90 G53 G0 X90.0000\" within "
                          "1000 ms")
                             .c_str());
  const TurntableStatus status = table->Status();
  EXPECT_EQ(status.state, TurntableState::kFault);
  EXPECT_THAT(status.detail, HasSubstr("no reply to"));
  const TurntableError again = ErrorOf([&] { table->MoveTo(90); });
  EXPECT_EQ(again.fault(), TurntableFault::kTimeout);
  EXPECT_THAT(again.what(), HasSubstr("unusable after an earlier failure"));
  EXPECT_THAT(again.what(), HasSubstr("reopen the turntable"));
}

TEST(GrblTurntable, ALostStatusReportTimesOut) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.reply_timeout_ms = 1000;
  auto table = OpenTurntable(config);
  emulator.DropStatusReports(true);
  const TurntableError e = ErrorOf([&] { table->MoveTo(30); });
  EXPECT_EQ(e.fault(), TurntableFault::kTimeout);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": move to 30.000 deg: no status report within 1000 ms of a status "
                          "query (?)")
                             .c_str());
}

TEST(GrblTurntable, ThePortVanishingMidMoveIsOneClearError) {
  GrblEmulator emulator;
  auto table = OpenTurntable(ConfigFor(emulator));
  emulator.FreezeMotion(true);
  std::optional<TurntableError> error;
  std::thread mover([&] { error = ErrorOf([&] { table->MoveTo(90); }); });
  ASSERT_TRUE(emulator.WaitForLine("G90 G53 G0 X90", kLong));
  emulator.Vanish();  // the USB serial adapter unplugged
  mover.join();
  ASSERT_TRUE(error);
  EXPECT_EQ(error->fault(), TurntableFault::kDisconnected);
  EXPECT_THAT(error->what(), StartsWith(Device(emulator) + ": move to 90.000 deg: the port " +
                                        emulator.port() + " vanished ("));
  EXPECT_EQ(table->State(), TurntableState::kFault);
}

TEST(GrblTurntable, ANewTableOnTheSamePortAfterAFaultResumes) {
  GrblEmulator emulator;
  TurntableConfig config = ConfigFor(emulator);
  config.reply_timeout_ms = 1000;
  {
    auto table = OpenTurntable(config);
    table->MoveTo(30);
    emulator.DropStatusReports(true);
    EXPECT_EQ(ErrorOf([&] { table->MoveTo(60); }).fault(), TurntableFault::kTimeout);
  }
  emulator.DropStatusReports(false);
  auto table = OpenTurntable(config);  // reopened: reset, welcome, position kept
  EXPECT_EQ(emulator.soft_resets(), 2);
  table->MoveTo(60);
  EXPECT_NEAR(table->PositionDeg(), 60.0, 0.01);
}

TEST(GrblTurntable, HomingFailureIsAnAlarmNamingTheCause) {
  GrblEmulator::Options options;
  options.homing_enabled = true;
  GrblEmulator emulator(options);
  TurntableConfig config = ConfigFor(emulator);
  config.homing = true;
  auto table = OpenTurntable(config);
  emulator.AlarmDuringNextMove(9, 0.5);
  const TurntableError e = ErrorOf([&] { table->Home(); });
  EXPECT_EQ(e.fault(), TurntableFault::kAlarm);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": home: homing raised ALARM:9, homing fail: could not find the limit "
                          "switch within the search distance")
                             .c_str());
}

TEST(GrblTurntable, AnAlarmAfterTheResetIsUnlockedOnlyWhenAllowed) {
  GrblEmulator::Options options;
  options.homing_enabled = true;
  GrblEmulator emulator(options);
  TurntableConfig config = ConfigFor(emulator);
  const TurntableError e = ErrorOf([&] { OpenTurntable(config); });
  EXPECT_EQ(e.fault(), TurntableFault::kAlarm);
  EXPECT_STREQ(e.what(),
               (Device(emulator) +
                ": open: the controller is in alarm after its reset (homing is enabled in the "
                "firmware, $22=1): set rig.yaml: turntable.homing: true to home it, or unlock: "
                "true to unlock it ($X) without homing")
                   .c_str());
  EXPECT_EQ(Count(emulator.Lines(), "$X"), 0);
  config.unlock = true;
  auto table = OpenTurntable(config);
  EXPECT_EQ(Count(emulator.Lines(), "$X"), 1);
  EXPECT_EQ(table->State(), TurntableState::kIdle);
  table->Home();  // homing: false: nothing to do
  EXPECT_EQ(Count(emulator.Lines(), "$H"), 0);
  table->MoveTo(10);
  EXPECT_NEAR(emulator.MachinePosition(0), 10.0, 1e-9);
}

TEST(GrblTurntable, RefusesControllersItCannotUse) {
  {
    GrblEmulator::Options options;
    options.report_inches = true;
    GrblEmulator emulator(options);
    const TurntableError e = ErrorOf([&] { OpenTurntable(ConfigFor(emulator)); });
    EXPECT_EQ(e.fault(), TurntableFault::kRefused);
    EXPECT_THAT(e.what(), HasSubstr(": open: the controller reports positions in inches ($13=1)"));
  }
  {
    GrblEmulator emulator;  // $22=0
    TurntableConfig config = ConfigFor(emulator);
    config.homing = true;
    const TurntableError e = ErrorOf([&] { OpenTurntable(config); });
    EXPECT_EQ(e.fault(), TurntableFault::kRefused);
    EXPECT_THAT(e.what(), HasSubstr("homing is disabled in the firmware ($22=0)"));
  }
  {
    GrblEmulator emulator;  // X Y Z only
    TurntableConfig config = ConfigFor(emulator);
    config.axis = "A";
    const TurntableError e = ErrorOf([&] { OpenTurntable(config); });
    EXPECT_EQ(e.fault(), TurntableFault::kRefused);
    EXPECT_THAT(e.what(), HasSubstr("the controller reports 3 axes, none is A (stock GRBL 1.1 has "
                                    "X, Y, Z): set rig.yaml: turntable.axis"));
  }
  {
    GrblEmulator::Options options;
    options.version = "0.9j";
    GrblEmulator emulator(options);
    const TurntableError e = ErrorOf([&] { OpenTurntable(ConfigFor(emulator)); });
    EXPECT_EQ(e.fault(), TurntableFault::kRefused);
    EXPECT_THAT(e.what(), HasSubstr("runs Grbl 0.9j; slshadow speaks the interface of GRBL 1.1"));
  }
}

TEST(GrblTurntable, NoWelcomeAfterTheResetTimesOut) {
  GrblEmulator emulator;
  emulator.Silence(true);
  TurntableConfig config = ConfigFor(emulator);
  config.startup_timeout_ms = 500;  // nothing will ever answer
  const TurntableError e = ErrorOf([&] { OpenTurntable(config); });
  EXPECT_EQ(e.fault(), TurntableFault::kTimeout);
  EXPECT_STREQ(e.what(), (Device(emulator) +
                          ": open: no welcome (\"Grbl 1.1...\") within 500 ms of a soft reset "
                          "(ctrl-x): is a GRBL 1.1 controller on " +
                          emulator.port() + " at 115200 baud?")
                             .c_str());
}

TEST(GrblTurntable, APortThatCannotBeOpenedNamesThePort) {
  TurntableConfig config;
  config.backend = "grbl";
  config.port = "/nonexistent/ttyUSB9";
  const TurntableError missing = ErrorOf([&] { OpenTurntable(config); });
  EXPECT_EQ(missing.fault(), TurntableFault::kDisconnected);
  EXPECT_STREQ(missing.what(),
               "turntable: grbl on /nonexistent/ttyUSB9 (axis X): open: cannot open "
               "/nonexistent/ttyUSB9: No such file or directory");
  config.port = "/dev/null";
  const TurntableError not_tty = ErrorOf([&] { OpenTurntable(config); });
  EXPECT_EQ(not_tty.fault(), TurntableFault::kRefused);
  EXPECT_THAT(not_tty.what(), HasSubstr("/dev/null is not a serial port"));
}

}  // namespace
}  // namespace slshadow::capture
