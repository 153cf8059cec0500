// The Aravis backend against Aravis's GigE Vision fake camera, through real GVCP/GVSP on loopback
// inside a private network namespace (fake_gv_camera.h). Oracle: every frame delivered kOk equals,
// bit for bit, the image the fake camera served under that frame id; every frame served is
// accounted for as delivered, damaged or lost whole.
#include "capture/aravis_camera.h"

#include <algorithm>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "capture/devices.h"
#include "capture/factory.h"
#include "core/error.h"
#include "tests/capture/fake_gv_camera.h"

namespace slshadow::capture {
namespace {

using std::chrono::milliseconds;
using testing::FakeFrameRequest;
using testing::FakeGvCamera;
using testing::FakeGvCameraOptions;

constexpr milliseconds kPatience{3000};  // generous: the machine is shared

// A different random image for every frame id (and camera salt), in the requested format.
cv::Mat RandomImage(const FakeFrameRequest& r, uint64_t salt = 0) {
  const bool mono8 = r.format == PixelFormat::kMono8;
  cv::Mat image(r.height, r.width, mono8 ? CV_8UC1 : CV_16UC1);
  cv::RNG rng(r.frame_id * 7919 + salt * 104729 + 1);
  const double top = mono8 ? 256 : r.format == PixelFormat::kMono12 ? 4096 : 65536;
  rng.fill(image, cv::RNG::UNIFORM, 0, top);
  return image;
}

bool SameImage(const cv::Mat& a, const cv::Mat& b) {
  return !a.empty() && a.size() == b.size() && a.type() == b.type() &&
         cv::norm(a, b, cv::NORM_INF) == 0;
}

CameraSettings SmallSoftware(PixelFormat format = PixelFormat::kMono8) {
  CameraSettings s;
  s.pixel_format = format;
  s.roi = Roi{16, 8, 320, 240};
  s.trigger = TriggerMode::kSoftware;
  return s;
}

std::unique_ptr<Camera> Open(const FakeGvCamera& fake) {
  return OpenAravisCamera(AravisOpenOptions{.device = fake.address()});
}

class AravisCameraTest : public ::testing::Test {
 protected:
  void SetUp() override {
    const std::string reason = testing::SkipReasonWithoutPrivateNetwork();
    if (!reason.empty()) GTEST_SKIP() << reason;
  }
};

TEST(FrameIds, WrapAroundIsNotAGap) {
  EXPECT_EQ(FrameIdsSkipped(65400, 65401), 0u);
  EXPECT_EQ(FrameIdsSkipped(65535, 1), 0u);  // 0 is invalid and skipped
  EXPECT_EQ(FrameIdsSkipped(65534, 2), 2u);  // 65535 and 1 missing
  EXPECT_EQ(FrameIdsSkipped(65535, 3), 2u);
  EXPECT_EQ(FrameIdsSkipped(10, 13), 2u);
  EXPECT_EQ(FrameIdsSkipped(70000, 70003), 2u);  // 64-bit ids (USB3 Vision) do not wrap at 16 bits
  EXPECT_TRUE(IsIpv4Address("127.0.0.2"));
  EXPECT_FALSE(IsIpv4Address("GV01"));
  EXPECT_FALSE(IsIpv4Address("Aravis-Fake-GV01"));
}

TEST_F(AravisCameraTest, OpensByAddressAndServesBitExactMono8AndMono16) {
  FakeGvCamera fake({.address = "127.0.0.2", .serial = "GV42"});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  const CameraInfo info = camera->Info();
  EXPECT_EQ(info.backend, "aravis");
  EXPECT_EQ(info.id, "127.0.0.2");
  EXPECT_EQ(info.vendor, "Aravis");
  EXPECT_EQ(info.model, "Fake");
  EXPECT_EQ(info.serial, "GV42");
  EXPECT_EQ(info.sensor_width, 2048);
  EXPECT_EQ(info.sensor_height, 2048);
  EXPECT_EQ(info.pixel_formats,
            (std::vector<PixelFormat>{PixelFormat::kMono8, PixelFormat::kMono16}));

  for (PixelFormat format : {PixelFormat::kMono8, PixelFormat::kMono16}) {
    SCOPED_TRACE(ToString(format));
    camera->Configure(SmallSoftware(format));
    const CameraSettings read = camera->Settings();
    EXPECT_EQ(read.pixel_format, format);
    EXPECT_EQ(read.roi.x, 16);
    EXPECT_EQ(read.roi.width, 320);
    EXPECT_EQ(read.roi.height, 240);
    camera->Start();
    uint64_t previous = 0;
    for (int i = 0; i < 12; ++i) {
      camera->Trigger();
      const Frame frame = camera->Grab(kPatience);
      ASSERT_TRUE(frame.ok()) << frame.message;
      EXPECT_EQ(frame.image.rows, 240);
      EXPECT_EQ(frame.image.cols, 320);
      EXPECT_EQ(frame.image.type(), format == PixelFormat::kMono8 ? CV_8UC1 : CV_16UC1);
      EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)))
          << "frame " << frame.frame_id;
      if (previous != 0) {
        EXPECT_EQ(FrameIdsSkipped(previous, frame.frame_id), 0u);
      }
      EXPECT_GT(frame.device_timestamp_ns, 0u);
      previous = frame.frame_id;
    }
    camera->Stop();
    const StreamStatistics stats = camera->Statistics();
    EXPECT_EQ(stats.completed_frames, 12u);
    EXPECT_EQ(stats.failed_frames, 0u);
    EXPECT_EQ(stats.missing_packets, 0u);
    EXPECT_EQ(stats.missing_frames, 0u);
  }
}

