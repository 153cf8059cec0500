// An emulated DLPC350 (LightCrafter 4500) at the HID report level, for tests of the protocol
// client (through MemoryTransport) and of the libusb transport (behind an umockdev usbdevfs
// emulator). It reassembles multi-report requests, keeps the state the structured-light commands
// set, answers reads and acks like the device does, logs every request, and injects faults.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <mutex>
#include <string>
#include <thread>
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
  uint32_t exposure_us = 0, frame_period_us = 0;  // 0x1A29
  std::vector<uint8_t>
      pattern_config;              // 0x1A31: entries - 1, repeat, TRIG_OUT2 period - 1, images - 1
  std::vector<uint8_t> trig_out1;  // 0x1A1D: invert, rising, falling
  // Called on every start / pause / stop write (under the caller's lock: must not call back).
  std::function<void(uint8_t control)> on_sequence_control;
  // The flash pattern each pattern-LUT entry shows, decoded from the LUTs as the device reads
  // them (the image LUT's first two entries swapped back): the flash is taken to hold the
  // patterns of a spec packed as dlpc350::SequenceFor lays them out, so entry e shows pattern
  // image x (24 / bit depth) + pattern number, image being the image-LUT entry after e's buffer
  // swaps. Empty when nothing is programmed.
  std::vector<int> LutPatterns() const;
  // Faults.
  uint16_t nack_command = 0;  // NACK every request of this command
  bool wrong_seq = false;     // echo seq + 1
  bool silent = false;        // queue no replies (a timeout)
  bool hold = false;          // keep replies back until ReleaseHeld() (a late device)
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

// The emulated device's own clock in pattern-sequence mode: Start(patterns, period) steps through
// the programmed entries on a thread, one frame period each; at the start of each it publishes the
// pattern on the DMD (showing()) and pulses TRIG_OUT1 (trigger_out). After the last entry the DMD
// is dark (no repeat). Stop() halts it at once. Faults: a dropped pulse, a device that dies.
class Dlpc350SequenceRunner {
 public:
  Dlpc350SequenceRunner();
  ~Dlpc350SequenceRunner();
  void Start(std::vector<int> patterns, uint32_t frame_period_us);
  void Stop();
  int showing() const { return showing_.load(); }  // pattern on the DMD, -1 dark
  uint64_t pulses() const { return pulses_.load(); }
  uint64_t runs() const { return runs_.load(); }
  // Set before Start. Runs on the runner's thread; `edge` is when the device's clock scheduled
  // the pulse (the thread may run late on a loaded machine; the DLPC350's clock does not).
  std::function<void(int entry, int pattern, std::chrono::system_clock::time_point edge)>
      trigger_out;
  std::atomic<int> drop_pulse_at{
      -1};  // the next run with this entry shows it without a pulse (once)
  std::atomic<int> halt_at{
      -1};  // the next run reaching this entry dies there (once): dark, no pulse, on_halt
  std::function<void()> on_halt;  // e.g. unplug the USB device

 private:
  void Loop();
  std::mutex mutex_;
  std::condition_variable wake_;
  std::vector<int> patterns_;
  std::chrono::microseconds period_{0};
  // When the start command came: the device's clock runs from there even when this thread wakes
  // late on a loaded machine (overdue pulses then go out at once, stamped with their edge time).
  std::chrono::steady_clock::time_point start_;
  std::chrono::system_clock::time_point start_system_;
  uint64_t generation_ = 0;
  bool running_ = false, quit_ = false;
  std::atomic<int> showing_{-1};
  std::atomic<uint64_t> pulses_{0}, runs_{0};
  std::thread thread_;
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
