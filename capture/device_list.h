// What `slshadow devices` lists: the cameras and projectors slshadow can capture with, and the X
// displays a window projector can use, one line per device.
#pragma once

#include <functional>
#include <string>
#include <vector>

namespace slshadow::capture {

struct DeviceListOptions {
  // GigE Vision cameras opened at these IPv4 addresses (GVCP to each address only); when given,
  // nothing else is enumerated but the displays.
  std::vector<std::string> addresses;
  // Broadcast a GigE Vision discovery on every network interface (else only USB3 Vision cameras
  // are enumerated, nothing is sent on any network).
  bool discover = false;
  // Throws slshadow::Error naming an address that is not an IPv4 address.
  void Check() const;
};

// The listing, handed to `print` one line per device as it is found (each ending in '\n'): "camera
// <protocol> <address> vendor=... model=... serial=... sensor=WxH formats=..." (or why it cannot be
// opened), V4L2 nodes, USB LightCrafters, "display <index> ..." per X display, and notes in
// parentheses for what was not looked for. Throws slshadow::Error when a camera given by address
// cannot be opened.
void ListDevices(const DeviceListOptions& options,
                 const std::function<void(const std::string& line)>& print);

}  // namespace slshadow::capture
