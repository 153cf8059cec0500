// The libusb transport of the LightCrafter against an in-process USB device emulated with umockdev:
// a usbdevfs node for 0451:6401 (HID interface 0, interrupt endpoints 0x81 / 0x01, 64 bytes)
// whose ioctls (SUBMITURB, REAPURB(NDELAY), DISCARDURB, CLAIMINTERFACE, GET_CAPABILITIES, ...)
// are answered by a Dlpc350Emulator. libusb is the real library, enumerating the umockdev sysfs.
// Proves: enumeration and claim, byte-exact reports through libusb (single and multi report),
// replies parsed, NACK, a device that never answers (libusb timeout, URB discarded and reaped),
// and an unplugged device, each a clear error. Must run under `umockdev-wrapper` (CTest does).
#include "capture/lightcrafter_usb.h"

#include <cerrno>
#include <chrono>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <functional>
#include <mutex>

#include <gtest/gtest.h>
#include <linux/ioctl.h>
#include <linux/usbdevice_fs.h>
#include <umockdev.h>

#include "core/error.h"
#include "tests/capture/dlpc350_emulator.h"
#include "tests/testing/run_cli.h"

namespace slshadow::capture {
namespace {
using dlpc350::Report;

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

bool UnderUmockdev() {
  const char* preload = std::getenv("LD_PRELOAD");
  return preload != nullptr && std::strstr(preload, "umockdev") != nullptr;
}

// Device, configuration, interface (HID), HID, endpoint 0x81 IN, endpoint 0x01 OUT descriptors.
constexpr const char* kDescriptors =
    "120100020000004051040164000101020001"
    "0902290001010080" "32"
    "090400000203000000"
    "092111010001221d00"
    "0705810340000a"
    "0705010340000a";

class UsbEmulator {
 public:
  UsbEmulator() {
    testbed_ = umockdev_testbed_new();
    handler_ = umockdev_ioctl_base_new();
    g_signal_connect_after(handler_, "handle-ioctl", G_CALLBACK(&UsbEmulator::OnIoctl), this);
    GError* error = nullptr;
    if (!umockdev_testbed_attach_ioctl(testbed_, "/dev/bus/usb/001/002", handler_, &error)) {
      ADD_FAILURE() << "attach_ioctl: " << (error ? error->message : "?");
      if (error) g_error_free(error);
    }
    const std::string device = std::string(
        "P: /devices/usb1/1-1\nN: bus/usb/001/002\nE: SUBSYSTEM=usb\nE: DRIVER=usb\nE: BUSNUM=001\nE: DEVNUM=002\n"
        "E: DEVNAME=/dev/bus/usb/001/002\nE: DEVTYPE=usb_device\nE: PRODUCT=451/6401/100\n"
        "A: bConfigurationValue=1\\n\nA: busnum=1\\n\nA: devnum=2\\n\nA: speed=12\\n\n"
        "A: idVendor=0451\\n\nA: idProduct=6401\\n\nH: descriptors=") + kDescriptors + "\n";
    if (!umockdev_testbed_add_from_string(testbed_, device.c_str(), &error)) {
      ADD_FAILURE() << "add_from_string: " << (error ? error->message : "?");
      if (error) g_error_free(error);
    }
  }
  ~UsbEmulator() {
    for (auto* d : in_flight_) umockdev_ioctl_data_unref(d);
    for (auto* d : done_) umockdev_ioctl_data_unref(d);
    for (auto* d : discarded_) umockdev_ioctl_data_unref(d);
    g_object_unref(handler_);
    g_object_unref(testbed_);
  }

  // Test-thread access to the emulated device.
  template <typename F>
  auto With(F f) {
    std::lock_guard lock(mutex_);
    return f(device_);
  }
  void Unplug() {
    std::lock_guard lock(mutex_);
    unplugged_ = true;
  }
  std::vector<unsigned long> unknown_ioctls() {
    std::lock_guard lock(mutex_);
    return unknown_;
  }

 private:
  static gboolean OnIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, gpointer self) {
    return static_cast<UsbEmulator*>(self)->Handle(client);
  }