TEST_F(AravisCameraTest, Mono12ThroughTheSfncXmlKeepsTwelveBitValues) {
  FakeGvCamera fake({.address = "127.0.0.2", .sfnc_xml = true});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r, 12); });
  auto camera = Open(fake);
  ASSERT_EQ(camera->Info().pixel_formats.size(), 3u);
  camera->Configure(SmallSoftware(PixelFormat::kMono12));
  camera->Start();
  for (int i = 0; i < 5; ++i) {
    camera->Trigger();
    const Frame frame = camera->Grab(kPatience);
    ASSERT_TRUE(frame.ok()) << frame.message;
    ASSERT_EQ(frame.image.type(), CV_16UC1);
    double lo = 0, hi = 0;
    cv::minMaxLoc(frame.image, &lo, &hi);
    EXPECT_LE(hi, 4095);
    EXPECT_GT(hi, 4000);  // the whole 12-bit range is used, not shifted or truncated to 8 bits
    EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
  }
}

// The device sees the exposure and gain the settings asked for, under the SFNC names when the
// device has them and under the older names otherwise.
TEST_F(AravisCameraTest, SfncNamesWithOlderNamesAsFallback) {
  struct Case {
    bool sfnc;
    double exposure_us, gain_db;
  };
  for (const Case c : {Case{false, 5000, 3}, Case{true, 7000, 4}}) {
    SCOPED_TRACE(c.sfnc ? "SFNC XML" : "built-in XML");
    FakeGvCamera fake({.address = "127.0.0.2", .sfnc_xml = c.sfnc});
    FakeFrameRequest seen;
    fake.SetFill([&seen](const FakeFrameRequest& r) {
      seen = r;
      return RandomImage(r);
    });
    auto camera = Open(fake);
    CameraSettings s = SmallSoftware();
    s.exposure_us = c.exposure_us;
    s.gain_db = c.gain_db;
    camera->Configure(s);
    const CameraSettings read = camera->Settings();
    ASSERT_TRUE(read.exposure_us && read.gain_db);
    EXPECT_DOUBLE_EQ(*read.exposure_us, c.exposure_us);
    EXPECT_DOUBLE_EQ(*read.gain_db, c.gain_db);
    camera->Start();
    camera->Trigger();
    const Frame frame = camera->Grab(kPatience);
    ASSERT_TRUE(frame.ok()) << frame.message;
    EXPECT_DOUBLE_EQ(frame.exposure_us, c.exposure_us);
    camera->Stop();
    EXPECT_EQ(seen.exposure_us, static_cast<uint32_t>(c.exposure_us));  // on the device's register
    EXPECT_EQ(seen.gain_raw, static_cast<uint32_t>(c.gain_db));
    bool gain_raw_warning = false;
    for (const auto& w : camera->Warnings())
      gain_raw_warning |= w.find("GainRaw") != std::string::npos;
    EXPECT_EQ(gain_raw_warning, !c.sfnc);  // only the older device has gain in raw units

    s.exposure_us = 1e9;  // beyond the device's range: refused with the field named
    try {
      camera->Configure(s);
      ADD_FAILURE() << "an exposure of 1e9 us was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("exposure_us"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(c.sfnc ? "ExposureTime)" : "ExposureTimeAbs)"),
                std::string::npos)
          << e.what();
    }
  }
}

