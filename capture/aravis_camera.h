// The Aravis backend of capture::Camera: GigE Vision and USB3 Vision cameras through Aravis 0.8.
// Aravis, GLib and GObject types stay in aravis_camera.cc; this header speaks the project's types.
//
// Opening never broadcasts unless asked to:
//  - an IPv4 address ("192.168.1.20", "127.0.0.2") opens that GigE Vision device directly (GVCP
//    unicast to the address; Aravis's GigE Vision interface picks the local interface on the
//    camera's subnet, no discovery packet is sent);
//  - any other string, a serial number or an Aravis device id ("vendor-model-serial", e.g.
//    "Aravis-Fake-GV01"), is matched against the USB3 Vision devices (local USB enumeration), and
//    against the GigE Vision devices only when AravisOpenOptions::allow_discovery is set, because
//    GigE Vision discovery broadcasts GVCP on every network interface. It is never resolved as a
//    host name (no DNS query).
//
// Feature names: the SFNC names real cameras use (`ExposureTime` in µs, `Gain` in dB) are
// preferred; the older names are the fallback (`ExposureTimeAbs`; `GainAbs` in dB, then `GainRaw`
// in device units with a warning). Settings() reads back the values the device accepted.
//
// Frames: every buffer's status is checked (missing packets, timeout, size mismatch, aborted, ...)
// and the buffer is queued again before Grab returns; a frame is kOk only when Aravis reported it
// complete AND its size, width, height and pixel format are those configured. kTimeout means that
// nothing arrived within the grab timeout; a frame that arrived but stayed incomplete (Aravis's
// buffer status MISSING_PACKETS, or TIMEOUT when unanswered resend requests ran out its retention)
// is kMissingPackets. Frame-id gaps are
// counted by the backend itself (16-bit GigE Vision ids wrap from 65535 to 1 without a gap) and
// with the stream's own counters returned by Statistics(): there, missing_frames counts frames lost
// whole (ids skipped between two complete frames, less the damaged frames delivered between them),
// each such gap also being one line of Warnings(). A damaged frame has frame_id 0: its leader
// packet, which carries the id, may be the packet that was lost. A device that stops answering
// turns Grab into kAborted frames with a message naming the device; nothing blocks longer than the
// grab timeout plus one GVCP probe (Aravis 0.8 retries GVCP 5 x 500 ms, so about 5 s); Stop() and
// the destructor of a lost camera take several seconds more for the same reason, and then return.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "capture/camera.h"

namespace slshadow::capture {

struct AravisOpenOptions {
  // IPv4 address, serial number or Aravis device id (see the header comment).
  std::string device;
  // Allows GigE Vision discovery (broadcast) to resolve a serial number or device id.
  bool allow_discovery = false;
  // Number of stream buffers queued to Aravis (more buffers absorb longer host stalls).
  int n_buffers = 8;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// Opens one camera; throws slshadow::Error naming the device when it cannot be opened.
std::unique_ptr<Camera> OpenAravisCamera(const AravisOpenOptions& options);

// One device as listed by `slshadow devices`.
struct AravisDeviceEntry {
  std::string id;        // Aravis device id (opens it with allow_discovery, or by address)
  std::string protocol;  // "GigEVision" or "USB3Vision"
  std::string vendor, model, serial;
  std::string address;  // IPv4 address (GigE Vision) or USB bus address
};

// Lists USB3 Vision devices (local USB enumeration) and, only when `gige_discovery` is set, GigE
// Vision devices found by a discovery broadcast on every network interface.
std::vector<AravisDeviceEntry> ListAravisDevices(bool gige_discovery);

// True when `text` is a dotted IPv4 address (the only form opened without any lookup).
bool IsIpv4Address(const std::string& text);

// The number of 16-bit GigE Vision frame ids strictly between `before` and `after` on the ring
// 1..65535 (0 is invalid and skipped), e.g. (65535, 1) -> 0, (65534, 2)
// -> 2. Ids above 65535 (USB3 Vision, GigE Vision 2 extended ids) are compared as plain 64-bit
// counters. Exposed for the tests.
uint64_t FrameIdsSkipped(uint64_t before, uint64_t after);

}  // namespace slshadow::capture
