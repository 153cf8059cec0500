// The DLPC350 protocol client against an emulated device at the HID report level: every command's
// request is compared byte for byte with the framing of TI's programmer's guide (the worked
// examples of ../shared/LIGHTCRAFTER.md where it has them), multi-report messages are split and
// reassembled, replies parsed, and each failure (NACK, wrong sequence echo, timeout, a device that
// takes nothing, validation that never finishes) is one error naming the command.
#include "capture/lightcrafter_protocol.h"

#include <functional>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/capture/dlpc350_emulator.h"

namespace slshadow::capture::dlpc350 {
namespace {
using testing::Dlpc350Emulator;
using testing::MemoryTransport;

std::string ErrorOf(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

// "40 01 03 00 1B 1A 01" padded with zeros to 64 bytes.
Report R(const std::string& hex) {
  Report r{};
  size_t i = 0;
  for (size_t at = 0; at + 1 < hex.size() + 1 && at < hex.size(); at += 3)
    r.at(i++) = static_cast<uint8_t>(std::stoul(hex.substr(at, 2), nullptr, 16));
  return r;
}

std::string ToHex(const Report& r) {
  std::string s;
  char b[4];
  for (auto v : r) {
    std::snprintf(b, sizeof b, "%02X ", v);
    s += b;
  }
  return s;
}

struct Fixture : ::testing::Test {
  Dlpc350Emulator device;
  MemoryTransport transport{device};
  Client client{transport,
                ClientOptions{std::chrono::milliseconds(50), std::chrono::milliseconds(1),
                              std::chrono::milliseconds(100)}};
  // The single report of the last request.
  void ExpectLast(const std::string& hex) {
    ASSERT_FALSE(transport.written.empty());
    EXPECT_EQ(ToHex(transport.written.back()), ToHex(R(hex)));
  }
};

TEST_F(Fixture, WorkedExamplesOfTheGuideAreByteExact) {
  client.SetDisplayMode(DisplayMode::kPatternSequence);  // seq 1
  ExpectLast("40 01 03 00 1B 1A 01");
  EXPECT_EQ(device.display_mode, 1);
  EXPECT_EQ(client.GetDisplayMode(), DisplayMode::kPatternSequence);
  ExpectLast("C0 00 02 00 1B 1A");
  client.SetExposure(16667, 16667);  // seq 2
  ExpectLast("40 02 0A 00 29 1A 1B 41 00 00 1B 41 00 00");
  client.SetPatternConfig(3, true, 3, 1);  // seq 3
  ExpectLast("40 03 06 00 31 1A 02 01 02 00");
  client.SetTrigOut1(TrigOut{false, 0, 0});  // seq 4
  ExpectLast("40 04 05 00 1D 1A 00 BB BB");
}

TEST_F(Fixture, EveryCommandIsByteExact) {
  client.SetDisplayMode(DisplayMode::kVideo);
  ExpectLast("40 01 03 00 1B 1A 00");
  client.SetPatternSource(PatternSource::kFlash);
  ExpectLast("40 02 03 00 22 1A 03");
  client.SetPatternTriggerMode(PatternTriggerMode::kVsync);
  ExpectLast("40 03 03 00 23 1A 00");
  client.SetSequence(SequenceControl::kStart);
  ExpectLast("40 04 03 00 24 1A 02");
  client.SetSequence(SequenceControl::kPause);
  ExpectLast("40 05 03 00 24 1A 01");
  client.SetSequence(SequenceControl::kStop);
  ExpectLast("40 06 03 00 24 1A 00");
  // Exposure 8000 us (0x1F40), period 8333 us (0x208D).
  client.SetExposure(8000, 8333);
  ExpectLast("40 07 0A 00 29 1A 40 1F 00 00 8D 20 00 00");
  // TRIG_OUT2 inverted, +1.072 us (10 steps: 0xC5); TRIG_OUT1 -1.072 us rising (0xB1), +2.787
  // falling (0xD5).
  client.SetTrigOut2(TrigOut{true, 1.072, 0});
  ExpectLast("40 08 04 00 1E 1A 01 C5");
  client.SetTrigOut1(TrigOut{false, -1.072, 2.787});
  ExpectLast("40 09 05 00 1D 1A 00 B1 D5");
  EXPECT_EQ(client.requests(), 9u);
}

TEST_F(Fixture, ImageLutIsSentWithTheFirstTwoEntriesSwapped) {
  client.WriteImageLut({5, 6, 7});
  ASSERT_EQ(transport.written.size(), 4u);
  EXPECT_EQ(ToHex(transport.written[0]), ToHex(R("40 01 03 00 33 1A 01")));
  EXPECT_EQ(ToHex(transport.written[1]), ToHex(R("40 02 03 00 32 1A 00")));
  EXPECT_EQ(ToHex(transport.written[2]), ToHex(R("40 03 05 00 34 1A 06 05 07")));
  EXPECT_EQ(ToHex(transport.written[3]), ToHex(R("40 04 03 00 33 1A 00")));
  EXPECT_EQ(device.image_lut, (std::vector<uint8_t>{6, 5, 7}));
}

TEST_F(Fixture, PatternLutEntriesAreEncodedFieldByField) {
  // 1-bit white pattern 5, external rising, insert black: 1 | 5<<2 | 1<<8 | 7<<12 | 1<<17 =
  // 0x027115.
  PatternEntry a{EntryTrigger::kExternalRising, 5, 1, kLedWhite, false, true, false, false};
  // 8-bit red pattern 2, continue, invert, buffer swap, TRIG_OUT from previous:
  // 3 | 2<<2 | 8<<8 | 1<<12 | 1<<16 | 1<<18 | 1<<19 = 0x0D180B.
  PatternEntry b{EntryTrigger::kContinue, 2, 8, kLedRed, true, false, true, true};
  EXPECT_EQ(EncodePatternEntry(a, "a"), 0x027115u);
  EXPECT_EQ(EncodePatternEntry(b, "b"), 0x0D180Bu);
  client.WritePatternLut({a, b});
  ASSERT_EQ(transport.written.size(), 4u);
  EXPECT_EQ(ToHex(transport.written[0]), ToHex(R("40 01 03 00 33 1A 02")));
  EXPECT_EQ(ToHex(transport.written[2]), ToHex(R("40 03 08 00 34 1A 15 71 02 0B 18 0D")));
  EXPECT_EQ(ToHex(transport.written[3]), ToHex(R("40 04 03 00 33 1A 00")));
  // Out-of-range fields are refused before anything is sent.
  EXPECT_NE(ErrorOf([&] {
              EncodePatternEntry(PatternEntry{EntryTrigger::kInternal, 3, 8, 7}, "e");
            }).find("e.pattern_number: must be 0..2 for bit depth 8 (got 3)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              EncodePatternEntry(PatternEntry{EntryTrigger::kInternal, 0, 9, 7}, "e");
            }).find("e.bit_depth"),
            std::string::npos);
}

TEST_F(Fixture, LongMessagesSpanReportsWithoutHeaders) {
  // 40 entries: 120 data bytes + 2 command bytes = 122 payload bytes: 60 + 62 over two reports.
  std::vector<PatternEntry> entries(40);
  for (int i = 0; i < 40; ++i)
    entries[i] = PatternEntry{EntryTrigger::kInternal, i % 24, 1, kLedWhite};
  client.WritePatternLut(entries);
  ASSERT_EQ(transport.written.size(), 5u);  // open, address, data (2 reports), close
  const Report& first = transport.written[2];
  const Report& second = transport.written[3];
  EXPECT_EQ(first[0], 0x40);
  EXPECT_EQ(first[2], 122);
  EXPECT_EQ(first[3], 0);
  EXPECT_EQ(first[4], 0x34);
  EXPECT_EQ(first[5], 0x1A);
  // Byte 58 of the data is the first byte of the second report, raw.
  std::vector<uint8_t> data;
  for (const auto& e : entries) {
    const uint32_t w = EncodePatternEntry(e, "e");
    data.insert(data.end(), {uint8_t(w), uint8_t(w >> 8), uint8_t(w >> 16)});
  }
  EXPECT_TRUE(std::equal(data.begin(), data.begin() + 58, first.begin() + 6));
  EXPECT_TRUE(std::equal(data.begin() + 58, data.end(), second.begin()));
  EXPECT_TRUE(std::all_of(second.begin() + 62, second.end(), [](uint8_t v) { return v == 0; }));
  EXPECT_EQ(device.pattern_lut, data);  // the emulator reassembled it
  EXPECT_EQ(device.log[2].reports.size(), 2u);
  // 128 entries: 386 payload bytes: 60 + 64 * 5 + 6 = 7 reports; 129 are refused.
  std::vector<PatternEntry> full(128);
  client.WritePatternLut(full);
  EXPECT_EQ(device.log.back().command, kMailboxOpen);
  EXPECT_EQ(device.log[device.log.size() - 2].reports.size(), 7u);
  EXPECT_EQ(device.pattern_lut.size(), 384u);
  full.push_back({});
  EXPECT_NE(ErrorOf([&] { client.WritePatternLut(full); }).find("need 1..128 entries (got 129)"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              EncodeRequest(0x40, 1, kMailboxData, std::vector<uint8_t>(507));
            }).find("512-byte limit"),
            std::string::npos);
}

TEST_F(Fixture, LongRepliesAreReassembledAndVersionsDecoded) {
  // Version: application 3.1.2 (major byte 3, minor byte 2, patch bytes 0-1), API 2.0.0, ...
  device.version = {2, 0, 1, 3, 0, 0, 0, 2, 7, 0, 0, 1, 0, 1, 0, 0};
  const FirmwareVersion v = client.GetVersion();
  ExpectLast("C0 00 02 00 05 02");
  EXPECT_EQ(v.application, 0x03010002u);
  EXPECT_EQ(v.ToString(),
            "application 3.1.2, API 2.0.0, software config 1.0.7, sequence config 0.0.256");
  // A 100-byte reply arrives in two reports.
  device.version.assign(100, 0);
  for (int i = 0; i < 100; ++i) device.version[i] = static_cast<uint8_t>(i);
  const auto raw = client.Read(kVersion);
  EXPECT_EQ(raw, device.version);
}

TEST_F(Fixture, SequenceNumbersRollAndSkipZero) {
  for (int i = 0; i < 300; ++i) client.SetSequence(SequenceControl::kStop);
  std::vector<int> seqs;
  for (const auto& q : device.log) seqs.push_back(q.seq);
  EXPECT_EQ(seqs[0], 1);
  EXPECT_EQ(seqs[254], 255);
  EXPECT_EQ(seqs[255], 1);  // 0 is what reads use
  EXPECT_EQ(std::count(seqs.begin(), seqs.end(), 0), 0);
}

TEST_F(Fixture, NackNamesTheCommandAndItsData) {
  device.nack_command = kExposure;
  const std::string e = ErrorOf([&] { client.SetExposure(1000, 1100); });
  EXPECT_NE(e.find("emulated LightCrafter 4500: exposure and frame period (0x1A29) with data [E8 "
                   "03 00 00 4C 04 00 00]"),
            std::string::npos)
      << e;
  EXPECT_NE(e.find("refused it (NACK"), std::string::npos) << e;
  // A value the device rejects (display mode 2 does not exist) is a NACK too.
  EXPECT_NE(ErrorOf([&] {
              client.Write(kDisplayMode, std::array<uint8_t, 1>{2});
            }).find("display mode (0x1A1B) with data [02]"),
            std::string::npos);
  // A failed read (NACK) names the read.
  EXPECT_NE(ErrorOf([&] { client.Read(kStatusMain); }).find("main status (0x1A0C)"),
            std::string::npos);
}

TEST_F(Fixture, WrongSequenceEchoIsRefused) {
  device.wrong_seq = true;
  const std::string e = ErrorOf([&] { client.SetDisplayMode(DisplayMode::kVideo); });
  EXPECT_NE(e.find("reply carries sequence number 2, expected 1"), std::string::npos) << e;
}

TEST_F(Fixture, TimeoutAndADeviceThatTakesNothing) {
  device.silent = true;
  EXPECT_NE(ErrorOf([&] {
              client.SetDisplayMode(DisplayMode::kVideo);
            }).find("no acknowledgement within 50 ms"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              client.GetDisplayMode();
            }).find("display mode (0x1A1B) with data [(none)]: no reply within 50 ms"),
            std::string::npos);
  transport.accept_writes = false;
  const std::string e = ErrorOf([&] { client.WritePatternLut(std::vector<PatternEntry>(30)); });
  EXPECT_NE(e.find("open mailbox (0x1A33) with data [02]: the device did not accept report 1 of 1 "
                   "within 50 ms"),
            std::string::npos)
      << e;
}

