// The turntable seam: the `turntable:` entry of devices.yaml (every field, the example file, one
// error naming the file, the field and the value for bad input), the none backend (one view) and
// the manual backend talking to an operator through pipes (and through the process's stdin).
#include "capture/turntable.h"

#include <fcntl.h>
#include <unistd.h>

#include <functional>
#include <optional>
#include <thread>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "capture/devices.h"
#include "capture/manual_turntable.h"
#include "core/config.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::capture {
namespace {

using slshadow::testing::ErrorOf;
using ::testing::HasSubstr;
using ::testing::StartsWith;

const std::string kHead =
    "format: slshadow-devices\nversion: 1\ncameras:\n  - {name: left, backend: replay, "
    "imageset: scan}\n";

DevicesConfig Parse(const std::string& yaml) {
  return DevicesFromConfig(ConfigNode::ParseYaml(kHead + yaml, "dev.yaml"));
}

// A pipe whose ends close with the object.
struct Pipe {
  int read_fd = -1, write_fd = -1;
  Pipe() {
    int fds[2];
    EXPECT_EQ(::pipe(fds), 0);
    read_fd = fds[0];
    write_fd = fds[1];
  }
  ~Pipe() {
    CloseRead();
    CloseWrite();
  }
  void CloseRead() {
    if (read_fd >= 0) ::close(read_fd);
    read_fd = -1;
  }
  void CloseWrite() {
    if (write_fd >= 0) ::close(write_fd);
    write_fd = -1;
  }
  void Write(const std::string& text) const {
    EXPECT_EQ(::write(write_fd, text.data(), text.size()), static_cast<ssize_t>(text.size()));
  }
  // Reads until `text` has been received (blocking: the writer is the code under test).
  std::string ReadUntil(const std::string& text) const {
    std::string got;
    char c = 0;
    while (got.find(text) == std::string::npos && ::read(read_fd, &c, 1) == 1) got += c;
    return got;
  }
};

TurntableError TurntableErrorOf(const std::function<void()>& f) {
  return slshadow::testing::ExceptionOf<TurntableError>(
      f, TurntableError(TurntableFault::kRefused, ""));
}

TEST(TurntableConfig, TheExampleLoadsEveryGrblField) {
  const DevicesConfig devices =
      LoadDevices(testing::SourceDir() / "config/devices/stereo_gige_hdmi_grbl_turntable.yaml");
  const TurntableConfig& t = devices.turntable;
  EXPECT_EQ(t.backend, "grbl");
  EXPECT_EQ(t.port, "/dev/ttyUSB0");
  EXPECT_EQ(t.baud, 115200);
  EXPECT_EQ(t.axis, "X");
  EXPECT_EQ(t.degrees_per_unit, 1.0);
  EXPECT_EQ(t.feed_deg_per_min, 3600.0);
  EXPECT_EQ(t.tolerance_deg, 0.01);
  EXPECT_EQ(t.move_timeout_ms, 30000);
  EXPECT_TRUE(t.homing);
  EXPECT_FALSE(t.unlock);
  EXPECT_EQ(t.settle_ms, 500);
  EXPECT_THAT(t.where, HasSubstr("stereo_gige_hdmi_grbl_turntable.yaml: turntable"));
  EXPECT_EQ(devices.cameras.size(), 2u);
}

TEST(TurntableConfig, ReadsAllFields) {
  const TurntableConfig t =
      Parse(
          "turntable:\n  backend: grbl\n  port: /dev/ttyACM1\n  baud: 230400\n  axis: a\n"
          "  degrees_per_unit: -0.5\n  feed_deg_per_min: 720\n  tolerance_deg: 0.05\n"
          "  move_timeout_ms: 9000\n  home_timeout_ms: 8000\n  reply_timeout_ms: 700\n"
          "  startup_timeout_ms: 6000\n  poll_interval_ms: 20\n  settle_ms: 250\n"
          "  homing: true\n  unlock: true\n")
          .turntable;
  EXPECT_EQ(t.port, "/dev/ttyACM1");
  EXPECT_EQ(t.baud, 230400);
  EXPECT_EQ(t.axis, "A");  // letters are upper-cased
  EXPECT_EQ(t.degrees_per_unit, -0.5);
  EXPECT_EQ(t.feed_deg_per_min, 720.0);
  EXPECT_EQ(t.tolerance_deg, 0.05);
  EXPECT_EQ(t.move_timeout_ms, 9000);
  EXPECT_EQ(t.home_timeout_ms, 8000);
  EXPECT_EQ(t.reply_timeout_ms, 700);
  EXPECT_EQ(t.startup_timeout_ms, 6000);
  EXPECT_EQ(t.poll_interval_ms, 20);
  EXPECT_EQ(t.settle_ms, 250);
  EXPECT_TRUE(t.homing);
  EXPECT_TRUE(t.unlock);
  EXPECT_EQ(t.where, "dev.yaml: turntable");

  const TurntableConfig d = Parse("turntable: {backend: grbl}\n").turntable;
  const TurntableConfig defaults;
  EXPECT_EQ(d.port, defaults.port);
  EXPECT_EQ(d.baud, 115200);
  EXPECT_EQ(d.axis, "X");
  EXPECT_EQ(d.move_timeout_ms, defaults.move_timeout_ms);
  EXPECT_FALSE(d.homing);

  const TurntableConfig m = Parse("turntable: {backend: manual, auto_confirm: true}\n").turntable;
  EXPECT_EQ(m.backend, "manual");
  EXPECT_TRUE(m.auto_confirm);

  const DevicesConfig none = Parse("");
  EXPECT_EQ(none.turntable.backend, "none");
  EXPECT_EQ(none.turntable.where, "dev.yaml: turntable");
}

TEST(TurntableConfig, BadInputIsOneErrorNamingTheFieldAndTheValue) {
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: stepper}\n"); }),
            "dev.yaml: turntable.backend: unknown backend (expected grbl, manual or none) (got "
            "\"stepper\")");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, baud: 250000}\n"); }),
            "dev.yaml: turntable.baud: must be one of 9600, 19200, 38400, 57600, 115200, 230400, "
            "460800, 500000, 921600, 1000000 (got 250000)");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, axis: W}\n"); }),
            "dev.yaml: turntable.axis: must be one axis letter: X, Y, Z, A, B or C (got \"W\")");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, degrees_per_unit: 0}\n"); }),
            "dev.yaml: turntable.degrees_per_unit: must be a finite, non-zero number of degrees "
            "per firmware unit (got 0)");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, move_timeout_ms: 0}\n"); }),
            "dev.yaml: turntable.move_timeout_ms: must be in (0, 3600000] milliseconds (got 0)");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, settle_ms: -1}\n"); }),
            "dev.yaml: turntable.settle_ms: must be in [0, 600000] milliseconds (got -1)");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, port: \"\"}\n"); }),
            "dev.yaml: turntable.port: must name the serial port, e.g. /dev/ttyUSB0 (got \"\")");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: manual, port: /dev/ttyUSB0}\n"); }),
            "dev.yaml: turntable.port: only for backend grbl (got \"/dev/ttyUSB0\")");
  EXPECT_EQ(ErrorOf([] { Parse("turntable: {backend: grbl, auto_confirm: true}\n"); }),
            "dev.yaml: turntable.auto_confirm: only for backend manual (got true)");
  EXPECT_THAT(ErrorOf([] { Parse("turntable: {backend: grbl, speed: 3}\n"); }),
              StartsWith("dev.yaml: turntable"));
  EXPECT_THAT(ErrorOf([] { Parse("turntable: {backend: grbl, speed: 3}\n"); }), HasSubstr("speed"));
  // Built in code: Check() names `where` and the field.
  TurntableConfig config;
  config.backend = "grbl";
  config.tolerance_deg = 0;
  EXPECT_EQ(ErrorOf([&] { config.Check(); }),
            "turntable.tolerance_deg: must be in (0, 10] degrees");
  EXPECT_EQ(ErrorOf([&] { OpenTurntable(config); }),
            "turntable.tolerance_deg: must be in (0, 10] degrees");
}