TEST_F(AravisCameraTest, EmulatedHardwareLineFiresOnlyOnPulses) {
  FakeGvCamera fake({.address = "127.0.0.2", .sfnc_xml = true});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  CameraSettings s = SmallSoftware();
  s.trigger = TriggerMode::kHardware;
  s.trigger_line = "Line1";
  camera->Configure(s);
  EXPECT_EQ(camera->Settings().trigger, TriggerMode::kHardware);
  camera->Start();
  camera->Trigger();  // a no-op under a hardware trigger
  const Frame none = camera->Grab(milliseconds(300));
  EXPECT_EQ(none.status, FrameStatus::kTimeout) << none.message;
  EXPECT_NE(none.message.find("no frame within 300 ms"), std::string::npos) << none.message;
  for (int i = 0; i < 5; ++i) {
    fake.PulseLine();
    const Frame frame = camera->Grab(kPatience);
    ASSERT_TRUE(frame.ok()) << frame.message;
    EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
  }
  EXPECT_EQ(fake.frames_served(), 5u);
}

TEST_F(AravisCameraTest, RefusedSettingsNameTheField) {
  FakeGvCamera fake({.address = "127.0.0.2"});
  auto camera = Open(fake);
  auto expect_refused = [&](CameraSettings s, const std::string& field) {
    try {
      camera->Configure(s);
      ADD_FAILURE() << field << " was accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("127.0.0.2"), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
    }
  };
  CameraSettings hardware = SmallSoftware();
  hardware.trigger = TriggerMode::kHardware;  // the built-in XML has no Line1
  expect_refused(hardware, "trigger_line: Line1");
  expect_refused(SmallSoftware(PixelFormat::kMono12), "pixel_format: Mono12");
  CameraSettings outside = SmallSoftware();
  outside.roi = Roi{2000, 0, 100, 100};
  expect_refused(outside, "roi");
  EXPECT_THROW(camera->Start(), Error);  // never configured successfully
}

TEST_F(AravisCameraTest, OpeningNeverDiscoversUnlessAllowed) {
  try {
    OpenAravisCamera(AravisOpenOptions{.device = "GV01"});
    ADD_FAILURE() << "opened a serial number without discovery";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("IP address"), std::string::npos) << e.what();
  }
  try {
    OpenAravisCamera(AravisOpenOptions{.device = "127.0.0.3"});  // nothing listens there
    ADD_FAILURE() << "opened an address without a camera";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("127.0.0.3"), std::string::npos) << e.what();
  }
}

// devices.yaml entries with backend aravis open through the factory; errors name the entry.
TEST_F(AravisCameraTest, FactoryOpensAnAravisEntry) {
  FakeGvCamera fake({.address = "127.0.0.2", .serial = "FACT1"});
  CameraEntry entry;
  entry.name = "left";
  entry.backend = "aravis";
  entry.address = "127.0.0.2";
  entry.where = "dev.yaml: cameras[0]";
  const auto camera = OpenCamera(entry);
  EXPECT_EQ(camera->Info().backend, "aravis");
  EXPECT_EQ(camera->Info().serial, "FACT1");
  entry.address = "127.0.0.3";  // nothing there
  try {
    OpenCamera(entry);
    ADD_FAILURE() << "opened 127.0.0.3";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("dev.yaml: cameras[0]: aravis: device '127.0.0.3'"),
              std::string::npos)
        << e.what();
  }
  entry.address.clear();  // none of address / id / serial
  try {
    OpenCamera(entry);
    ADD_FAILURE() << "opened an entry without a device";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("dev.yaml: cameras[0]: aravis: device:"),
              std::string::npos)
        << e.what();
  }
}