  gboolean Handle(UMockdevIoctlClient* client) {
    std::lock_guard lock(mutex_);
    const unsigned long request = umockdev_ioctl_client_get_request(client);
    UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
    switch (request) {
      case USBDEVFS_GET_CAPABILITIES: {
        UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(guint32), nullptr);
        *reinterpret_cast<guint32*>(d->data) = USBDEVFS_CAP_ZERO_PACKET | USBDEVFS_CAP_NO_PACKET_SIZE_LIM;
        umockdev_ioctl_data_unref(d);
        umockdev_ioctl_client_complete(client, 0, 0);
        return TRUE;
      }
      case USBDEVFS_CLAIMINTERFACE:
      case USBDEVFS_RELEASEINTERFACE:
      case USBDEVFS_DISCONNECT_CLAIM:
      case USBDEVFS_CLEAR_HALT:
      case USBDEVFS_RESET:
        umockdev_ioctl_client_complete(client, 0, 0);
        return TRUE;
      case USBDEVFS_GETDRIVER:
        umockdev_ioctl_client_complete(client, -1, ENODATA);
        return TRUE;
      case USBDEVFS_SUBMITURB: {
        if (unplugged_) {
          umockdev_ioctl_client_complete(client, -1, ENODEV);
          return TRUE;
        }
        UMockdevIoctlData* urb_data = umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
        auto* urb = reinterpret_cast<usbdevfs_urb*>(urb_data->data);
        UMockdevIoctlData* buffer =
            umockdev_ioctl_data_resolve(urb_data, G_STRUCT_OFFSET(usbdevfs_urb, buffer), urb->buffer_length, nullptr);
        if (urb->type != USBDEVFS_URB_TYPE_INTERRUPT || urb->buffer_length != 64 ||
            (urb->endpoint != 0x01 && urb->endpoint != 0x81)) {
          umockdev_ioctl_data_unref(buffer);
          umockdev_ioctl_data_unref(urb_data);
          umockdev_ioctl_client_complete(client, -1, EINVAL);
          return TRUE;
        }
        if (urb->endpoint == 0x01) {
          Report report{};
          std::memcpy(report.data(), buffer->data, 64);
          device_.Receive(report);
          urb->actual_length = 64;
          urb->status = 0;
          done_.push_back(urb_data);
        } else {
          in_flight_.push_back(urb_data);
        }
        umockdev_ioctl_data_unref(buffer);
        umockdev_ioctl_client_complete(client, 0, 0);
        return TRUE;
      }
      case USBDEVFS_REAPURB:
      case USBDEVFS_REAPURBNDELAY: {
        UMockdevIoctlData* urb_data = nullptr;
        if (!discarded_.empty()) {
          urb_data = discarded_.front();
          discarded_.pop_front();
          reinterpret_cast<usbdevfs_urb*>(urb_data->data)->status = -ENOENT;
        } else if (!done_.empty()) {
          urb_data = done_.front();
          done_.pop_front();
        } else if (!in_flight_.empty()) {
          Report reply{};
          if (device_.PopReply(&reply)) {
            urb_data = in_flight_.front();
            in_flight_.pop_front();
            auto* urb = reinterpret_cast<usbdevfs_urb*>(urb_data->data);
            std::memcpy(urb->buffer, reply.data(), 64);
            urb->actual_length = 64;
            urb->status = 0;
          }
        }
        if (urb_data == nullptr) {
          umockdev_ioctl_client_complete(client, -1, unplugged_ ? ENODEV : EAGAIN);
          return TRUE;
        }
        UMockdevIoctlData* ptr = umockdev_ioctl_data_resolve(arg, 0, sizeof(gpointer), nullptr);
        umockdev_ioctl_data_set_ptr(ptr, 0, urb_data);
        umockdev_ioctl_data_unref(ptr);
        umockdev_ioctl_data_unref(urb_data);
        umockdev_ioctl_client_complete(client, 0, 0);
        return TRUE;
      }
      case USBDEVFS_DISCARDURB: {
        const gulong addr = reinterpret_cast<gulong>(*reinterpret_cast<void**>(arg->data));
        for (auto it = in_flight_.begin(); it != in_flight_.end(); ++it) {
          if ((*it)->client_addr == addr) {
            discarded_.push_back(*it);
            in_flight_.erase(it);
            umockdev_ioctl_client_complete(client, 0, 0);
            return TRUE;
          }
        }
        umockdev_ioctl_client_complete(client, -1, EINVAL);
        return TRUE;
      }
      default:
        unknown_.push_back(request);
        return FALSE;
    }
  }

