#include "tests/capture/usb_lightcrafter_emulator.h"

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <string>

#include <gtest/gtest.h>
#include <linux/ioctl.h>
#include <linux/usbdevice_fs.h>
#include <umockdev.h>

namespace slshadow::capture::testing {
namespace {
using dlpc350::Report;

// Device, configuration, interface (HID), HID, endpoint 0x81 IN, endpoint 0x01 OUT descriptors.
constexpr const char* kDescriptors =
    "120100020000004051040164000101020001"
    "0902290001010080"
    "32"
    "090400000203000000"
    "092111010001221d00"
    "0705810340000a"
    "0705010340000a";

}  // namespace

bool UnderUmockdev() {
  const char* preload = std::getenv("LD_PRELOAD");
  return preload != nullptr && std::strstr(preload, "umockdev") != nullptr;
}

UsbLightCrafterEmulator::UsbLightCrafterEmulator() {
  testbed_ = umockdev_testbed_new();
  handler_ = umockdev_ioctl_base_new();
  g_signal_connect_after(handler_, "handle-ioctl", G_CALLBACK(&UsbLightCrafterEmulator::OnIoctl),
                         this);
  GError* error = nullptr;
  if (!umockdev_testbed_attach_ioctl(testbed_, "/dev/bus/usb/001/002", handler_, &error)) {
    ADD_FAILURE() << "attach_ioctl: " << (error ? error->message : "?");
    if (error) g_error_free(error);
  }
  const std::string device =
      std::string(
          "P: /devices/usb1/1-1\nN: bus/usb/001/002\nE: SUBSYSTEM=usb\nE: DRIVER=usb\nE: "
          "BUSNUM=001\nE: DEVNUM=002\n"
          "E: DEVNAME=/dev/bus/usb/001/002\nE: DEVTYPE=usb_device\nE: PRODUCT=451/6401/100\n"
          "A: bConfigurationValue=1\\n\nA: busnum=1\\n\nA: devnum=2\\n\nA: speed=12\\n\n"
          "A: idVendor=0451\\n\nA: idProduct=6401\\n\nH: descriptors=") +
      kDescriptors + "\n";
  if (!umockdev_testbed_add_from_string(testbed_, device.c_str(), &error)) {
    ADD_FAILURE() << "add_from_string: " << (error ? error->message : "?");
    if (error) g_error_free(error);
  }
}

UsbLightCrafterEmulator::~UsbLightCrafterEmulator() {
  for (auto* d : in_flight_) umockdev_ioctl_data_unref(d);
  for (auto* d : done_) umockdev_ioctl_data_unref(d);
  for (auto* d : discarded_) umockdev_ioctl_data_unref(d);
  g_object_unref(handler_);
  g_object_unref(testbed_);
}

void UsbLightCrafterEmulator::Unplug() {
  std::lock_guard lock(mutex_);
  unplugged_ = true;
}

void UsbLightCrafterEmulator::Replug() {
  std::lock_guard lock(mutex_);
  unplugged_ = false;
}

std::vector<unsigned long> UsbLightCrafterEmulator::unknown_ioctls() {
  std::lock_guard lock(mutex_);
  return unknown_;
}

int UsbLightCrafterEmulator::OnIoctl(UMockdevIoctlBase*, UMockdevIoctlClient* client, void* self) {
  return static_cast<UsbLightCrafterEmulator*>(self)->Handle(client);
}

int UsbLightCrafterEmulator::Handle(UMockdevIoctlClient* client) {
  std::lock_guard lock(mutex_);
  const unsigned long request = umockdev_ioctl_client_get_request(client);
  UMockdevIoctlData* arg = umockdev_ioctl_client_get_arg(client);
  switch (request) {
    case USBDEVFS_GET_CAPABILITIES: {
      UMockdevIoctlData* d = umockdev_ioctl_data_resolve(arg, 0, sizeof(guint32), nullptr);
      *reinterpret_cast<guint32*>(d->data) =
          USBDEVFS_CAP_ZERO_PACKET | USBDEVFS_CAP_NO_PACKET_SIZE_LIM;
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
      UMockdevIoctlData* urb_data =
          umockdev_ioctl_data_resolve(arg, 0, sizeof(usbdevfs_urb), nullptr);
      auto* urb = reinterpret_cast<usbdevfs_urb*>(urb_data->data);
      UMockdevIoctlData* buffer = umockdev_ioctl_data_resolve(
          urb_data, G_STRUCT_OFFSET(usbdevfs_urb, buffer), urb->buffer_length, nullptr);
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

}  // namespace slshadow::capture::testing