TEST_F(Fixture, ALateReplyIsNotTakenForTheNextRequests) {
  // A read times out; its reply (display mode 1) arrives afterwards. Without draining, the next
  // read of the sequence state would take it (reads all carry seq 0) and report 1 = pause.
  device.display_mode = 1;
  device.hold = true;
  EXPECT_NE(ErrorOf([&] { client.GetDisplayMode(); }).find("no reply within 50 ms"),
            std::string::npos);
  device.hold = false;
  device.ReleaseHeld();
  device.sequence_control = 2;
  EXPECT_EQ(client.Read(kSequenceControl), (std::vector<uint8_t>{2}));
  EXPECT_EQ(client.stale_reports(), 1u);
  // A long late reply (two reports) is dropped whole.
  device.version.assign(100, 7);
  device.hold = true;
  EXPECT_NE(ErrorOf([&] { client.GetVersion(); }).find("no reply within 50 ms"), std::string::npos);
  device.hold = false;
  device.ReleaseHeld();
  client.SetDisplayMode(DisplayMode::kVideo);
  EXPECT_EQ(client.stale_reports(), 3u);
}

TEST_F(Fixture, ValidatePollsUntilDoneAndNamesEveryBit) {
  device.busy_polls = 3;
  device.validation_status = 0x0C;
  const Validation v = client.Validate();
  EXPECT_TRUE(v.ok());
  EXPECT_EQ(v.warnings.size(), 2u);
  // write 00, then 4 reads (3 busy + 1 done)
  ASSERT_EQ(device.log.size(), 5u);
  EXPECT_EQ(ToHex(device.log[0].reports[0]), ToHex(R("40 01 03 00 1A 1A 00")));
  EXPECT_EQ(ToHex(device.log[4].reports[0]), ToHex(R("C0 00 02 00 1A 1A")));
  for (int bits = 0; bits < 256; ++bits) {
    const Validation d = DecodeValidation(static_cast<uint8_t>(bits));
    EXPECT_EQ(d.errors.size() + d.warnings.size(), static_cast<size_t>(__builtin_popcount(bits)))
        << bits;
  }
  // A device that stays busy.
  device.busy_polls = 1 << 30;
  EXPECT_NE(ErrorOf([&] { client.Validate(); }).find("still busy (bit 7) after 100 ms"),
            std::string::npos);
}