TEST(NoneTurntable, IsOneViewAtZeroDegrees) {
  TurntableConfig config;
  config.where = "dev.yaml: turntable";
  auto table = OpenTurntable(config);
  EXPECT_EQ(table->Describe(), "dev.yaml: turntable: none");
  table->Home();
  table->MoveTo(0);
  EXPECT_EQ(table->PositionDeg(), 0.0);
  EXPECT_EQ(table->State(), TurntableState::kIdle);
  const TurntableError e = TurntableErrorOf([&] { table->MoveTo(30); });
  EXPECT_EQ(e.fault(), TurntableFault::kRefused);
  EXPECT_STREQ(e.what(),
               "dev.yaml: turntable: none: move to 30.000 deg: there is no turntable (backend "
               "none: a single view at 0 deg); add a turntable with backend grbl or manual to the "
               "devices file");
}

TurntableConfig Manual(bool auto_confirm = false) {
  TurntableConfig config;
  config.backend = "manual";
  config.auto_confirm = auto_confirm;
  config.where = "dev.yaml: turntable";
  return config;
}

TEST(ManualTurntable, PromptsForEachAngleAndWaitsForEnter) {
  Pipe in, out;
  ManualTurntable table(Manual(), {in.read_fd, out.write_fd});
  EXPECT_EQ(table.Describe(), "dev.yaml: turntable: manual (the operator turns the table)");
  std::thread mover([&] { table.MoveTo(30); });
  const std::string prompt = out.ReadUntil("(q to abort): ");
  EXPECT_EQ(prompt,
            "slshadow: turntable: turn the table to 30.000 deg (now at 0.000 deg), then press "
            "Enter (q to abort): ");
  const TurntableStatus waiting = table.Status();  // the prompt is out: it waits for Enter
  EXPECT_EQ(waiting.state, TurntableState::kMoving);
  EXPECT_EQ(waiting.position_deg, 0.0);
  in.Write("\n");
  mover.join();
  EXPECT_EQ(table.State(), TurntableState::kIdle);
  EXPECT_EQ(table.PositionDeg(), 30.0);

  in.Write("  \r\n");  // a line of blanks from a terminal confirms as well
  std::thread second([&] { table.MoveTo(90); });
  EXPECT_THAT(out.ReadUntil("(q to abort): "), HasSubstr("to 90.000 deg (now at 30.000 deg)"));
  second.join();
  EXPECT_EQ(table.PositionDeg(), 90.0);
  table.MoveTo(90);  // already there: asks nothing (a third prompt would block this thread)

  in.Write("\n");
  table.Home();
  EXPECT_THAT(out.ReadUntil("(q to abort): "), HasSubstr("set the table to its zero mark (0 deg)"));
  EXPECT_EQ(table.PositionDeg(), 0.0);
}

