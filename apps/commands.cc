#include "apps/commands.h"

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <string>

#include <CLI/CLI.hpp>

#include "core/error.h"
#include "core/huge_pages.h"
#include "reconstruct/strict_policy.h"
#include "report/html_report.h"

#ifndef SLSHADOW_VERSION
#define SLSHADOW_VERSION "unknown"
#endif

namespace slshadow::app {

const std::vector<Command>& Commands() {
  static const std::vector<Command> commands = {
      {"demo",
       "the main job: simulate the demo rig scanning the demo part, reconstruct both modes, "
       "compare with truth",
       RunDemo},
      {"simulate",
       "virtual scan: ray-cast a rig over a scene into an ImageSet + ground truth (simulate --rig "
       "--scene --patterns --out)",
       RunSimulate},
      {"patterns",
       "pattern sequences: write projector images of a spec (patterns generate SPEC --out DIR), "
       "describe one",
       RunPatterns},
      {"reconstruct",
       "decode an ImageSet and triangulate a point cloud (reconstruct IMAGESET --out CLOUD.ply "
       "[--mode projector|stereo])",
       RunReconstruct},
      {"compare",
       "compare a cloud against a reference mesh or cloud: registration, deviations, report folder",
       RunCompare},
      {"calibrate",
       "calibrate cameras, stereo, projector or rig from board images (calibrate "
       "camera|stereo|projector|rig|import|export)",
       RunCalibrate},
      {"bench",
       "speed of simulate, decode, reconstruct and compare on the demo, with peers in the same run",
       RunBenchCommand},
      {"shadow",
       "real vs virtual: a real scan against its twin re-scan of the part; physics fitted, causes "
       "named (shadow IMAGESET --part PART --out DIR)",
       RunShadowCommand},
      {"rig",
       "inspect a rig file: cameras, projector, baselines, angles, overlap (rig show RIG.yaml)",
       RunRig},
      {"latency",
       "projector-to-camera latency to wait after each pattern (latency --devices DEVICES.yaml), "
       "or the window's present latency",
       RunLatency},
      {"capture",
       "real capture: projector + cameras from a devices file into a resumable ImageSet (capture "
       "--rig --devices --patterns --out)",
       RunCapture},
      {"devices",
       "list cameras and displays to capture with (devices [--address IP]... [--discover]: "
       "discovery broadcasts)",
       RunDevices},
      {"projector",
       "a DLP LightCrafter 4500 over USB: firmware and mode, switch video/pattern mode, validate "
       "(projector info|mode|validate)",
       RunProjector},
      {"scan",
       "multi-view scan with real devices: the turntable turns (or you place the part), one "
       "ImageSet per view, resumable (scan --rig --devices --patterns --views --out PROJECT)",
       RunScan},
      {"turntable",
       "check the devices file's turntable: status, home, move --deg A (turntable status "
       "--devices D)",
       RunTurntable},
      {"merge",
       "merge a multi-view project into one model and compare it with the CAD model (merge PROJECT "
       "--out MODEL [--cad MESH])",
       RunMerge},
      {"report",
       "(re)write the self-contained HTML page (report.html) of a compare, shadow or demo result "
       "folder (report DIR)",
       RunReport},
      {"plan",
       "plan a turntable scan: the fewest table angles covering the target share of the part, "
       "predicted without images (plan --rig --part --turntable --target T --out VIEWS.yaml)",
       RunPlan},
      {"sweep",
       "studies as independent jobs: sweep plan STUDY.yaml --out JOBS | run JOBS --shard I/N | "
       "merge JOBS --out RESULT",
       RunSweep},
  };
  return commands;
}

void AddStrictOptions(CLI::App* app, StrictOptions* strict) {
  app->add_flag("--strict", strict->enabled,
                "what a measurement chain should run with: end with a non-zero exit and write "
                "nothing when a reconstruction's calibration check warns, cannot run (e.g. "
                "camera-projector with one coded axis and no stereo check of that camera), or "
                "turns fewer than --strict-min-points of its decoded pixels into points");
  app->add_option("--strict-min-points", strict->min_point_share,
                  "strict mode: least share of the decoded (valid) pixels that must become "
                  "points, 0..1 (stereo: of the mean over both cameras)")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
}

void AddHtmlOptions(CLI::App* app, bool* no_html, report::HtmlOptions* html) {
  app->add_flag("--no-html", *no_html,
                "do not write report.html (the self-contained page of the result; slshadow report "
                "DIR writes it later)");
  app->add_option("--html-max-points", html->max_points,
                  "points drawn in report.html's 3D view (a fixed-seed uniform sample; the figures "
                  "use every point)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
}

std::string CommandLine(int argc, char** argv) {
  std::string line;
  for (int i = 0; i < argc; ++i) line += (i ? " " : "") + std::string(argv[i]);
  return line;
}

int ExitOnParseError(const CLI::App& app, const CLI::ParseError& error) {
  if (error.get_exit_code() == static_cast<int>(CLI::ExitCodes::Success)) return app.exit(error);
  std::string message = error.what();
  for (char& c : message) {
    if (c == '\n') c = ' ';
  }
  std::fprintf(stderr, "slshadow: error: %s: %s (--help lists the options)\n",
               app.get_name().c_str(), message.c_str());
  return error.get_exit_code();
}

namespace {

void PrintHelp() {
  std::printf(
      "slshadow %s: a structured-light 3D scanner and its digital shadow\n\n"
      "usage: slshadow <command> [options]    (slshadow <command> --help for its options)\n\n"
      "commands:\n",
      SLSHADOW_VERSION);
  for (const auto& c : Commands()) std::printf("  %-12s %s\n", c.name.c_str(), c.summary.c_str());
  std::printf(
      "\nconventions: millimetres, radians, pixels (OpenCV: (0,0) is the centre of the top-left "
      "pixel);\n"
      "file formats are documented in docs/formats.md.\n");
}

}  // namespace

int Main(int argc, char** argv) {
  if (argc < 2 || std::strcmp(argv[1], "--help") == 0 || std::strcmp(argv[1], "-h") == 0 ||
      std::strcmp(argv[1], "help") == 0) {
    PrintHelp();
    return argc < 2 ? EXIT_FAILURE : EXIT_SUCCESS;
  }
  if (std::strcmp(argv[1], "--version") == 0 || std::strcmp(argv[1], "version") == 0) {
    std::printf("slshadow %s\n%s\n", SLSHADOW_VERSION, HugePagesStatus().c_str());
    return EXIT_SUCCESS;
  }
  for (const auto& c : Commands()) {
    if (c.name != argv[1]) continue;
    std::string program = std::string("slshadow ") + argv[1];
    std::vector<char*> args;
    args.push_back(program.data());
    for (int i = 2; i < argc; ++i) args.push_back(argv[i]);
    try {
      return c.run(static_cast<int>(args.size()), args.data());
    } catch (const Error& e) {
      std::fprintf(stderr, "slshadow: error: %s\n", e.what());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "slshadow: error: %s\n", e.what());
    }
    return EXIT_FAILURE;
  }
  std::fprintf(stderr,
               "slshadow: error: unknown command '%s' (slshadow --help lists the commands)\n",
               argv[1]);
  return EXIT_FAILURE;
}

}  // namespace slshadow::app