TEST_F(Fixture, ProgramRunsTheSetUpOrderAndReportsValidationErrors) {
  PatternSequence s;
  s.source = PatternSource::kFlash;
  s.images = {0, 1, 2};
  for (int i = 0; i < 6; ++i)
    s.entries.push_back({EntryTrigger::kInternal, i, 1, kLedWhite, false, false, i == 3, false});
  s.patterns_per_trig_out2 = 6;
  s.exposure_us = 10000;
  s.frame_period_us = 10230;
  client.Program(s);
  std::vector<uint16_t> commands;
  for (const auto& q : device.log) commands.push_back(q.command);
  const std::vector<uint16_t> expected = {
      kSequenceControl, kDisplayMode, kPatternSource, kPatternConfig,
      kPatternTrigger,  kExposure,    kMailboxOpen,   kMailboxAddress,
      kMailboxData,     kMailboxOpen, kMailboxOpen,   kMailboxAddress,
      kMailboxData,     kMailboxOpen, kValidate,      kValidate};
  EXPECT_EQ(commands, expected);
  EXPECT_EQ(device.image_lut, (std::vector<uint8_t>{1, 0, 2}));
  device.validation_status = 0x11;
  const std::string e = ErrorOf([&] { client.Program(s); });
  EXPECT_NE(
      e.find(
          "bit 0: exposure or frame period invalid; bit 4: frame period - exposure below 230 us"),
      std::string::npos)
      << e;
  s.frame_period_us = 10229;
  EXPECT_NE(ErrorOf([&] { client.Program(s); }).find("or be at most frame_period_us - 230"),
            std::string::npos);
  EXPECT_NE(ErrorOf([&] {
              EncodeTrigDelay(3.0, "TRIG_OUT2 rising");
            }).find("TRIG_OUT2 rising: delay must be in"),
            std::string::npos);
  EXPECT_EQ(EncodeTrigDelay(-20.05, "x"), 0);
}

