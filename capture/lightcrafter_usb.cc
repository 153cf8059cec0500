#include "capture/lightcrafter_usb.h"

#include <libusb.h>

#include "core/error.h"

namespace slshadow::capture {
namespace {

constexpr unsigned char kEndpointOut = 0x01;
constexpr unsigned char kEndpointIn = 0x81;
constexpr int kInterface = 0;

std::string UsbError(int code) {
  return std::string(libusb_error_name(code)) + " (" + libusb_strerror(code) + ")";
}

struct Context {
  libusb_context* ctx = nullptr;
  Context() {
    const int rc = libusb_init(&ctx);
    SLSHADOW_THROW_IF(rc != 0, "LightCrafter over USB: libusb_init failed: ", UsbError(rc));
  }
  ~Context() { libusb_exit(ctx); }
  Context(const Context&) = delete;
  Context& operator=(const Context&) = delete;
};

std::string BusAddress(libusb_device* dev) {
  return std::to_string(libusb_get_bus_number(dev)) + ":" +
         std::to_string(libusb_get_device_address(dev));
}

// Calls f(device, "bus:address") for every 0451:6401.
template <typename F>
void ForEachLightCrafter(libusb_context* ctx, F f) {
  libusb_device** list = nullptr;
  const ssize_t n = libusb_get_device_list(ctx, &list);
  SLSHADOW_THROW_IF(
      n < 0, "LightCrafter over USB: cannot list USB devices: ", UsbError(static_cast<int>(n)));
  for (ssize_t i = 0; i < n; ++i) {
    libusb_device_descriptor d{};
    if (libusb_get_device_descriptor(list[i], &d) != 0) continue;
    if (d.idVendor == kLightCrafterVendor && d.idProduct == kLightCrafterProduct)
      f(list[i], BusAddress(list[i]));
  }
  libusb_free_device_list(list, 1);
}

class UsbTransport : public dlpc350::Transport {
 public:
  explicit UsbTransport(const std::string& bus_address) {
    libusb_device* chosen = nullptr;
    std::vector<std::string> found;
    ForEachLightCrafter(context_.ctx, [&](libusb_device* dev, const std::string& where) {
      found.push_back(where);
      if (bus_address.empty() || bus_address == where) {
        if (chosen) libusb_unref_device(chosen);
        chosen = libusb_ref_device(dev);
      }
    });
    std::string all;
    for (const auto& f : found) all += (all.empty() ? "" : ", ") + f;
    if (bus_address.empty() && found.size() > 1) {
      libusb_unref_device(chosen);
      SLSHADOW_THROW("LightCrafter over USB: ", found.size(), " LightCrafters found (", all,
                     "): name one with its BUS:ADDRESS");
    }
    SLSHADOW_THROW_IF(chosen == nullptr,
                      "LightCrafter over USB: no LightCrafter 4500 (USB 0451:6401)",
                      bus_address.empty() ? std::string() : " at " + bus_address,
                      " (found: ", all.empty() ? "none" : all, ")");
    describe_ = "LightCrafter 4500 on USB " + BusAddress(chosen);
    const int rc = libusb_open(chosen, &handle_);
    libusb_unref_device(chosen);
    SLSHADOW_THROW_IF(
        rc != 0, describe_, ": cannot open: ", UsbError(rc),
        rc == LIBUSB_ERROR_ACCESS ? " (a udev rule granting access to 0451:6401 is needed)" : "");
    libusb_set_auto_detach_kernel_driver(handle_, 1);  // not supported everywhere; claim tells
    const int claim = libusb_claim_interface(handle_, kInterface);
    if (claim != 0) {
      libusb_close(handle_);
      SLSHADOW_THROW(describe_, ": cannot claim HID interface 0: ", UsbError(claim),
                     " (another program holds it?)");
    }
  }
  ~UsbTransport() override {
    libusb_release_interface(handle_, kInterface);
    libusb_close(handle_);
  }

  bool Write(const dlpc350::Report& report, std::chrono::milliseconds timeout) override {
    dlpc350::Report copy = report;
    return Transfer(kEndpointOut, copy.data(), timeout, "write");
  }
  bool Read(dlpc350::Report* report, std::chrono::milliseconds timeout) override {
    report->fill(0);
    return Transfer(kEndpointIn, report->data(), timeout, "read");
  }
  std::string Describe() const override { return describe_; }

 private:
  bool Transfer(unsigned char endpoint, unsigned char* data, std::chrono::milliseconds timeout,
                const char* what) {
    int done = 0;
    const int rc = libusb_interrupt_transfer(
        handle_, endpoint, data, static_cast<int>(dlpc350::kReportSize), &done,
        static_cast<unsigned>(std::max<int64_t>(1, timeout.count())));
    if (rc == LIBUSB_ERROR_TIMEOUT) return false;
    SLSHADOW_THROW_IF(rc == LIBUSB_ERROR_NO_DEVICE, describe_, ": the device was unplugged (", what,
                      " failed)");
    SLSHADOW_THROW_IF(rc != 0, describe_, ": interrupt ", what, " failed: ", UsbError(rc));
    SLSHADOW_THROW_IF(static_cast<size_t>(done) != dlpc350::kReportSize, describe_, ": interrupt ",
                      what, " moved ", done, " bytes, expected ", dlpc350::kReportSize);
    return true;
  }

  Context context_;
  libusb_device_handle* handle_ = nullptr;
  std::string describe_;
};

}  // namespace

std::vector<std::string> ListLightCrafters() {
  Context context;
  std::vector<std::string> out;
  ForEachLightCrafter(context.ctx,
                      [&](libusb_device*, const std::string& where) { out.push_back(where); });
  return out;
}

std::unique_ptr<dlpc350::Transport> OpenLightCrafterUsb(const std::string& bus_address) {
  return std::make_unique<UsbTransport>(bus_address);
}

}  // namespace slshadow::capture
