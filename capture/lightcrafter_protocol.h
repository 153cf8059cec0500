// The DLPC350 (TI DLP LightCrafter 4500) USB HID command protocol, behind a transport interface
// so that it is unit-testable without USB. Framing follows TI's DLPC350 programmer's guide
// (DLPU010); the byte-level facts and the pitfalls of public drivers are in
// ../shared/LIGHTCRAFTER.md. No libusb here: capture/lightcrafter_usb.cc implements Transport.
//
// Request:  [flags] [seq] [len LSB] [len MSB] [CMD low] [CMD high] [data ...]  zero-padded to 64
//           flags 0x40 write with ack, 0x00 write without ack, 0xC0 read; len = 2 + data bytes.
//           Longer messages: the first report carries the header and the first 60 payload
//           bytes, each further report 64 raw payload bytes; the reply follows the last report.
// Reply:    [flags] [seq] [len LSB] [len MSB] [data ...]; flags bit 5 (0x20) = NACK.
// Every reply is checked: NACK, the sequence echo, the length, and (reads) a non-empty payload.
// Failures throw slshadow::Error naming the device, the command and its decoded payload.
#pragma once

#include <array>
#include <chrono>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

namespace slshadow::capture::dlpc350 {

inline constexpr size_t kReportSize = 64;   // HID report, both directions
inline constexpr size_t kMaxMessage = 512;  // header + command + data, bytes
using Report = std::array<uint8_t, kReportSize>;

inline constexpr uint8_t kFlagRead = 0x80;
inline constexpr uint8_t kFlagReply = 0x40;
inline constexpr uint8_t kFlagNack = 0x20;

// Command codes (16-bit; sent low byte first).
enum Command : uint16_t {
  kPower = 0x0200,
  kVersion = 0x0205,
  kLedCurrent = 0x0B01,
  kLedEnable = 0x1A07,
  kStatusHardware = 0x1A0A,
  kStatusSystem = 0x1A0B,
  kStatusMain = 0x1A0C,
  kValidate = 0x1A1A,
  kDisplayMode = 0x1A1B,
  kTrigOut1 = 0x1A1D,
  kTrigOut2 = 0x1A1E,
  kPatternSource = 0x1A22,
  kPatternTrigger = 0x1A23,
  kSequenceControl = 0x1A24,
  kExposure = 0x1A29,
  kPatternConfig = 0x1A31,
  kMailboxAddress = 0x1A32,
  kMailboxOpen = 0x1A33,
  kMailboxData = 0x1A34,
};
std::string CommandName(uint16_t command);  // "display mode (0x1A1B)"

// One HID link to the device. Write/Read return false on a timeout (nothing sent / nothing came)
// and throw slshadow::Error on any other transport failure (device gone, pipe error).
class Transport {
 public:
  virtual ~Transport() = default;
  virtual bool Write(const Report& report, std::chrono::milliseconds timeout) = 0;
  virtual bool Read(Report* report, std::chrono::milliseconds timeout) = 0;
  virtual std::string Describe() const = 0;  // "LightCrafter 4500 on USB 1-2", for messages
};

// Pure framing (exposed for tests and for emulators).
std::vector<Report> EncodeRequest(uint8_t flags, uint8_t seq, uint16_t command,
                                  std::span<const uint8_t> data);

enum class DisplayMode : uint8_t { kVideo = 0, kPatternSequence = 1 };
enum class PatternSource : uint8_t { kVideoPort = 0, kFlash = 3 };
enum class PatternTriggerMode : uint8_t {
  kVsync = 0,
  kInternalOrExternal = 1,
  kTrigIn1Pairs = 2,
  kVariableExposureIntExt = 3,
  kVariableExposureVsync = 4
};
enum class SequenceControl : uint8_t { kStop = 0, kPause = 1, kStart = 2 };

// Per-entry trigger of the pattern LUT.
enum class EntryTrigger : uint8_t {
  kInternal = 0,
  kExternalRising = 1,
  kExternalFalling = 2,
  kContinue = 3
};

// LED bits of a pattern LUT entry.
inline constexpr uint8_t kLedRed = 1, kLedGreen = 2, kLedBlue = 4, kLedWhite = 7;

// One pattern LUT entry: which bit plane(s) of the current image, with which LEDs and trigger.
struct PatternEntry {
  EntryTrigger trigger = EntryTrigger::kInternal;
  int pattern_number = 0;    // bit-plane group in the 24-bit image: 0 .. 24 / bit_depth - 1
  int bit_depth = 1;         // 1..8
  uint8_t leds = kLedWhite;  // kLedRed | kLedGreen | kLedBlue; 0 = off (black)
  bool invert = false;
  bool insert_black = false;   // black after the pattern (needed between 1-bit patterns at rates)
  bool buffer_swap = false;    // move to the next image of the image LUT before this entry
  bool trig_out_prev = false;  // share TRIG_OUT with the previous entry
};
// The 24-bit LUT word; throws slshadow::Error naming `where` and the bad field.
uint32_t EncodePatternEntry(const PatternEntry& entry, const std::string& where);

// A whole pattern sequence to run from the device's own timing.
struct PatternSequence {
  std::vector<PatternEntry> entries;  // 1..128
  std::vector<uint8_t> images;        // image-LUT (flash image indices), 1..64; video port: {0}
  PatternSource source = PatternSource::kVideoPort;
  PatternTriggerMode trigger_mode = PatternTriggerMode::kInternalOrExternal;
  bool repeat = true;
  int patterns_per_trig_out2 = 1;  // TRIG_OUT2 pulses once every this many entries
  uint32_t exposure_us = 16667;
  uint32_t frame_period_us = 16667;  // == exposure, or >= exposure + 230
  void Check() const;                // throws slshadow::Error naming the field
};

// The sequence that shows `patterns` patterns of `bit_depth` bits from flash images packed
// 24 / bit_depth to a 24-bit image (pattern i: image i / per_image, pattern number i % per_image,
// a buffer swap on the first entry of every image after the first), white LEDs, each entry
// started by `trigger` (internal: the device's own period; external: TRIG_IN), TRIG_OUT2 once
// per sequence, with black inserted after 1-bit patterns as TI recommends between binary frames.
// Throws slshadow::Error for a count or depth the device cannot hold.
PatternSequence SequenceFor(int patterns, int bit_depth, EntryTrigger trigger, uint32_t exposure_us,
                            uint32_t frame_period_us);

struct TrigOut {
  bool invert = false;          // false: active high
  double rising_delay_us = 0;   // -20.05 .. +2.787 us in steps of 107.2 ns
  double falling_delay_us = 0;  // TRIG_OUT1 only
};
// The delay byte (0xBB = 0 us); throws slshadow::Error for a delay outside the range.
uint8_t EncodeTrigDelay(double delay_us, const std::string& what);

struct FirmwareVersion {
  uint32_t application = 0, api = 0, software_config = 0, sequence_config = 0;
  std::string ToString() const;  // "app 3.0.0, API 2.0.0, ..."
};

// Validation status (read of 0x1A1A after the validate write).
struct Validation {
  uint8_t status = 0;
  std::vector<std::string> errors;    // bits 0, 1, 4 and unknown bits
  std::vector<std::string> warnings;  // bits 2, 3
  bool ok() const { return errors.empty(); }
};
Validation DecodeValidation(uint8_t status);

struct ClientOptions {
  std::chrono::milliseconds timeout{1000};           // per report, write and read
  std::chrono::milliseconds validate_poll{10};       // between busy polls
  std::chrono::milliseconds validate_timeout{5000};  // busy longer than this is an error
  std::chrono::milliseconds drain_timeout{20};  // after a timeout: wait this long for late replies
};

// The DLPC350 command set over a Transport. Not thread-safe.
class Client {
 public:
  explicit Client(Transport& transport, ClientOptions options = {});