TEST_F(Fixture, SequenceForPacksPatternsIntoImagesAndProgramsThem) {
  // 10 patterns of 8 bits: 3 per image, 4 images; buffer swaps at 3, 6, 9.
  const PatternSequence s = SequenceFor(10, 8, EntryTrigger::kExternalRising, 16667, 16667);
  ASSERT_EQ(s.entries.size(), 10u);
  EXPECT_EQ(s.images, (std::vector<uint8_t>{0, 1, 2, 3}));
  for (int i = 0; i < 10; ++i) {
    EXPECT_EQ(s.entries[i].pattern_number, i % 3);
    EXPECT_EQ(s.entries[i].buffer_swap, i == 3 || i == 6 || i == 9) << i;
    EXPECT_FALSE(s.entries[i].insert_black);
  }
  client.Program(s);
  // Pattern configuration: 10 entries, repeat, TRIG_OUT2 every 10, 4 images.
  EXPECT_EQ(ToHex(device.log[3].reports[0]), ToHex(R("40 04 06 00 31 1A 09 01 09 03")));
  // Image LUT on the wire: first two swapped.
  EXPECT_EQ(device.image_lut, (std::vector<uint8_t>{1, 0, 2, 3}));
  // Entry 3: external rising (1), pattern 0, depth 8, white, buffer swap: 1 | 8<<8 | 7<<12 | 1<<18
  // = 0x047801.
  ASSERT_EQ(device.pattern_lut.size(), 30u);
  EXPECT_EQ(device.pattern_lut[9] | device.pattern_lut[10] << 8 | device.pattern_lut[11] << 16,
            0x047801);
  // 1-bit: 24 per image, black inserted; 40 patterns -> 2 images.
  const PatternSequence b = SequenceFor(40, 1, EntryTrigger::kInternal, 8000, 8333);
  EXPECT_EQ(b.images.size(), 2u);
  EXPECT_TRUE(b.entries[24].buffer_swap);
  EXPECT_EQ(b.entries[24].pattern_number, 0);
  EXPECT_TRUE(b.entries[0].insert_black);
  EXPECT_NE(ErrorOf([] {
              SequenceFor(129, 1, EntryTrigger::kInternal, 8000, 8333);
            }).find("128-entry pattern LUT"),
            std::string::npos);
  EXPECT_NE(ErrorOf([] {
              SequenceFor(10, 8, EntryTrigger::kInternal, 8000, 8100);
            }).find("frame_period_us - 230"),
            std::string::npos);
}

}  // namespace
}  // namespace slshadow::capture::dlpc350
