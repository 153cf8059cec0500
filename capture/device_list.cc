#include "capture/device_list.h"

#include <cstdio>
#include <cstdlib>
#include <functional>
#include <vector>

#include "capture/aravis_camera.h"
#include "capture/lightcrafter_usb.h"
#include "capture/v4l2_camera.h"
#include "capture/window_projector.h"
#include "core/error.h"
#include "core/string_printf.h"

namespace slshadow::capture {
namespace {

std::string Formats(const CameraInfo& info) {
  std::string out;
  for (auto f : info.pixel_formats) {
    if (!out.empty()) out += ",";
    out += ToString(f);
  }
  return out.empty() ? "none of Mono8/Mono12/Mono16" : out;
}

// printf to the sink, any length.
using Sink = std::function<void(const std::string&)>;

template <typename... Args>
void Append(const Sink* out, const char* format, Args... args) {
  (*out)(StringPrintf(format, args...));
}

void AppendCamera(const Sink* out, const CameraInfo& info, const std::string& protocol,
                  const std::string& address) {
  Append(out, "camera  %-10s %-16s vendor=%s model=%s serial=%s sensor=%dx%d formats=%s\n",
         protocol.c_str(), address.c_str(), info.vendor.c_str(), info.model.c_str(),
         info.serial.c_str(), info.sensor_width, info.sensor_height, Formats(info).c_str());
}

}  // namespace

void DeviceListOptions::Check() const {
  for (const auto& address : addresses) {
    SLSHADOW_THROW_IF(!IsIpv4Address(address), "--address: '", address,
                      "' is not an IPv4 address (e.g. 192.168.1.20)");
  }
}

void ListDevices(const DeviceListOptions& options,
                 const std::function<void(const std::string& line)>& print) {
  options.Check();
  const Sink* out = &print;
  // Cameras opened by address: full information, or the error naming the address.
  for (const auto& address : options.addresses) {
    const auto camera = OpenAravisCamera({.device = address});
    AppendCamera(out, camera->Info(), "GigEVision", address);
  }
  if (options.addresses.empty()) {
    // Listed devices: each opened for its sensor and formats; one that cannot be opened (e.g. in
    // use by another program) is still listed, with the reason.
    for (const auto& entry : ListAravisDevices(options.discover)) {
      const std::string open_by = entry.protocol == "GigEVision" ? entry.address : entry.id;
      try {
        const auto camera = OpenAravisCamera({.device = open_by});
        AppendCamera(out, camera->Info(), entry.protocol, entry.address);
      } catch (const Error& e) {
        Append(out, "camera  %-10s %-16s vendor=%s model=%s serial=%s (cannot open: %s)\n",
               entry.protocol.c_str(), entry.address.c_str(), entry.vendor.c_str(),
               entry.model.c_str(), entry.serial.c_str(), e.what());
      }
    }
    if (!options.discover)
      print("(GigE Vision cameras: --address IP opens one; --discover broadcasts to find them)\n");
    // UVC cameras (V4L2 nodes; metadata nodes say why they cannot capture) and LightCrafters on
    // USB.
    for (const auto& node : ListV4l2Nodes()) {
      try {
        AppendCamera(out, V4l2Camera(node).Info(), "V4L2", node);
      } catch (const Error& e) {
        Append(out, "camera  %-10s %-16s (cannot capture: %s)\n", "V4L2", node.c_str(), e.what());
      }
    }
    try {
      for (const auto& usb : ListLightCrafters()) {
        Append(
            out,
            "projector LightCrafter 4500 on USB %s (devices.yaml projector: backend lightcrafter; "
            "`slshadow projector info`)\n",
            usb.c_str());
      }
    } catch (const Error& e) {
      Append(out, "(USB projectors: cannot list: %s)\n", e.what());
    }
  }
  // Displays (HDMI projector windows): listed by the window projector backend.
  if (std::getenv("DISPLAY") == nullptr) {
    print("(displays: $DISPLAY is not set, no X display to list)\n");
  } else {
    for (const auto& d : ListDisplays()) {
      Append(out,
             "display %-2d %-14s at %d,%d,%d,%d %.0f Hz (devices.yaml projector: backend window, "
             "display %d)\n",
             d.index, d.name.c_str(), d.bounds.x, d.bounds.y, d.bounds.width, d.bounds.height,
             d.refresh_hz, d.index);
    }
  }
}

}  // namespace slshadow::capture