// Asked for, discovery resolves a serial number or an Aravis device id. It broadcasts: inside the
// private namespace (SetUp skips outside it) loopback is the only interface.
TEST_F(AravisCameraTest, DiscoveryWhenAllowedFindsASerialOrADeviceId) {
  FakeGvCamera fake({.address = "127.0.0.2", .serial = "DISC7"});
  for (const std::string name : {"DISC7", "Aravis-Fake-DISC7"}) {
    SCOPED_TRACE(name);
    auto camera = OpenAravisCamera(AravisOpenOptions{.device = name, .allow_discovery = true});
    EXPECT_EQ(camera->Info().serial, "DISC7");
    EXPECT_EQ(camera->Info().id, name);
  }
  const auto listed = ListAravisDevices(true);
  ASSERT_EQ(listed.size(), 1u);
  EXPECT_EQ(listed[0].protocol, "GigEVision");
  EXPECT_EQ(listed[0].address, "127.0.0.2");
  EXPECT_EQ(listed[0].serial, "DISC7");
  EXPECT_TRUE(ListAravisDevices(false).empty());  // no USB3 Vision here, and no broadcast
}

// The fake camera starts at frame id 65400: 150 frames cross 65535 -> 1, which is not a gap.
TEST_F(AravisCameraTest, FrameIdWrapAroundIsNotReportedAsAGap) {
  FakeGvCamera fake({.address = "127.0.0.2", .keep_served = 8});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  CameraSettings s = SmallSoftware();
  s.roi = Roi{0, 0, 64, 64};
  camera->Configure(s);
  camera->Start();
  std::vector<uint64_t> ids;
  for (int i = 0; i < 150; ++i) {
    camera->Trigger();
    const Frame frame = camera->Grab(kPatience);
    ASSERT_TRUE(frame.ok()) << frame.message;
    EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
    ids.push_back(frame.frame_id);
  }
  EXPECT_EQ(ids, fake.served_ids());
  EXPECT_EQ(ids.front(), 65401u);
  ASSERT_NE(std::find(ids.begin(), ids.end(), 65535u), ids.end());
  EXPECT_EQ(ids[135], 1u);  // after 65535 comes 1
  EXPECT_EQ(camera->Statistics().missing_frames, 0u);
  EXPECT_TRUE(camera->Warnings().empty()) << camera->Warnings().front();
}

// A whole frame dropped (loss ratio 1 for one frame) is a frame-id gap, counted and reported.
TEST_F(AravisCameraTest, WholeFrameLostIsAGap) {
  FakeGvCamera fake({.address = "127.0.0.2"});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  camera->Configure(SmallSoftware());
  camera->Start();
  camera->Trigger();
  const Frame first = camera->Grab(kPatience);
  ASSERT_TRUE(first.ok()) << first.message;
  fake.SetLostPacketRatio(1.0);
  camera->Trigger();
  EXPECT_EQ(camera->Grab(milliseconds(500)).status, FrameStatus::kTimeout);
  fake.SetLostPacketRatio(0.0);
  camera->Trigger();
  const Frame third = camera->Grab(kPatience);
  ASSERT_TRUE(third.ok()) << third.message;
  EXPECT_EQ(FrameIdsSkipped(first.frame_id, third.frame_id), 1u);
  EXPECT_EQ(camera->Statistics().missing_frames, 1u);
  ASSERT_EQ(camera->Warnings().size(), 1u);
  EXPECT_NE(camera->Warnings()[0].find("never arrived"), std::string::npos)
      << camera->Warnings()[0];
}

// Packet loss injected by the fake camera: no false alarm at 0; above, every damaged frame is
// delivered with a non-OK status, none as OK with wrong content, and the frames delivered, damaged
// and lost whole add up to the frames served, as do Aravis's own counters.
class PacketLossTest : public AravisCameraTest, public ::testing::WithParamInterface<double> {};

