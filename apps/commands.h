// The slshadow command line: a table of subcommands, each a thin `int RunX(argc, argv)` that
// parses its options (CLI11), makes one library call and writes its outputs (STYLE.md habit 10).
// Compiled into slshadow_app so tests can call the subcommands directly.
#pragma once

#include <string>
#include <vector>

namespace CLI {
class App;
class ParseError;
}  // namespace CLI

namespace slshadow {
struct StrictOptions;
}  // namespace slshadow
namespace slshadow::report {
struct HtmlOptions;
}  // namespace slshadow::report
namespace slshadow::multiview {
struct MergeOptions;
}  // namespace slshadow::multiview

namespace slshadow::app {

struct Command {
  std::string name;                   // first word after "slshadow"
  std::string summary;                // one line for `slshadow --help`
  int (*run)(int argc, char** argv);  // argv[0] is "slshadow <name>"
};

// All subcommands, in the order `slshadow --help` lists them.
const std::vector<Command>& Commands();

// Entry point: dispatches argv[1] to its subcommand. Catches slshadow::Error (and any other
// exception), prints one line "slshadow: error: ..." and returns EXIT_FAILURE.
int Main(int argc, char** argv);

// A subcommand's answer to a command-line parse error: --help and --version print as CLI11 does;
// anything else is one line on stderr ("slshadow: error: slshadow rig: RIG is required ...") and
// CLI11's non-zero exit code.
int ExitOnParseError(const CLI::App& app, const CLI::ParseError& error);

// `--strict` and `--strict-min-points` (reconstruct/strict_policy.h), with the help text that says
// what strict mode refuses; shared by the commands that reconstruct a capture.
void AddStrictOptions(CLI::App* app, StrictOptions* strict);

// `--no-html` (sets *no_html) and `--html-max-points` (report/html_report.h), with their help text;
// shared by the commands that write a report.html.
void AddHtmlOptions(CLI::App* app, bool* no_html, report::HtmlOptions* html);

// The fusion's options (--fuse-*: cell, agreement bound, per-point noise model, the checks of
// single-view points; workflows/multiview/merge.h step 4), with help text that says what each
// does; shared by `slshadow merge` and `slshadow demo --views`. Defined in cmd_merge.cc.
void AddFusionOptions(CLI::App* app, multiview::MergeOptions* merge);

// The command line as one string, the words of argv joined by single spaces ("slshadow capture
// --rig rig.yaml ..."), as the outputs' provenance records it.
std::string CommandLine(int argc, char** argv);

// Subcommands.
int RunRig(int argc, char** argv);
int RunCalibrate(int argc, char** argv);
int RunPatterns(int argc, char** argv);
int RunReconstruct(int argc, char** argv);
int RunCompare(int argc, char** argv);
int RunSimulate(int argc, char** argv);
int RunDemo(int argc, char** argv);
int RunBenchCommand(int argc, char** argv);
int RunLatency(int argc, char** argv);
int RunCapture(int argc, char** argv);
int RunDevices(int argc, char** argv);
int RunShadowCommand(int argc, char** argv);
int RunProjector(int argc, char** argv);
int RunSweep(int argc, char** argv);
int RunMerge(int argc, char** argv);
int RunPlan(int argc, char** argv);
int RunScan(int argc, char** argv);
int RunTurntable(int argc, char** argv);
int RunReport(int argc, char** argv);

}  // namespace slshadow::app
