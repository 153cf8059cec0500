// slshadow scan --rig RIG --devices DEVICES.yaml --patterns SPEC --views VIEWS.yaml --out PROJECT
//               [--resume] [--yes] [--encoding E] [--max-retries N] [--auto-exposure] [--no-home]
// slshadow turntable status|home|move --devices DEVICES.yaml [--deg A]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>
#include <memory>
#include <sstream>

#include "apps/commands.h"
#include "capture/devices.h"
#include "capture/factory.h"
#include "capture/stop_on_interrupt.h"
#include "capture/turntable.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/strict_policy.h"
#include "workflows/multiview/scan.h"
#include "workflows/multiview/views.h"

namespace slshadow::app {

int RunScan(int argc, char** argv) {
  CLI::App app{
      "Scan a whole part with real devices: for each view of VIEWS (docs/formats.md \"Views "
      "YAML\") the\n"
      "turntable of DEVICES turns the part to the view's table_deg and is read back, or, for a "
      "view\n"
      "without table_deg, you move the part by hand and press Enter; then the projector and "
      "cameras\n"
      "capture one validated ImageSet of the view exactly as `slshadow capture` does. PROJECT "
      "gets\n"
      "project.json and views/<name>/ (docs/formats.md \"Multi-view project\"), which `slshadow "
      "merge`\n"
      "turns into one model. Each view records its provenance in project.json: commanded and "
      "read-back\n"
      "table angle (before and after the capture), the table, the cameras' serials, times.\n\n"
      "Turntable (devices file, turntable: entry): grbl (a GRBL 1.1 controller on a serial port: "
      "moves\n"
      "in machine coordinates, waits until Idle within tolerance_deg), manual (prints \"turn the "
      "table\n"
      "to X deg\" and waits for Enter; --yes takes it as done), none (only views at 0 deg). Table "
      "views\n"
      "need the rig's turntable axis: measure it first with `slshadow calibrate turntable`. Check "
      "the\n"
      "table before a scan with `slshadow turntable status|home|move --devices DEVICES`.\n\n"
      "Faults: a turntable error, alarm, timeout or lost port, or a camera or projector whose "
      "frames\n"
      "fail, ends the scan with one message naming the view and the device. Everything written "
      "stays;\n"
      "fix the device and run the same command with --resume: complete views are kept, the "
      "faulty view\n"
      "continues at its first missing frame (after the table turns to its angle again). A table "
      "that\n"
      "moved during a view's capture rejects the view (moved aside to "
      "views/<name>.rejected-N).\n"
      "With --strict each view is reconstructed right after its capture, as `slshadow reconstruct "
      "--strict`\n"
      "does: a calibration check that warns or cannot run, or too few points, rejects the view "
      "the same\n"
      "way and stops the scan (a rig bumped mid-scan is caught at that view; recalibrate and "
      "start a new\n"
      "project, since a resume needs the same rig file).\n\n"
      "Exit status: 0 every view complete, 1 error (the project resumable), 130 interrupted "
      "(Ctrl-C,\n"
      "or q at a prompt).\n"
      "Example (a GRBL table on /dev/ttyUSB0, 12 views a full turn; "
      "config/devices/stereo_gige_hdmi_grbl_turntable.yaml "
      "shows\n"
      "the turntable entry):\n"
      "  slshadow calibrate turntable --rig rig.yaml --target board.yaml --images cal/* --out "
      "rig_tt.yaml\n"
      "  slshadow scan --rig rig_tt.yaml --devices devices.yaml --patterns "
      "config/patterns/graycode_phase.yaml \\\n"
      "      --views config/demo/views_12.yaml --out part_scan\n"
      "  slshadow merge part_scan --out part_model --cad part.stl",
      argv[0]};
  std::string rig_path, devices_path, patterns_path, views_path, out_dir, encoding = "png";
  bool resume = false, yes = false, auto_exposure = false, no_validate = false, no_home = false,
       quiet = false;
  int max_retries = 3;
  multiview::ScanOptions options;
  app.add_option("--rig", rig_path,
                 "rig file (docs/formats.md \"Rig YAML\"), with its turntable axis for table views")
      ->required();
  app.add_option("--devices", devices_path,
                 "devices file (docs/formats.md \"Devices YAML\"): cameras, projector, turntable")
      ->required();
  app.add_option("--patterns", patterns_path, "pattern spec (docs/formats.md \"Pattern spec\")")
      ->required();
  app.add_option("--views", views_path,
                 "views file (docs/formats.md \"Views YAML\"): names and table angles, in scan "
                 "order")
      ->required();
  app.add_option("--out", out_dir,
                 "project folder to write (docs/formats.md \"Multi-view project\")")
      ->required();
  app.add_flag("--resume", resume,
               "continue the project in OUT (same rig, patterns, views and encoding): complete "
               "views are kept, a partial view continues at its first missing frame");
  app.add_flag("--yes", yes,
               "do not wait for Enter: a manual turntable and hand-placed views are taken as set "
               "(scripts)");
  app.add_flag("--no-home", no_home,
               "do not reference the table before its first move (grbl with homing: true runs "
               "$H; manual asks for the zero mark)");
  app.add_option("--max-retries", max_retries,
                 "extra attempts per pattern (and per pattern pair) before a view fails")
      ->capture_default_str()
      ->check(CLI::Range(0, 100));
  app.add_option("--encoding", encoding, "image encoding: png, pgm (raw, fastest) or tiff")
      ->capture_default_str()
      ->check(CLI::IsMember({"png", "pgm", "tiff"}));
  app.add_flag("--auto-exposure", auto_exposure,
               "choose each camera's exposure per view from its white frame (see `slshadow "
               "capture --help`)");
  app.add_flag("--no-validate", no_validate,
               "store frames without checking them against the patterns (a projector backend "
               "none needs it)");
  app.add_flag("--quiet", quiet, "print nothing but errors and operator prompts");
  AddStrictOptions(&app, &options.strict);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const Rig rig = LoadRig(rig_path);
  const PatternSpec spec = LoadPatternSpec(patterns_path);
  const multiview::ViewsFile views = multiview::LoadViews(views_path);
  bool on_table = false;
  for (const auto& v : views.views) on_table = on_table || v.OnTable();
  const capture::OpenedDevices opened =
      capture::OpenDevicesFile(devices_path, rig, [&](capture::DevicesConfig& devices) {
        if (devices.turntable.backend == "manual" && yes) devices.turntable.auto_confirm = true;
        multiview::CheckScanInputs(rig, spec, views, devices.turntable.backend, devices_path);
      });
  const capture::DevicesConfig& devices = opened.config;
  std::unique_ptr<capture::Turntable> turntable;
  if (on_table) turntable = capture::OpenTurntable(devices.turntable);

  multiview::ScanDevices scan_devices;
  scan_devices.cameras = opened.cameras;
  scan_devices.projector = opened.projector.get();
  scan_devices.sequence_projector = opened.sequence_projector.get();
  scan_devices.turntable = turntable.get();
  scan_devices.turntable_backend = devices.turntable.backend;
  scan_devices.turntable_tolerance_deg = devices.turntable.tolerance_deg;
  scan_devices.devices_file = devices_path;

  options.resume = resume;
  options.home = !no_home;
  options.confirm_hand_views = !yes;
  options.sequencer.settle = opened.settle;
  options.sequencer.max_retries = max_retries;
  options.sequencer.validate = !no_validate;
  options.sequencer.auto_exposure = auto_exposure;
  options.sequencer.writer.encoding = ImageEncodingFromString(encoding);
  options.sequencer.progress = !quiet;
  const std::string cmdline = CommandLine(argc, argv);
  options.sequencer.extra = {{"command", cmdline}, {"devices", devices_path}};
  options.provenance = {{"command", cmdline}, {"views_file", views_path}};
  std::ostringstream discard;
  if (quiet) options.prompt = yes ? &discard : &std::cerr;

  const capture::StopOnInterrupt interrupt;
  options.sequencer.stop = interrupt.flag();

  const multiview::ScanSummary s =
      multiview::ScanProject(rig, spec, views, scan_devices, out_dir, options);
  if (s.interrupted) {
    std::fprintf(stderr, "scan: interrupted: %s; run the same command with --resume to continue\n",
                 s.BriefReport().c_str());
    return 130;
  }
  if (!quiet)
    std::printf("scan: %s -> %s\n%s\nnext: slshadow merge %s --out MODEL\n", views_path.c_str(),
                out_dir.c_str(), s.BriefReport().c_str(), out_dir.c_str());
  return 0;
}

int RunTurntable(int argc, char** argv) {
  CLI::App app{
      "Check the turntable of a devices file before a scan (docs/formats.md \"Devices YAML\", "
      "turntable:):\n"
      "  status   open the table and print its state and angle (grbl: the controller's status "
      "report)\n"
      "  home     reference it (grbl with homing: true: the homing cycle $H; manual: the zero "
      "mark)\n"
      "  move     turn it to --deg (absolute, degrees as the table counts them) and wait\n"
      "A grbl table is reset when it is opened (as GRBL does on every new connection). Errors "
      "name the\n"
      "device and the request; exit status 1. Example:\n"
      "  slshadow turntable move --devices devices.yaml --deg 90",
      argv[0]};
  std::string action, devices_path;
  double deg = 0;
  bool yes = false;
  app.add_option("action", action, "status, home or move")
      ->required()
      ->check(CLI::IsMember({"status", "home", "move"}));
  app.add_option("--devices", devices_path, "devices file with a turntable: entry")->required();
  auto* deg_option = app.add_option("--deg", deg, "move: the absolute table angle, degrees");
  app.add_flag("--yes", yes, "manual: do not wait for Enter");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  SLSHADOW_THROW_IF(action == "move" && deg_option->count() == 0,
                    "slshadow turntable move: --deg is required");
  capture::DevicesConfig devices = capture::LoadDevices(devices_path);
  if (devices.turntable.backend == "manual" && yes) devices.turntable.auto_confirm = true;
  const std::unique_ptr<capture::Turntable> table = capture::OpenTurntable(devices.turntable);
  if (action == "home") table->Home();
  if (action == "move") table->MoveTo(deg);
  const capture::TurntableStatus status = table->Status();
  std::printf("%s: %s at %.4f deg%s%s\n", table->Describe().c_str(),
              capture::ToString(status.state).c_str(), status.position_deg,
              status.detail.empty() ? "" : " | ", status.detail.c_str());
  return status.state == capture::TurntableState::kAlarm ||
                 status.state == capture::TurntableState::kFault
             ? 1
             : 0;
}

}  // namespace slshadow::app
