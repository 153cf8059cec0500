// The USB HID transport of a TI DLP LightCrafter 4500 (DLPC350, USB 0451:6401) through
// libusb-1.0: interface 0 claimed (the kernel's usbhid driver detached while we hold it),
// 64-byte interrupt reports on endpoints 0x01 OUT / 0x81 IN, per-report timeouts. libusb stays in
// the .cc file. Tested against an in-process umockdev usbdevfs emulator
// (tests/capture/lightcrafter_usb_test.cc).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "capture/lightcrafter_protocol.h"

namespace slshadow::capture {

inline constexpr uint16_t kLightCrafterVendor = 0x0451;
inline constexpr uint16_t kLightCrafterProduct = 0x6401;

// "BUS:ADDRESS" of every LightCrafter 4500 on the USB buses (e.g. "1:7"); empty when none.
std::vector<std::string> ListLightCrafters();

// Opens the LightCrafter at `bus_address` ("BUS:ADDRESS"), or the only one when empty. Throws
// slshadow::Error naming the device when none / several match or it cannot be opened or claimed.
std::unique_ptr<dlpc350::Transport> OpenLightCrafterUsb(const std::string& bus_address);

}  // namespace slshadow::capture