  // Raw commands: a write asks for and checks the ack; a read returns the reply's payload.
  void Write(uint16_t command, std::span<const uint8_t> data);
  std::vector<uint8_t> Read(uint16_t command, std::span<const uint8_t> data = {});

  void SetDisplayMode(DisplayMode mode);
  DisplayMode GetDisplayMode();
  void SetPatternSource(PatternSource source);
  void SetPatternTriggerMode(PatternTriggerMode mode);
  void SetSequence(SequenceControl control);
  void SetExposure(uint32_t exposure_us, uint32_t frame_period_us);
  void SetPatternConfig(int lut_entries, bool repeat, int patterns_per_trig_out2, int images);
  void WritePatternLut(const std::vector<PatternEntry>& entries);
  void WriteImageLut(
      const std::vector<uint8_t>& images);  // swaps the first two entries on the wire
  void SetTrigOut1(const TrigOut& trig);
  void SetTrigOut2(const TrigOut& trig);
  // Writes validate, polls until not busy; returns every bit as a message.
  Validation Validate();
  FirmwareVersion GetVersion();
  // Stop, pattern mode, source, configuration, trigger mode, exposure, image LUT, pattern LUT,
  // validate. Throws slshadow::Error listing the validation errors; does not start.
  Validation Program(const PatternSequence& sequence);

  uint64_t requests() const { return requests_; }
  // Reports thrown away because they arrived after their request had timed out.
  uint64_t stale_reports() const { return stale_reports_; }

 private:
  std::vector<uint8_t> Transact(uint8_t flags, uint16_t command, std::span<const uint8_t> data);
  [[noreturn]] void Fail(uint16_t command, std::span<const uint8_t> data,
                         const std::string& why) const;

  Transport& transport_;
  ClientOptions options_;
  uint8_t next_seq_ = 1;
  uint64_t requests_ = 0;
  uint64_t stale_reports_ = 0;
  bool drain_ = false;  // a reply timed out: its late report may still come; drop it first
};

}  // namespace slshadow::capture::dlpc350
