// slshadow bench [--repetitions N] [--only ENTRY ...] [--json FILE]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/file_util.h"
#include "workflows/pipeline/bench.h"

namespace slshadow::app {
using pipeline::BenchOptions;
using pipeline::BenchToJson;
using pipeline::FormatBench;
using pipeline::RunBench;

int RunBenchCommand(int argc, char** argv) {
  BenchOptions options;
  bool no_opencv = false;
  bool no_open3d = false;
  bool no_cloudcompare = false;
  std::string json_path;
  CLI::App app{
      "Speed of the pipeline on the embedded demo (the demo rig scanning the demo part, images\n"
      "rendered in memory, no file encoding), with peers measured in the same run:\n"
      "  simulate     ray casting + pattern passes, 2 cameras x 38 patterns\n"
      "  decode       DecodePatterns on both cameras; peer: OpenCV GrayCodePattern per-pixel "
      "decoding\n"
      "  reconstruct  decode + triangulate both cameras (camera-projector); stereo from decoded "
      "maps\n"
      "  compare      C2M and C2C of the stereo cloud; peers: Open3D (both), CloudCompare (C2C)\n"
      "Each entry runs N times; the median wall time and the CPU time of that run are printed.\n"
      "Google Benchmark programs with more detail: bench/*/ *_bench (docs/benchmarks.md).",
      argv[0]};
  app.add_option("--repetitions,-n", options.repetitions, "runs per entry (median reported)")
      ->capture_default_str();
  app.add_option("--only", options.only, "entries to run (default: all)");
  app.add_flag("--no-opencv", no_opencv, "skip the OpenCV peer (about 1 s per repetition)");
  app.add_flag("--no-open3d", no_open3d, "skip the Open3D C2M peer (bench/c2m_peer/open3d_c2m.py)");
  app.add_flag("--no-cloudcompare", no_cloudcompare, "skip the CloudCompare C2C peer");
  app.add_option(
      "--json", json_path,
      "also write the entries as JSON (docs/benchmarks.md is rendered from such a file)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  options.with_opencv = !no_opencv;
  options.with_open3d = !no_open3d;
  options.with_cloudcompare = !no_cloudcompare;
  const auto entries = RunBench(options);
  if (!json_path.empty()) WriteTextFileAtomically(json_path, BenchToJson(entries, options));
  std::printf("%s", FormatBench(entries).c_str());
  return 0;
}

}  // namespace slshadow::app
