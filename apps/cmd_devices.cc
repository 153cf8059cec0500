// slshadow devices [--address IP]... [--discover]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "apps/commands.h"
#include "capture/aravis_camera.h"
#include "capture/lightcrafter_usb.h"
#include "capture/v4l2_camera.h"
#include "capture/window_projector.h"
#include "core/error.h"

namespace slshadow::app {
namespace {

std::string Formats(const capture::CameraInfo& info) {
  std::string out;
  for (auto f : info.pixel_formats) out += (out.empty() ? "" : ",") + capture::ToString(f);
  return out.empty() ? "none of Mono8/Mono12/Mono16" : out;
}

void PrintCamera(const capture::CameraInfo& info, const std::string& protocol, const std::string& address) {
  std::printf("camera  %-10s %-16s vendor=%s model=%s serial=%s sensor=%dx%d formats=%s\n",
              protocol.c_str(), address.c_str(), info.vendor.c_str(), info.model.c_str(),
              info.serial.c_str(), info.sensor_width, info.sensor_height, Formats(info).c_str());
}

}  // namespace

int RunDevices(int argc, char** argv) {
  CLI::App app{"List the cameras (and displays) slshadow can capture with.\n\n"
               "Without options: USB3 Vision cameras (local USB enumeration; nothing is sent on any\n"
               "network). GigE Vision cameras are found only when asked: --address opens one camera at\n"
               "its IP address (GVCP to that address only); --discover broadcasts a GigE Vision discovery\n"
               "on every network interface and opens each camera that answers.",
               argv[0]};
  std::vector<std::string> addresses;
  bool discover = false;
  app.add_option("--address", addresses, "IPv4 address of a GigE Vision camera (repeatable)");
  app.add_flag("--discover", discover, "broadcast a GigE Vision discovery on every network interface");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  for (const auto& address : addresses) {
    SLSHADOW_THROW_IF(!capture::IsIpv4Address(address), "--address: '", address,
                      "' is not an IPv4 address (e.g. 192.168.1.20)");
  }

  // Cameras opened by address: full information, or the error naming the address.
  for (const auto& address : addresses) {
    const auto camera = capture::OpenAravisCamera({.device = address});
    PrintCamera(camera->Info(), "GigEVision", address);
  }
  if (addresses.empty()) {
    // Listed devices: each opened for its sensor and formats; one that cannot be opened (e.g. in
    // use by another program) is still listed, with the reason.
    for (const auto& entry : capture::ListAravisDevices(discover)) {
      const std::string open_by = entry.protocol == "GigEVision" ? entry.address : entry.id;
      try {
        const auto camera = capture::OpenAravisCamera({.device = open_by});
        PrintCamera(camera->Info(), entry.protocol, entry.address);
      } catch (const Error& e) {
        std::printf("camera  %-10s %-16s vendor=%s model=%s serial=%s (cannot open: %s)\n",
                    entry.protocol.c_str(), entry.address.c_str(), entry.vendor.c_str(),
                    entry.model.c_str(), entry.serial.c_str(), e.what());
      }
    }
    if (!discover) {
      std::printf("(GigE Vision cameras: --address IP opens one; --discover broadcasts to find them)\n");
    }
    // UVC cameras (V4L2 nodes; metadata nodes say why they cannot capture) and LightCrafters on USB.
    for (const auto& node : capture::ListV4l2Nodes()) {
      try {
        PrintCamera(capture::V4l2Camera(node).Info(), "V4L2", node);
      } catch (const Error& e) {
        std::printf("camera  %-10s %-16s (cannot capture: %s)\n", "V4L2", node.c_str(), e.what());
      }
    }
    try {
      for (const auto& usb : capture::ListLightCrafters()) {
        std::printf("projector LightCrafter 4500 on USB %s (devices.yaml projector: backend lightcrafter; "
                    "`slshadow projector info`)\n", usb.c_str());
      }
    } catch (const Error& e) {
      std::printf("(USB projectors: cannot list: %s)\n", e.what());
    }
  }
  // Displays (HDMI projector windows): listed here by the window projector backend.
  if (std::getenv("DISPLAY") == nullptr) {
    std::printf("(displays: $DISPLAY is not set, no X display to list)\n");
  } else {
    for (const auto& d : capture::ListDisplays()) {
      std::printf("display %-2d %-14s at %d,%d,%d,%d %.0f Hz (devices.yaml projector: backend window, display %d)\n",
                  d.index, d.name.c_str(), d.bounds.x, d.bounds.y, d.bounds.width, d.bounds.height, d.refresh_hz,
                  d.index);
    }
  }
  return 0;
}

}  // namespace slshadow::app
