#include "capture/lightcrafter_protocol.h"

#include <cmath>
#include <cstdio>
#include <thread>

#include "core/error.h"

namespace slshadow::capture::dlpc350 {
namespace {

constexpr size_t kHeader = 4;
constexpr size_t kFirstPayload = kReportSize - kHeader;  // 60: command + 58 data bytes
constexpr double kTrigDelayStepUs = 0.1072;
constexpr int kTrigDelayZero = 0xBB;
constexpr int kTrigDelayMax = 0xD5;  // +2.787 us

std::string Hex(std::span<const uint8_t> bytes, size_t limit = 24) {
  std::string s;
  char buf[4];
  for (size_t i = 0; i < bytes.size() && i < limit; ++i) {
    std::snprintf(buf, sizeof buf, "%02X", bytes[i]);
    if (i) s.push_back(' ');
    s.append(buf);
  }
  if (bytes.size() > limit) s += " ... (" + std::to_string(bytes.size()) + " bytes)";
  return s.empty() ? "(none)" : s;
}

std::string Hex16(uint16_t v) {
  char buf[8];
  std::snprintf(buf, sizeof buf, "0x%04X", v);
  return buf;
}

void PutU32(std::vector<uint8_t>* out, uint32_t v) {
  for (int i = 0; i < 4; ++i) out->push_back(static_cast<uint8_t>(v >> (8 * i)));
}

uint32_t GetU32(std::span<const uint8_t> b, size_t at) {
  return uint32_t(b[at]) | uint32_t(b[at + 1]) << 8 | uint32_t(b[at + 2]) << 16 |
         uint32_t(b[at + 3]) << 24;
}

std::string VersionText(uint32_t v) {
  // DLPC350 packs major.minor.patch as major (byte 3), minor (byte 2), patch (bytes 0-1).
  return std::to_string(v >> 24) + "." + std::to_string((v >> 16) & 0xFF) + "." +
         std::to_string(v & 0xFFFF);
}

}  // namespace

std::string CommandName(uint16_t command) {
  const char* name = "command";
  switch (command) {
    case kPower:
      name = "power";
      break;
    case kVersion:
      name = "firmware version";
      break;
    case kLedCurrent:
      name = "LED current";
      break;
    case kLedEnable:
      name = "LED enable";
      break;
    case kStatusHardware:
      name = "hardware status";
      break;
    case kStatusSystem:
      name = "system status";
      break;
    case kStatusMain:
      name = "main status";
      break;
    case kValidate:
      name = "validate";
      break;
    case kDisplayMode:
      name = "display mode";
      break;
    case kTrigOut1:
      name = "TRIG_OUT1";
      break;
    case kTrigOut2:
      name = "TRIG_OUT2";
      break;
    case kPatternSource:
      name = "pattern data source";
      break;
    case kPatternTrigger:
      name = "pattern trigger mode";
      break;
    case kSequenceControl:
      name = "start/pause/stop";
      break;
    case kExposure:
      name = "exposure and frame period";
      break;
    case kPatternConfig:
      name = "pattern configuration";
      break;
    case kMailboxAddress:
      name = "mailbox address";
      break;
    case kMailboxOpen:
      name = "open mailbox";
      break;
    case kMailboxData:
      name = "mailbox data";
      break;
    default:
      break;
  }
  return std::string(name) + " (" + Hex16(command) + ")";
}

std::vector<Report> EncodeRequest(uint8_t flags, uint8_t seq, uint16_t command,
                                  std::span<const uint8_t> data) {
  const size_t payload = 2 + data.size();
  SLSHADOW_THROW_IF(kHeader + payload > kMaxMessage, "DLPC350 ", CommandName(command),
                    ": message of ", kHeader + payload, " bytes exceeds the protocol's ",
                    kMaxMessage, "-byte limit");
  std::vector<uint8_t> bytes;
  bytes.reserve(payload);
  bytes.push_back(static_cast<uint8_t>(command & 0xFF));
  bytes.push_back(static_cast<uint8_t>(command >> 8));
  bytes.insert(bytes.end(), data.begin(), data.end());

  std::vector<Report> reports;
  Report first{};
  first[0] = flags;
  first[1] = seq;
  first[2] = static_cast<uint8_t>(payload & 0xFF);
  first[3] = static_cast<uint8_t>(payload >> 8);
  size_t at = std::min(payload, kFirstPayload);
  std::copy(bytes.begin(), bytes.begin() + static_cast<long>(at), first.begin() + kHeader);
  reports.push_back(first);
  while (at < payload) {
    Report next{};
    const size_t n = std::min(payload - at, kReportSize);
    std::copy(bytes.begin() + static_cast<long>(at), bytes.begin() + static_cast<long>(at + n),
              next.begin());
    reports.push_back(next);
    at += n;
  }
  return reports;
}

uint32_t EncodePatternEntry(const PatternEntry& e, const std::string& where) {
  SLSHADOW_THROW_IF(e.bit_depth < 1 || e.bit_depth > 8, where, ".bit_depth: must be 1..8 (got ",
                    e.bit_depth, ")");
  const int max_number = 24 / e.bit_depth - 1;
  SLSHADOW_THROW_IF(e.pattern_number < 0 || e.pattern_number > max_number, where,
                    ".pattern_number: must be 0..", max_number, " for bit depth ", e.bit_depth,
                    " (got ", e.pattern_number, ")");
  SLSHADOW_THROW_IF(e.leds > 7, where, ".leds: must be a mask of red 1, green 2, blue 4 (got ",
                    int(e.leds), ")");
  uint32_t word = static_cast<uint32_t>(e.trigger) & 0x3;
  word |= static_cast<uint32_t>(e.pattern_number) << 2;
  word |= static_cast<uint32_t>(e.bit_depth) << 8;
  word |= static_cast<uint32_t>(e.leds) << 12;
  if (e.invert) word |= 1u << 16;
  if (e.insert_black) word |= 1u << 17;
  if (e.buffer_swap) word |= 1u << 18;
  if (e.trig_out_prev) word |= 1u << 19;
  return word;
}

void PatternSequence::Check() const {
  SLSHADOW_THROW_IF(entries.empty() || entries.size() > 128,
                    "pattern sequence: entries: need 1..128 (got ", entries.size(), ")");
  SLSHADOW_THROW_IF(images.empty() || images.size() > 64,
                    "pattern sequence: images: need 1..64 (got ", images.size(), ")");
  for (size_t i = 0; i < entries.size(); ++i)
    EncodePatternEntry(entries[i], "pattern sequence: entries[" + std::to_string(i) + "]");
  SLSHADOW_THROW_IF(patterns_per_trig_out2 < 1 || patterns_per_trig_out2 > 256,
                    "pattern sequence: patterns_per_trig_out2: must be 1..256 (got ",
                    patterns_per_trig_out2, ")");
  SLSHADOW_THROW_IF(exposure_us == 0 || frame_period_us == 0,
                    "pattern sequence: exposure_us and frame_period_us must be > 0");
  SLSHADOW_THROW_IF(exposure_us != frame_period_us && uint64_t(exposure_us) + 230 > frame_period_us,
                    "pattern sequence: exposure_us ", exposure_us, " must equal frame_period_us ",
                    frame_period_us, " or be at most frame_period_us - 230");
}

PatternSequence SequenceFor(int patterns, int bit_depth, EntryTrigger trigger, uint32_t exposure_us,
                            uint32_t frame_period_us) {
  SLSHADOW_THROW_IF(bit_depth < 1 || bit_depth > 8,
                    "pattern sequence: bit depth must be 1..8 (got ", bit_depth, ")");
  const int per_image = 24 / bit_depth;
  SLSHADOW_THROW_IF(patterns < 1 || patterns > 128, "pattern sequence: ", patterns,
                    " patterns do not fit the device's 128-entry pattern LUT");
  const int images = (patterns + per_image - 1) / per_image;
  SLSHADOW_THROW_IF(images > 64, "pattern sequence: ", patterns, " patterns of ", bit_depth,
                    " bits need ", images, " images, more than the 64-entry image LUT");
  PatternSequence s;
  s.source = PatternSource::kFlash;
  s.trigger_mode = PatternTriggerMode::kInternalOrExternal;
  s.exposure_us = exposure_us;
  s.frame_period_us = frame_period_us;
  s.patterns_per_trig_out2 = patterns;
  for (int i = 0; i < images; ++i) s.images.push_back(static_cast<uint8_t>(i));
  for (int i = 0; i < patterns; ++i) {
    PatternEntry e;
    e.trigger = trigger;
    e.pattern_number = i % per_image;
    e.bit_depth = bit_depth;
    e.leds = kLedWhite;
    e.insert_black = bit_depth == 1;
    e.buffer_swap = i > 0 && i % per_image == 0;
    s.entries.push_back(e);
  }
  s.Check();
  return s;
}

uint8_t EncodeTrigDelay(double delay_us, const std::string& what) {
  const long steps = std::lround(delay_us / kTrigDelayStepUs);
  const long code = kTrigDelayZero + steps;
  SLSHADOW_THROW_IF(!std::isfinite(delay_us) || code < 0 || code > kTrigDelayMax, what,
                    ": delay must be in -20.05 .. +2.787 us (got ", delay_us, " us)");
  return static_cast<uint8_t>(code);
}

std::string FirmwareVersion::ToString() const {
  return "application " + VersionText(application) + ", API " + VersionText(api) +
         ", software config " + VersionText(software_config) + ", sequence config " +
         VersionText(sequence_config);
}

Validation DecodeValidation(uint8_t status) {
  Validation v;
  v.status = status;
  if (status & 0x01) v.errors.push_back("bit 0: exposure or frame period invalid");
  if (status & 0x02) v.errors.push_back("bit 1: pattern numbers invalid");
  if (status & 0x04)
    v.warnings.push_back("bit 2: TRIG_OUT1 continues across pattern boundaries (warning)");
  if (status & 0x08) v.warnings.push_back("bit 3: post-vector sequence warning");
  if (status & 0x10) v.errors.push_back("bit 4: frame period - exposure below 230 us");
  if (status & 0x20) v.errors.push_back("bit 5: undocumented validation bit set");
  if (status & 0x40) v.errors.push_back("bit 6: undocumented validation bit set");
  if (status & 0x80) v.errors.push_back("bit 7: still busy");
  return v;
}

Client::Client(Transport& transport, ClientOptions options)
    : transport_(transport), options_(options) {}

void Client::Fail(uint16_t command, std::span<const uint8_t> data, const std::string& why) const {
  SLSHADOW_THROW(transport_.Describe(), ": ", CommandName(command), " with data [", Hex(data),
                 "]: ", why);
}

std::vector<uint8_t> Client::Transact(uint8_t flags, uint16_t command,
                                      std::span<const uint8_t> data) {
  const bool read = flags & kFlagRead;
  const uint8_t seq = read ? 0 : next_seq_;
  if (!read) next_seq_ = static_cast<uint8_t>(next_seq_ == 255 ? 1 : next_seq_ + 1);
  const auto reports = EncodeRequest(flags, seq, command, data);
  ++requests_;
  if (drain_) {  // a late reply to a timed-out request must not be taken for this one's
    Report stale{};
    while (transport_.Read(&stale, options_.drain_timeout)) ++stale_reports_;
    drain_ = false;
  }
  for (size_t i = 0; i < reports.size(); ++i) {
    if (!transport_.Write(reports[i], options_.timeout)) {
      Fail(command, data,
           "the device did not accept report " + std::to_string(i + 1) + " of " +
               std::to_string(reports.size()) + " within " +
               std::to_string(options_.timeout.count()) + " ms");
    }
  }
  if (!(flags & kFlagReply)) return {};
  Report report{};
  if (!transport_.Read(&report, options_.timeout)) {
    drain_ = true;
    Fail(command, data,
         std::string("no ") + (read ? "reply" : "acknowledgement") + " within " +
             std::to_string(options_.timeout.count()) + " ms");
  }
  const uint8_t rflags = report[0];
  const uint8_t rseq = report[1];
  const size_t len = report[2] | size_t(report[3]) << 8;
  if (rseq != seq) {
    Fail(command, data,
         "reply carries sequence number " + std::to_string(rseq) + ", expected " +
             std::to_string(seq) + " (a stale or foreign reply)");
  }
  if (rflags & kFlagNack) {
    Fail(
        command, data,
        std::string("the device refused it (NACK: command unknown, payload out of range, or not ") +
            "allowed in the current mode; reply flags " + Hex(std::span(&rflags, 1)) + ")");
  }
  if (kHeader + len > kMaxMessage)
    Fail(command, data, "reply claims " + std::to_string(len) + " payload bytes (over 508)");
  std::vector<uint8_t> payload(report.begin() + kHeader,
                               report.begin() + kHeader + std::min(len, kFirstPayload));
  while (payload.size() < len) {
    if (!transport_.Read(&report, options_.timeout)) {
      drain_ = true;
      Fail(command, data,
           "reply cut short: " + std::to_string(payload.size()) + " of " + std::to_string(len) +
               " bytes arrived within " + std::to_string(options_.timeout.count()) + " ms");
    }
    const size_t n = std::min(len - payload.size(), kReportSize);
    payload.insert(payload.end(), report.begin(), report.begin() + static_cast<long>(n));
  }
  if (read && payload.empty())
    Fail(command, data, "the device answered the read with no data (read failed)");
  return payload;
}

void Client::Write(uint16_t command, std::span<const uint8_t> data) {
  Transact(kFlagReply, command, data);
}

std::vector<uint8_t> Client::Read(uint16_t command, std::span<const uint8_t> data) {
  return Transact(kFlagRead | kFlagReply, command, data);
}

namespace {
template <typename E>
std::array<uint8_t, 1> Byte(E v) {
  return {static_cast<uint8_t>(v)};
}
}  // namespace

void Client::SetDisplayMode(DisplayMode mode) { Write(kDisplayMode, Byte(mode)); }

DisplayMode Client::GetDisplayMode() {
  const auto reply = Read(kDisplayMode);
  if (reply[0] > 1)
    Fail(kDisplayMode, {}, "unknown display mode " + std::to_string(reply[0]) + " in the reply");
  return static_cast<DisplayMode>(reply[0]);
}

void Client::SetPatternSource(PatternSource source) { Write(kPatternSource, Byte(source)); }
void Client::SetPatternTriggerMode(PatternTriggerMode mode) { Write(kPatternTrigger, Byte(mode)); }
void Client::SetSequence(SequenceControl control) { Write(kSequenceControl, Byte(control)); }

void Client::SetExposure(uint32_t exposure_us, uint32_t frame_period_us) {
  std::vector<uint8_t> data;
  PutU32(&data, exposure_us);
  PutU32(&data, frame_period_us);
  Write(kExposure, data);
}

void Client::SetPatternConfig(int lut_entries, bool repeat, int patterns_per_trig_out2,
                              int images) {
  SLSHADOW_THROW_IF(lut_entries < 1 || lut_entries > 128 || patterns_per_trig_out2 < 1 ||
                        patterns_per_trig_out2 > 256 || images < 1 || images > 64,
                    transport_.Describe(),
                    ": pattern configuration: entries 1..128, TRIG_OUT2 period 1..256, images ",
                    "1..64 (got ", lut_entries, ", ", patterns_per_trig_out2, ", ", images, ")");
  const std::array<uint8_t, 4> data = {
      static_cast<uint8_t>(lut_entries - 1), static_cast<uint8_t>(repeat ? 1 : 0),
      static_cast<uint8_t>(patterns_per_trig_out2 - 1), static_cast<uint8_t>(images - 1)};
  Write(kPatternConfig, data);
}

void Client::WritePatternLut(const std::vector<PatternEntry>& entries) {
  SLSHADOW_THROW_IF(entries.empty() || entries.size() > 128, transport_.Describe(),
                    ": pattern LUT: need 1..128 entries (got ", entries.size(), ")");
  std::vector<uint8_t> data;
  for (size_t i = 0; i < entries.size(); ++i) {
    const uint32_t w = EncodePatternEntry(entries[i], "pattern LUT entry " + std::to_string(i));
    data.push_back(static_cast<uint8_t>(w));
    data.push_back(static_cast<uint8_t>(w >> 8));
    data.push_back(static_cast<uint8_t>(w >> 16));
  }
  Write(kMailboxOpen, std::array<uint8_t, 1>{2});
  Write(kMailboxAddress, std::array<uint8_t, 1>{0});
  Write(kMailboxData, data);
  Write(kMailboxOpen, std::array<uint8_t, 1>{0});
}

void Client::WriteImageLut(const std::vector<uint8_t>& images) {
  SLSHADOW_THROW_IF(images.empty() || images.size() > 64, transport_.Describe(),
                    ": image LUT: need 1..64 entries (got ", images.size(), ")");
  std::vector<uint8_t> data = images;
  if (data.size() >= 2) std::swap(data[0], data[1]);  // the DLPC350 reads the first two swapped
  Write(kMailboxOpen, std::array<uint8_t, 1>{1});
  Write(kMailboxAddress, std::array<uint8_t, 1>{0});
  Write(kMailboxData, data);
  Write(kMailboxOpen, std::array<uint8_t, 1>{0});
}

void Client::SetTrigOut1(const TrigOut& t) {
  const std::array<uint8_t, 3> data = {static_cast<uint8_t>(t.invert ? 1 : 0),
                                       EncodeTrigDelay(t.rising_delay_us, "TRIG_OUT1 rising"),
                                       EncodeTrigDelay(t.falling_delay_us, "TRIG_OUT1 falling")};
  Write(kTrigOut1, data);
}

void Client::SetTrigOut2(const TrigOut& t) {
  const std::array<uint8_t, 2> data = {static_cast<uint8_t>(t.invert ? 1 : 0),
                                       EncodeTrigDelay(t.rising_delay_us, "TRIG_OUT2 rising")};
  Write(kTrigOut2, data);
}

Validation Client::Validate() {
  Write(kValidate, std::array<uint8_t, 1>{0});
  const auto start = std::chrono::steady_clock::now();
  for (;;) {
    const uint8_t status = Read(kValidate)[0];
    if (!(status & 0x80)) return DecodeValidation(status);
    if (std::chrono::steady_clock::now() - start > options_.validate_timeout) {
      Fail(kValidate, {},
           "still busy (bit 7) after " + std::to_string(options_.validate_timeout.count()) +
               " ms of polling");
    }
    std::this_thread::sleep_for(options_.validate_poll);
  }
}

FirmwareVersion Client::GetVersion() {
  const auto r = Read(kVersion);
  if (r.size() < 16)
    Fail(kVersion, {}, "reply of " + std::to_string(r.size()) + " bytes, expected 16");
  return {GetU32(r, 0), GetU32(r, 4), GetU32(r, 8), GetU32(r, 12)};
}

Validation Client::Program(const PatternSequence& s) {
  s.Check();
  SetSequence(SequenceControl::kStop);
  SetDisplayMode(DisplayMode::kPatternSequence);
  SetPatternSource(s.source);
  SetPatternConfig(static_cast<int>(s.entries.size()), s.repeat, s.patterns_per_trig_out2,
                   static_cast<int>(s.images.size()));
  SetPatternTriggerMode(s.trigger_mode);
  SetExposure(s.exposure_us, s.frame_period_us);
  if (s.source == PatternSource::kFlash) WriteImageLut(s.images);
  WritePatternLut(s.entries);
  Validation v = Validate();
  if (!v.ok()) {
    std::string all;
    for (const auto& e : v.errors) {
      if (!all.empty()) all.append("; ");
      all.append(e);
    }
    SLSHADOW_THROW(transport_.Describe(),
                   ": the device refused the pattern sequence at validation: ", all);
  }
  return v;
}

}  // namespace slshadow::capture::dlpc350
