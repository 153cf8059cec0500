// slshadow devices [--address IP]... [--discover]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "capture/device_list.h"

namespace slshadow::app {

int RunDevices(int argc, char** argv) {
  CLI::App app{
      "List the cameras (and displays) slshadow can capture with.\n\n"
      "Without options: USB3 Vision cameras (local USB enumeration; nothing is sent on any\n"
      "network). GigE Vision cameras are found only when asked: --address opens one camera at\n"
      "its IP address (GVCP to that address only); --discover broadcasts a GigE Vision discovery\n"
      "on every network interface and opens each camera that answers.",
      argv[0]};
  std::vector<std::string> addresses;
  bool discover = false;
  app.add_option("--address", addresses, "IPv4 address of a GigE Vision camera (repeatable)");
  app.add_flag("--discover", discover,
               "broadcast a GigE Vision discovery on every network interface");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  capture::DeviceListOptions options;
  options.addresses = addresses;
  options.discover = discover;
  capture::ListDevices(options, [](const std::string& line) { std::printf("%s", line.c_str()); });
  return 0;
}

}  // namespace slshadow::app
