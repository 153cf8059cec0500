// slshadow rig show RIG.yaml
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/rig.h"

namespace slshadow::app {

int RunRig(int argc, char** argv) {
  CLI::App app{
      "Inspect a rig file (docs/formats.md, \"Rig YAML\").\n\n"
      "  show RIG.yaml   print every camera and the projector (resolution, intrinsics, field of\n"
      "                  view, position) and, per pair, the baseline, the triangulation angle at\n"
      "                  the working distance and the share of the first device's image whose\n"
      "                  rays at the working distance also land in the second device's image.",
      argv[0]};
  app.require_subcommand(1);
  std::string rig_path;
  auto* show = app.add_subcommand("show", "print the rig's geometry");
  show->add_option("RIG", rig_path, "rig file (.yaml or .json)")->required();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const Rig rig = LoadRig(rig_path);
  std::printf("%s", DescribeRig(rig).c_str());
  return 0;
}

}  // namespace slshadow::app
