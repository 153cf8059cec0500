// An emulated DLPC350 (LightCrafter 4500) at the HID report level, for tests of the protocol
// client (through MemoryTransport) and of the libusb transport (behind an umockdev usbdevfs
// emulator). It reassembles multi-report requests, keeps the state the structured-light commands
// set, answers reads and acks like the device does, logs every request, and injects faults.
#pragma once

#include <chrono>
#include <cstdint>
#include <deque>
#include <string>
#include <vector>

#include "capture/lightcrafter_protocol.h"

namespace slshadow::capture::testing {

class Dlpc350Emulator {
 public:
  struct Request {
    uint8_t flags = 0, seq = 0;
    uint16_t command = 0;
    std::vector<uint8_t> data;
    std::vector<dlpc350::Report> reports;  // as received
  };

  // One OUT report from the host.
  void Receive(const dlpc350::Report& report);
  // The next IN report the device has queued, if any.
  bool PopReply(dlpc350::Report* report);

  std::vector<Request> log;
  // Device state.
  uint8_t display_mode = 0;
  uint8_t sequence_control = 0;
  std::vector<uint8_t> pattern_lut, image_lut;  // mailbox contents as written on the wire
  uint8_t mailbox = 0, mailbox_address = 0;
  std::vector<uint8_t> version = std::vector<uint8_t>(16, 0);
  // Faults.
  uint16_t nack_command = 0;      // NACK every request of this command
  bool wrong_seq = false;         // echo seq + 1
  bool silent = false;            // queue no replies (a timeout)
  bool hold = false;              // keep replies back until ReleaseHeld() (a late device)
  void ReleaseHeld();
  int busy_polls = 0;             // validate reads report busy this many times
  uint8_t validation_status = 0;  // the final validation bits

 private:
  void Handle(const Request& request);
  void Reply(const Request& request, uint8_t flags, const std::vector<uint8_t>& data);
  std::vector<uint8_t> pending_;  // bytes of a multi-report request
  Request partial_;
  size_t expected_ = 0;
  std::deque<dlpc350::Report> replies_, held_;
};

// The Transport a test hands to dlpc350::Client: writes go to the emulator, reads pop its replies.
class MemoryTransport : public dlpc350::Transport {
 public:
  explicit MemoryTransport(Dlpc350Emulator& device) : device_(device) {}
  bool Write(const dlpc350::Report& report, std::chrono::milliseconds timeout) override;
  bool Read(dlpc350::Report* report, std::chrono::milliseconds timeout) override;
  std::string Describe() const override { return "emulated LightCrafter 4500"; }
  bool accept_writes = true;  // false: the OUT endpoint never takes a report (a hung device)
  std::vector<dlpc350::Report> written;

 private:
  Dlpc350Emulator& device_;
};

}  // namespace slshadow::capture::testing