TEST_P(PacketLossTest, EveryDamagedFrameIsDetectedAndAccountedFor) {
  const double ratio = GetParam();
  FakeGvCamera::SeedLoss(20261124);
  FakeGvCamera fake({.address = "127.0.0.2", .keep_served = 256});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  CameraSettings s = SmallSoftware();
  s.roi = Roi{0, 0, 512, 512};  // 262 144 bytes: about 190 packets of 1400 bytes per frame
  camera->Configure(s);
  camera->Start();

  int ok = 0, damaged = 0, no_frame = 0;
  auto take = [&](const Frame& frame) {
    if (frame.ok()) {
      ++ok;
      EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)))
          << "frame " << frame.frame_id;
    } else if (frame.status == FrameStatus::kTimeout) {
      ++no_frame;
    } else {
      ++damaged;
      EXPECT_EQ(frame.status, FrameStatus::kMissingPackets) << frame.message;
      EXPECT_TRUE(frame.image.empty());
    }
  };
  auto clean_frame = [&] {  // brackets the lossy run with complete frames
    fake.SetLostPacketRatio(0.0);
    camera->Trigger();
    Frame frame = camera->Grab(kPatience);
    while (!frame.ok() && frame.status != FrameStatus::kTimeout) {  // damaged ones still queued
      take(frame);
      frame = camera->Grab(kPatience);
    }
    ASSERT_TRUE(frame.ok()) << frame.message;
    take(frame);
  };
  clean_frame();
  fake.SetLostPacketRatio(ratio);
  const int n = ratio >= 0.1 ? 40 : 100;  // each damaged frame waits out the 100 ms retention
  for (int i = 0; i < n; ++i) {
    camera->Trigger();
    take(camera->Grab(kPatience));
  }
  clean_frame();
  camera->Stop();

  const StreamStatistics stats = camera->Statistics();
  const auto served = fake.frames_served();
  EXPECT_EQ(served, static_cast<uint64_t>(n + 2));
  EXPECT_EQ(static_cast<uint64_t>(ok + damaged) + stats.missing_frames, served)
      << "ok " << ok << " damaged " << damaged << " lost whole " << stats.missing_frames;
  EXPECT_EQ(static_cast<uint64_t>(no_frame), stats.missing_frames);
  EXPECT_EQ(stats.completed_frames, static_cast<uint64_t>(ok));
  EXPECT_EQ(stats.failed_frames, static_cast<uint64_t>(damaged));
  EXPECT_EQ(stats.timeouts, static_cast<uint64_t>(damaged));  // resend on, never answered
  if (ratio == 0) {
    EXPECT_EQ(damaged, 0);
    EXPECT_EQ(stats.missing_frames, 0u);
    EXPECT_EQ(stats.missing_packets, 0u);
    EXPECT_EQ(stats.resend_requests, 0u);
    EXPECT_TRUE(camera->Warnings().empty());
  } else {
    EXPECT_GT(damaged, 0);
    EXPECT_GE(stats.missing_packets, static_cast<uint64_t>(damaged));
    EXPECT_GT(stats.resend_requests, 0u);
  }
  std::printf(
      "loss %.3f: %d frames served, %d ok, %d damaged, %llu lost whole, %llu packets missing, "
      "%llu resend requests\n",
      ratio, n + 2, ok, damaged, static_cast<unsigned long long>(stats.missing_frames),
      static_cast<unsigned long long>(stats.missing_packets),
      static_cast<unsigned long long>(stats.resend_requests));
}

INSTANTIATE_TEST_SUITE_P(Ratios, PacketLossTest, ::testing::Values(0.0, 0.001, 0.01, 0.1));