  UMockdevTestbed* testbed_ = nullptr;
  UMockdevIoctlBase* handler_ = nullptr;
  std::mutex mutex_;
  testing::Dlpc350Emulator device_;
  bool unplugged_ = false;
  std::deque<UMockdevIoctlData*> in_flight_, done_, discarded_;
  std::vector<unsigned long> unknown_;
};

class LightCrafterUsb : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!UnderUmockdev()) GTEST_SKIP() << "needs umockdev-wrapper (LD_PRELOAD of libumockdev-preload)";
    emulator_ = std::make_unique<UsbEmulator>();
  }
  std::unique_ptr<UsbEmulator> emulator_;
};

TEST_F(LightCrafterUsb, EnumeratesOpensAndSpeaksTheProtocolByteExact) {
  EXPECT_EQ(ListLightCrafters(), (std::vector<std::string>{"1:2"}));
  auto transport = OpenLightCrafterUsb("");
  EXPECT_EQ(transport->Describe(), "LightCrafter 4500 on USB 1:2");
  dlpc350::Client client(*transport);
  client.SetDisplayMode(dlpc350::DisplayMode::kPatternSequence);
  EXPECT_EQ(client.GetDisplayMode(), dlpc350::DisplayMode::kPatternSequence);
  client.SetExposure(16667, 16667);
  std::vector<dlpc350::PatternEntry> entries(40);
  for (int i = 0; i < 40; ++i) entries[i] = {dlpc350::EntryTrigger::kInternal, i % 24, 1, dlpc350::kLedWhite};
  client.WritePatternLut(entries);
  emulator_->With([&](testing::Dlpc350Emulator& d) {
    ASSERT_EQ(d.log.size(), 7u);
    // The exact bytes that crossed usbdevfs (LIGHTCRAFTER.md worked examples).
    const uint8_t mode[] = {0x40, 0x01, 0x03, 0x00, 0x1B, 0x1A, 0x01};
    EXPECT_TRUE(std::equal(std::begin(mode), std::end(mode), d.log[0].reports[0].begin()));
    EXPECT_TRUE(std::all_of(d.log[0].reports[0].begin() + 7, d.log[0].reports[0].end(), [](uint8_t v) { return v == 0; }));
    const uint8_t read[] = {0xC0, 0x00, 0x02, 0x00, 0x1B, 0x1A};
    EXPECT_TRUE(std::equal(std::begin(read), std::end(read), d.log[1].reports[0].begin()));
    const uint8_t exposure[] = {0x40, 0x02, 0x0A, 0x00, 0x29, 0x1A, 0x1B, 0x41, 0x00, 0x00, 0x1B, 0x41, 0x00, 0x00};
    EXPECT_TRUE(std::equal(std::begin(exposure), std::end(exposure), d.log[2].reports[0].begin()));
    EXPECT_EQ(d.log[5].reports.size(), 2u);  // 122-byte mailbox data in two reports
    EXPECT_EQ(d.pattern_lut.size(), 120u);
    EXPECT_EQ(d.display_mode, 1);
  });
  EXPECT_TRUE(emulator_->unknown_ioctls().empty());
}

