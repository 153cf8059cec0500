// An emulated TI DLP LightCrafter 4500 on USB for tests, through umockdev: a usbdevfs node for
// 0451:6401 (HID interface 0, interrupt endpoints 0x81 / 0x01, 64 bytes) in a umockdev testbed,
// whose ioctls (SUBMITURB, REAPURB(NDELAY), DISCARDURB, CLAIMINTERFACE, GET_CAPABILITIES, ...)
// are answered by a Dlpc350Emulator. libusb is the real library, enumerating the umockdev sysfs
// as bus 1, address 2. The test binary must run under `umockdev-wrapper` (UnderUmockdev()).
#pragma once

#include <deque>
#include <mutex>
#include <vector>

#include "tests/capture/dlpc350_emulator.h"

typedef struct _UMockdevTestbed UMockdevTestbed;
typedef struct _UMockdevIoctlBase UMockdevIoctlBase;
typedef struct _UMockdevIoctlClient UMockdevIoctlClient;
typedef struct _UMockdevIoctlData UMockdevIoctlData;

namespace slshadow::capture::testing {

// True when libumockdev-preload is in LD_PRELOAD (umockdev_in_mock_environment() is unreliable).
bool UnderUmockdev();

class UsbLightCrafterEmulator {
 public:
  UsbLightCrafterEmulator();
  ~UsbLightCrafterEmulator();
  UsbLightCrafterEmulator(const UsbLightCrafterEmulator&) = delete;
  UsbLightCrafterEmulator& operator=(const UsbLightCrafterEmulator&) = delete;

  // Test-thread access to the emulated device (under the lock the ioctl handler takes).
  template <typename F>
  auto With(F f) {
    std::lock_guard lock(mutex_);
    return f(device_);
  }
  // The device disappears: every later transfer fails with ENODEV. Replug brings it back (the
  // host must open it again, as after a real replug).
  void Unplug();
  void Replug();
  std::vector<unsigned long> unknown_ioctls();

 private:
  static int OnIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, void* self);
  int Handle(UMockdevIoctlClient* client);

  UMockdevTestbed* testbed_ = nullptr;
  UMockdevIoctlBase* handler_ = nullptr;
  std::mutex mutex_;
  Dlpc350Emulator device_;
  bool unplugged_ = false;
  std::deque<UMockdevIoctlData*> in_flight_, done_, discarded_;
  std::vector<unsigned long> unknown_;
};

}  // namespace slshadow::capture::testing