// Resend off, free-run: a damaged frame is closed as soon as the next one starts (Aravis's status
// MISSING_PACKETS), or, when the fake camera's thread is starved mid-frame on a loaded machine, by
// its retention expiring (Aravis's TIMEOUT, counted in its n_timeouts; reported as missing packets
// too, its message saying so). Which of the two closes a frame is the machine's speed, not the
// backend's behaviour: the test counts both. The same accounting holds from the stream's first
// frame to the last complete one, whatever the machine's load (a buffer underrun is a frame lost
// whole, counted as a gap).
TEST_F(AravisCameraTest, PacketLossWithoutResendInFreeRun) {
  FakeGvCamera::SeedLoss(7);
  FakeGvCamera fake({.address = "127.0.0.2", .frame_rate_hz = 100, .keep_served = 256});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  CameraSettings s = SmallSoftware();
  s.roi = Roi{0, 0, 512, 512};
  s.trigger = TriggerMode::kFreeRun;
  s.packet_resend = false;
  camera->Configure(s);
  camera->Start();
  Frame first = camera->Grab(kPatience);
  ASSERT_TRUE(first.ok()) << first.message;
  fake.SetLostPacketRatio(0.01);
  int ok = 1, damaged = 0, retention_expired = 0;
  uint64_t last_ok = first.frame_id;
  const auto count_damaged = [&](const Frame& frame) {
    ++damaged;
    EXPECT_EQ(frame.status, FrameStatus::kMissingPackets) << frame.message;
    if (frame.message.find("packets missing when the frame retention expired") !=
        std::string::npos) {
      ++retention_expired;
    }
  };
  for (int i = 0; i < 60; ++i) {
    const Frame frame = camera->Grab(kPatience);
    ASSERT_NE(frame.status, FrameStatus::kTimeout) << frame.message;
    if (frame.ok()) {
      ++ok;
      last_ok = frame.frame_id;
      EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)))
          << "frame " << frame.frame_id;
    } else {
      count_damaged(frame);
    }
  }
  fake.SetLostPacketRatio(0.0);
  for (Frame frame = camera->Grab(kPatience);; frame = camera->Grab(kPatience)) {
    ASSERT_NE(frame.status, FrameStatus::kTimeout) << frame.message;
    if (frame.ok()) {
      ++ok;
      last_ok = frame.frame_id;
      EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
      break;
    }
    count_damaged(frame);
  }
  const StreamStatistics stats = camera->Statistics();
  const std::vector<uint64_t> served = fake.served_ids();
  const auto last = std::find(served.begin(), served.end(), last_ok);
  ASSERT_NE(last, served.end());
  const auto served_until_last_ok = static_cast<uint64_t>(last - served.begin() + 1);
  EXPECT_EQ(static_cast<uint64_t>(ok + damaged) + stats.missing_frames, served_until_last_ok)
      << "ok " << ok << " damaged " << damaged << " lost whole " << stats.missing_frames;
  EXPECT_GT(damaged, 0);  // about 190 packets a frame at 1 %: most frames are damaged
  EXPECT_EQ(stats.resend_requests, 0u);
  // Every frame we were handed as closed by its retention is one Aravis counted as a timeout
  // (frames still queued after the last complete one may add to its count, never subtract).
  EXPECT_GE(stats.timeouts, static_cast<uint64_t>(retention_expired))
      << "damaged " << damaged << ", closed by retention " << retention_expired;
}

TEST_F(AravisCameraTest, FrameTimeoutIsReportedAndTheCameraStaysUsable) {
  FakeGvCamera fake({.address = "127.0.0.2"});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  camera->Configure(SmallSoftware());
  camera->Start();
  const Frame none = camera->Grab(milliseconds(200));  // no trigger: nothing comes
  EXPECT_EQ(none.status, FrameStatus::kTimeout);
  EXPECT_NE(none.message.find("no frame within 200 ms (software trigger)"), std::string::npos)
      << none.message;
  camera->Trigger();
  const Frame frame = camera->Grab(kPatience);
  ASSERT_TRUE(frame.ok()) << frame.message;
  EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
}