TEST_F(LightCrafterUsb, VersionNackTimeoutAndUnplug) {
  auto transport = OpenLightCrafterUsb("1:2");
  dlpc350::Client client(*transport, dlpc350::ClientOptions{std::chrono::milliseconds(200)});
  emulator_->With([](testing::Dlpc350Emulator& d) { d.version = {2, 0, 1, 3, 0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 1}; });
  EXPECT_EQ(client.GetVersion().ToString(), "application 3.1.2, API 2.0.0, software config 1.0.0, sequence config 1.0.0");
  emulator_->With([](testing::Dlpc350Emulator& d) { d.nack_command = dlpc350::kPatternConfig; });
  EXPECT_NE(ErrorOf([&] { client.SetPatternConfig(3, true, 3, 1); })
                .find("LightCrafter 4500 on USB 1:2: pattern configuration (0x1A31) with data [02 01 02 00]: the device refused it (NACK"),
            std::string::npos);
  // A device that never answers: libusb times out, discards the URB, and the client says so.
  emulator_->With([](testing::Dlpc350Emulator& d) {
    d.nack_command = 0;
    d.silent = true;
  });
  EXPECT_NE(ErrorOf([&] { client.SetDisplayMode(dlpc350::DisplayMode::kVideo); }).find("no acknowledgement within 200 ms"),
            std::string::npos);
  // It answers again: the link still works after the discarded URB.
  emulator_->With([](testing::Dlpc350Emulator& d) { d.silent = false; });
  client.SetDisplayMode(dlpc350::DisplayMode::kVideo);
  emulator_->Unplug();
  EXPECT_NE(ErrorOf([&] { client.SetSequence(dlpc350::SequenceControl::kStart); }).find("the device was unplugged"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] { OpenLightCrafterUsb("3:9"); }).find("no LightCrafter 4500 (USB 0451:6401) at 3:9 (found: 1:2)"),
            std::string::npos);
}

// `slshadow projector info|mode|validate` against the emulated device, in-process.
TEST_F(LightCrafterUsb, ProjectorCommand) {
  auto run = [](std::vector<std::string> args, std::string* out, std::string* err) {
    ::testing::internal::CaptureStdout();
    ::testing::internal::CaptureStderr();
    const int code = ::slshadow::testing::RunCli(std::move(args));
    std::fflush(stdout);
    *out = ::testing::internal::GetCapturedStdout();
    *err = ::testing::internal::GetCapturedStderr();
    return code;
  };
  std::string out, err;
  emulator_->With([](testing::Dlpc350Emulator& d) { d.version = {2, 0, 1, 3, 0, 0, 0, 2, 0, 0, 0, 1, 0, 0, 0, 1}; });
  ASSERT_EQ(run({"projector", "info"}, &out, &err), 0) << err;
  EXPECT_NE(out.find("LightCrafter 4500 on USB 1:2\nfirmware: application 3.1.2, API 2.0.0"), std::string::npos) << out;
  EXPECT_NE(out.find("display mode: video"), std::string::npos) << out;
  ASSERT_EQ(run({"projector", "--usb", "1:2", "mode", "pattern"}, &out, &err), 0) << err;
  EXPECT_NE(out.find("display mode pattern"), std::string::npos) << out;
  EXPECT_EQ(emulator_->With([](testing::Dlpc350Emulator& d) { return int(d.display_mode); }), 1);
  emulator_->With([](testing::Dlpc350Emulator& d) {
    d.busy_polls = 2;
    d.validation_status = 0x12;
  });
  EXPECT_EQ(run({"projector", "validate"}, &out, &err), 1);
  EXPECT_NE(out.find("validation status 0x12: INVALID"), std::string::npos) << out;
  EXPECT_NE(out.find("error   bit 1: pattern numbers invalid"), std::string::npos) << out;
  EXPECT_NE(out.find("error   bit 4: frame period - exposure below 230 us"), std::string::npos) << out;
  EXPECT_NE(run({"projector", "--usb", "2:5", "info"}, &out, &err), 0);
  EXPECT_NE(err.find("no LightCrafter 4500 (USB 0451:6401) at 2:5 (found: 1:2)"), std::string::npos) << err;
}

// Round trips through libusb and usbdevfs (printed for docs/benchmarks.md; asserted only for
// correctness: every request acknowledged and logged in order).
TEST_F(LightCrafterUsb, RoundTrips) {
  auto transport = OpenLightCrafterUsb("");
  dlpc350::Client client(*transport);
  constexpr int kN = 300;
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < kN; ++i) client.GetDisplayMode();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::printf("[ MEASURE  ] %d read round trips: %.1f requests/s, %.3f ms per round trip\n", kN, kN / seconds,
              1e3 * seconds / kN);
  EXPECT_EQ(emulator_->With([](testing::Dlpc350Emulator& d) { return d.log.size(); }), static_cast<size_t>(kN));
}

}  // namespace
}  // namespace slshadow::capture
