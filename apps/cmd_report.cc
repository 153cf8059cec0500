// slshadow report DIR [--max-points N]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "report/html_report.h"

namespace slshadow::app {

int RunReport(int argc, char** argv) {
  CLI::App app{
      "(Re)write DIR/report.html: one self-contained page of a result, to open in any browser\n"
      "from the file (no network, no server) or to send to someone who never runs slshadow.\n\n"
      "DIR is a folder written by\n"
      "  slshadow compare ... --out DIR   (report.json, compared.ply, histogram.png, "
      "deviation_map.png)\n"
      "  slshadow shadow ... --out DIR    (report.json, clouds/, maps/, charts/)\n"
      "  slshadow demo --out DIR          (demo.json, <mode>/ comparison folders, "
      "ground_truth.ply)\n"
      "  slshadow merge PROJECT --out DIR (report.json, merged.ply, cad_deviation.ply)\n"
      "Those commands write the page themselves unless given --no-html; this command writes it\n"
      "again, e.g. with another --max-points, or for a folder written before pages existed.\n\n"
      "The page holds: a 3D view of the cloud(s) coloured by signed deviation with the colour\n"
      "scale and range of deviation_map.png (orbit: drag; pan: right-drag; zoom: wheel; click a\n"
      "point for its deviation, camera pixel and position), the reference or CAD mesh as a\n"
      "toggle when its file is found, every table of report.json (values as written there,\n"
      "each cell naming its field), and the PNG charts and maps. three.js (libjs-three, MIT) is\n"
      "embedded with its licence. docs/formats.md \"HTML report\" describes the page.\n\n"
      "Example:\n"
      "  slshadow compare scan.ply part.stl --out cmp --no-html\n"
      "  slshadow report cmp --max-points 300000 && xdg-open cmp/report.html",
      argv[0]};
  std::string dir;
  report::HtmlOptions options;
  app.add_option("DIR", dir, "result folder (holds report.json or demo.json)")
      ->required()
      ->check(CLI::ExistingDirectory);
  app.add_option("--max-points", options.max_points,
                 "points drawn in the 3D view over all its clouds (a fixed-seed uniform sample; "
                 "the tables use every point)")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const report::HtmlSummary summary = report::WriteHtmlReport(dir, options);
  for (const auto& note : summary.notes) std::printf("note: %s\n", note.c_str());
  std::printf("%s\nwritten: %s\n", summary.Brief().c_str(), summary.path.string().c_str());
  return 0;
}

}  // namespace slshadow::app
