// slshadow projector info|mode|validate [--usb BUS:ADDRESS]: a TI DLP LightCrafter 4500 over USB.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <string>

#include "apps/commands.h"
#include "capture/lightcrafter_protocol.h"
#include "capture/lightcrafter_usb.h"
#include "core/error.h"

namespace slshadow::app {
namespace {

const char* ModeName(capture::dlpc350::DisplayMode mode) {
  return mode == capture::dlpc350::DisplayMode::kVideo ? "video" : "pattern";
}

}  // namespace

int RunProjector(int argc, char** argv) {
  CLI::App app{
      "A TI DLP LightCrafter 4500 (DLPC350) over USB: firmware and display mode (info), switch\n"
      "between video mode (an HDMI display) and pattern-sequence mode (mode video|pattern),\n"
      "or validate the programmed pattern sequence and print every status bit (validate).",
      argv[0]};
  app.require_subcommand(1);
  std::string usb;
  app.add_option(
      "--usb", usb,
      "BUS:ADDRESS of the LightCrafter (default: the only one; `slshadow devices` lists them)");
  app.add_subcommand("info", "firmware versions and display mode");
  auto* mode_cmd = app.add_subcommand("mode", "set the display mode");
  std::string mode;
  mode_cmd->add_option("MODE", mode, "video | pattern")
      ->required()
      ->check(CLI::IsMember({"video", "pattern"}));
  app.add_subcommand("validate", "validate the pattern sequence (polls until the device is done)");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const auto transport = capture::OpenLightCrafterUsb(usb);
  capture::dlpc350::Client client(*transport);
  if (app.got_subcommand("info")) {
    const auto version = client.GetVersion();
    std::printf("%s\nfirmware: %s\ndisplay mode: %s\n", transport->Describe().c_str(),
                version.ToString().c_str(), ModeName(client.GetDisplayMode()));
  } else if (app.got_subcommand("mode")) {
    const auto wanted = mode == "video" ? capture::dlpc350::DisplayMode::kVideo
                                        : capture::dlpc350::DisplayMode::kPatternSequence;
    if (wanted == capture::dlpc350::DisplayMode::kVideo)
      client.SetSequence(capture::dlpc350::SequenceControl::kStop);
    client.SetDisplayMode(wanted);
    const auto now = client.GetDisplayMode();
    SLSHADOW_THROW_IF(now != wanted, transport->Describe(), ": display mode reads back as ",
                      ModeName(now), " after setting ", mode);
    std::printf("%s: display mode %s\n", transport->Describe().c_str(), ModeName(now));
  } else {
    const auto v = client.Validate();
    std::printf("%s: validation status 0x%02X: %s\n", transport->Describe().c_str(), v.status,
                v.ok() ? (v.warnings.empty() ? "valid" : "valid with warnings") : "INVALID");
    for (const auto& e : v.errors) std::printf("  error   %s\n", e.c_str());
    for (const auto& w : v.warnings) std::printf("  warning %s\n", w.c_str());
    return v.ok() ? 0 : 1;
  }
  return 0;
}

}  // namespace slshadow::app