TEST_F(AravisCameraTest, CameraDisappearingMidStreamAbortsWithAMessage) {
  for (TriggerMode trigger : {TriggerMode::kSoftware, TriggerMode::kFreeRun}) {
    SCOPED_TRACE(ToString(trigger));
    FakeGvCamera fake({.address = "127.0.0.2", .serial = "GONE", .frame_rate_hz = 100});
    fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
    auto camera = Open(fake);
    CameraSettings s = SmallSoftware();
    s.trigger = trigger;
    camera->Configure(s);
    camera->Start();
    for (int i = 0; i < 3; ++i) {
      camera->Trigger();
      ASSERT_TRUE(camera->Grab(kPatience).ok());
    }
    fake.Destroy();
    camera->Trigger();
    Frame frame = camera->Grab(milliseconds(300));
    // Frames completed before the camera went away may still be delivered, about one per stream
    // buffer at most (free run fills them all when this thread is slow, e.g. under ASan); then the
    // loss shows.
    const int buffers = AravisOpenOptions{}.n_buffers;
    for (int i = 0; i < buffers && frame.ok(); ++i) frame = camera->Grab(milliseconds(300));
    EXPECT_EQ(frame.status, FrameStatus::kAborted) << frame.message;
    EXPECT_NE(frame.message.find("127.0.0.2 (serial GONE) lost"), std::string::npos)
        << frame.message;
    const Frame again = camera->Grab(milliseconds(300));
    EXPECT_EQ(again.status, FrameStatus::kAborted);
    camera->Stop();  // returns; the destructor too
  }
}

TEST_F(AravisCameraTest, StereoPairOnTwoAddresses) {
  FakeGvCamera left({.address = "127.0.0.2", .serial = "LEFT"});
  FakeGvCamera right({.address = "127.0.0.3", .serial = "RIGHT"});
  left.SetFill([](const FakeFrameRequest& r) { return RandomImage(r, 1); });
  right.SetFill([](const FakeFrameRequest& r) { return RandomImage(r, 2); });
  auto cam_left = Open(left);
  auto cam_right = Open(right);
  EXPECT_EQ(cam_left->Info().serial, "LEFT");
  EXPECT_EQ(cam_right->Info().serial, "RIGHT");
  for (auto* c : {cam_left.get(), cam_right.get()}) {
    c->Configure(SmallSoftware());
    c->Start();
  }
  for (int i = 0; i < 5; ++i) {
    cam_left->Trigger();
    cam_right->Trigger();
    const Frame l = cam_left->Grab(kPatience);
    const Frame r = cam_right->Grab(kPatience);
    ASSERT_TRUE(l.ok() && r.ok()) << l.message << r.message;
    EXPECT_TRUE(SameImage(l.image, left.ServedImage(l.frame_id)));
    EXPECT_TRUE(SameImage(r.image, right.ServedImage(r.frame_id)));
    EXPECT_FALSE(SameImage(l.image, r.image));
  }
}

TEST_F(AravisCameraTest, SocketBufferIsReadBackAndAKernelCapWarned) {
  long rmem_max = 0;
  std::ifstream("/proc/sys/net/core/rmem_max") >> rmem_max;
  ASSERT_GT(rmem_max, 0);
  FakeGvCamera fake({.address = "127.0.0.2"});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  for (const long asked : {rmem_max / 2, rmem_max * 2}) {
    SCOPED_TRACE(asked);
    CameraSettings s = SmallSoftware();
    s.socket_buffer_bytes = static_cast<int>(asked);
    camera->Configure(s);
    camera->Start();
    camera->Trigger();
    ASSERT_TRUE(camera->Grab(kPatience).ok());
    const int granted = camera->Settings().socket_buffer_bytes;
    const bool capped = asked > rmem_max;
    EXPECT_EQ(granted, capped ? rmem_max : asked);
    bool warned = false;
    for (const auto& w : camera->Warnings())
      warned |= w.find("net.core.rmem_max") != std::string::npos;
    EXPECT_EQ(warned, capped);
    camera->Stop();
  }
}

TEST_F(AravisCameraTest, PacketSizeIsAppliedAndFramesStayExact) {
  FakeGvCamera fake({.address = "127.0.0.2"});
  fake.SetFill([](const FakeFrameRequest& r) { return RandomImage(r); });
  auto camera = Open(fake);
  CameraSettings s = SmallSoftware();
  s.packet_size_bytes = 8192;
  s.packet_resend = false;
  camera->Configure(s);
  EXPECT_EQ(camera->Settings().packet_size_bytes, 8192);
  camera->Start();
  for (int i = 0; i < 5; ++i) {
    camera->Trigger();
    const Frame frame = camera->Grab(kPatience);
    ASSERT_TRUE(frame.ok()) << frame.message;
    EXPECT_TRUE(SameImage(frame.image, fake.ServedImage(frame.frame_id)));
  }
}

}  // namespace
}  // namespace slshadow::capture

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