TEST(ManualTurntable, TheOperatorAbortsOrTheInputCloses) {
  Pipe in, out;
  ManualTurntable table(Manual(), {in.read_fd, out.write_fd});
  in.Write("q\n");
  const TurntableError aborted = TurntableErrorOf([&] { table.MoveTo(45); });
  EXPECT_EQ(aborted.fault(), TurntableFault::kAborted);
  EXPECT_STREQ(aborted.what(),
               "dev.yaml: turntable: manual (the operator turns the table): move to 45.000 deg: "
               "aborted by the operator");
  EXPECT_EQ(table.PositionDeg(), 0.0);
  in.CloseWrite();
  const TurntableError closed = TurntableErrorOf([&] { table.MoveTo(45); });
  EXPECT_EQ(closed.fault(), TurntableFault::kAborted);
  EXPECT_THAT(closed.what(),
              HasSubstr("move to 45.000 deg: the input closed before the operator confirmed"));
}

TEST(ManualTurntable, AutoConfirmPrintsThePromptAndGoesOn) {
  Pipe in, out;  // nothing is ever written to `in`: a read would block
  ManualTurntable table(Manual(/*auto_confirm=*/true), {in.read_fd, out.write_fd});
  table.MoveTo(120);
  EXPECT_EQ(out.ReadUntil("\n"),
            "slshadow: turntable: turn the table to 120.000 deg (now at 0.000 deg), "
            "auto-confirmed\n");
  EXPECT_EQ(table.PositionDeg(), 120.0);
}

TEST(ManualTurntable, OpenTurntableTalksOnStdinAndStderr) {
  Pipe in, err;
  const int saved_in = ::dup(0), saved_err = ::dup(2);
  ASSERT_GE(saved_in, 0);
  ASSERT_GE(saved_err, 0);
  ASSERT_EQ(::dup2(in.read_fd, 0), 0);
  ASSERT_EQ(::dup2(err.write_fd, 2), 2);
  in.Write("\n");
  std::optional<std::string> failure;
  try {
    auto table = OpenTurntable(Manual());
    table->MoveTo(60);
    if (table->PositionDeg() != 60.0) failure = "position not 60";
  } catch (const std::exception& e) {
    failure = e.what();
  }
  ::dup2(saved_in, 0);
  ::dup2(saved_err, 2);
  ::close(saved_in);
  ::close(saved_err);
  EXPECT_FALSE(failure) << *failure;
  EXPECT_THAT(err.ReadUntil("(q to abort): "), HasSubstr("turn the table to 60.000 deg"));
}

}  // namespace
}  // namespace slshadow::capture
