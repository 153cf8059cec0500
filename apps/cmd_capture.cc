// slshadow capture --rig RIG --devices DEVICES.yaml --patterns SPEC --out DIR [--resume]
//                  [--auto-exposure] [--poses N]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <iostream>

#include "apps/commands.h"
#include "capture/devices.h"
#include "capture/factory.h"
#include "capture/sequencer.h"
#include "capture/stop_on_interrupt.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"

namespace slshadow::app {
namespace {

std::string List(const std::vector<std::string>& names) {
  std::string s;
  for (const auto& n : names) s += (s.empty() ? "" : ", ") + n;
  return s;
}

}  // namespace

int RunCapture(int argc, char** argv) {
  CLI::App app{
      "Capture a structured-light ImageSet with real devices: the projector shows each pattern of "
      "SPEC,\n"
      "every camera of DEVICES takes it, each frame is checked against what the pattern predicts, "
      "and\n"
      "the frames go to DIR as an ImageSet (docs/formats.md \"ImageSet\") that `slshadow "
      "reconstruct`\n"
      "reads exactly like a simulated one.\n\n"
      "Per pattern: show, wait the projector's latency_us + settle_us (devices file), trigger all "
      "cameras\n"
      "together, grab each within its grab_timeout_ms, validate, retry (--max-retries), store. A "
      "frame is\n"
      "refused when it arrived damaged or late, when it is nearly equal to the previous one "
      "although the\n"
      "patterns differ (the projector had not switched yet: raise latency_us), or when a Gray bit "
      "and its\n"
      "inverse are not complementary; after the retries the capture stops with a message naming "
      "the\n"
      "pattern and the camera. Frame-id gaps, retries, timeouts and the cameras' stream counters "
      "go to\n"
      "the manifest's extra.capture; each image record carries the device serial and frame id.\n\n"
      "Interrupted captures resume: frames are staged in DIR.partial/ (an fsynced journal); after "
      "Ctrl-C,\n"
      "a crash or a lost camera, run the same command with --resume and it continues from the "
      "first\n"
      "missing frame, then commits DIR. The result equals an uninterrupted capture.\n\n"
      "--poses N captures N calibration board poses one after another (Enter between poses) into\n"
      "DIR/pose_00 ... DIR/pose_NN, the layout of `slshadow calibrate rig --imagesets "
      "DIR/pose_*`.\n\n"
      "Devices file: docs/formats.md \"Devices YAML\", examples in config/devices/. Camera "
      "backends\n"
      "built into this slshadow: " +
          List(capture::BuiltInCameraBackends()) +
          "; projector backends: " + List(capture::BuiltInProjectorBackends()) +
          ".\n\n"
          "Exit status: 0 complete, 1 error (nothing committed, the staged frames kept), 130 "
          "interrupted.\n"
          "Example without hardware (replays a simulated scan through the whole capture path):\n"
          "  slshadow simulate --rig config/demo/rig.yaml --scene config/demo/scene.yaml \\\n"
          "      --patterns config/patterns/graycode_phase.yaml --out scan_virtual --encoding pgm\n"
          "  slshadow capture --rig config/demo/rig.yaml --devices config/devices/replay.yaml \\\n"
          "      --patterns config/patterns/graycode_phase.yaml --out scan_replayed",
      argv[0]};
  std::string rig_path, devices_path, patterns_path, out_dir, encoding = "png";
  bool resume = false, overwrite = false, auto_exposure = false, no_validate = false, quiet = false;
  int poses = 0, max_retries = 3;
  app.add_option("--rig", rig_path,
                 "rig file (docs/formats.md \"Rig YAML\"): camera names and image sizes")
      ->required();
  app.add_option("--devices", devices_path,
                 "devices file (docs/formats.md \"Devices YAML\", config/devices/)")
      ->required();
  app.add_option("--patterns", patterns_path,
                 "pattern spec (docs/formats.md \"Pattern spec\"), e.g. config/demo/patterns.yaml")
      ->required();
  app.add_option("--out", out_dir,
                 "output ImageSet folder (with --poses: the folder of the pose ImageSets)")
      ->required();
  app.add_flag("--resume", resume,
               "continue the capture staged in OUT.partial (same rig, patterns and encoding)");
  app.add_flag("--overwrite", overwrite, "replace an existing OUT when the capture completes");
  app.add_flag("--auto-exposure", auto_exposure,
               "set each camera's exposure from the white frame so the brightest 1 % of the lit "
               "area sits at 85 % of "
               "full scale; the chosen values go to the manifest (a resumed capture reuses them)");
  app.add_option("--poses", poses,
                 "capture N board poses into OUT/pose_00 ... (Enter between poses)")
      ->check(CLI::Range(1, 99));
  app.add_option("--max-retries", max_retries,
                 "extra attempts per pattern (and per pattern pair) before giving up")
      ->capture_default_str()
      ->check(CLI::Range(0, 100));
  app.add_option("--encoding", encoding, "image encoding: png, pgm (raw, fastest) or tiff")
      ->capture_default_str()
      ->check(CLI::IsMember({"png", "pgm", "tiff"}));
  app.add_flag("--no-validate", no_validate,
               "store frames without checking them against the patterns (a projector backend "
               "none needs it, unless every camera replays a recorded capture)");
  app.add_flag("--quiet", quiet, "print nothing but errors");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const Rig rig = LoadRig(rig_path);
  const PatternSpec spec = LoadPatternSpec(patterns_path);
  // Before any device opens (Capture checks it again, naming no files).
  CheckProjectorSize(rig, spec, patterns_path, rig_path);
  const capture::OpenedDevices opened = capture::OpenDevicesFile(devices_path, rig);

  capture::SequencerOptions options;
  options.settle = opened.settle;
  options.max_retries = max_retries;
  options.validate = !no_validate;
  options.auto_exposure = auto_exposure;
  options.writer.encoding = ImageEncodingFromString(encoding);
  options.writer.resume = resume;
  options.writer.overwrite = overwrite;
  options.progress = !quiet;
  options.extra = {{"command", CommandLine(argc, argv)}, {"devices", devices_path}};
  const capture::StopOnInterrupt interrupt;
  options.stop = interrupt.flag();

  const std::string again = "run the same command with --resume to continue";
  SLSHADOW_THROW_IF(
      poses > 0 && opened.sequence_projector, devices_path,
      ": projector: --poses needs a projector shown pattern by pattern (mode: video)");
  if (poses > 0) {
    const capture::PosesSummary s = capture::CapturePoses(
        rig, spec, opened.cameras, *opened.projector, out_dir, poses, options, std::cin, std::cerr);
    if (!quiet) {
      for (const auto& p : s.poses)
        std::printf("%s: %s\n", p.out.string().c_str(), p.BriefReport().c_str());
    }
    if (s.interrupted) {
      std::fprintf(stderr, "capture: interrupted after %zu new pose(s) (%d already complete); %s\n",
                   s.poses.size(), s.skipped, again.c_str());
      return 130;
    }
    if (!quiet)
      std::printf("capture: %d poses in %s (slshadow calibrate rig --imagesets %s/pose_*)\n", poses,
                  out_dir.c_str(), out_dir.c_str());
    return 0;
  }
  const capture::CaptureSummary s = capture::CaptureImageSet(rig, spec, opened, out_dir, options);
  if (s.interrupted) {
    std::fprintf(stderr, "capture: interrupted: %d of %d images staged in %s; %s\n",
                 s.images_before + s.images_stored, s.images_total, s.staging.string().c_str(),
                 again.c_str());
    return 130;
  }
  if (!quiet)
    std::printf("capture: %s -> %s\n%s\n", devices_path.c_str(), out_dir.c_str(),
                s.BriefReport().c_str());
  return 0;
}

}  // namespace slshadow::app
