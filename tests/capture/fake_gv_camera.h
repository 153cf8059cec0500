// An in-process GigE Vision camera for tests: Aravis's ArvGvFakeCamera on a loopback address,
// serving the images a test supplies through real GVCP (control) and GVSP (stream) over UDP.
// Open it with capture::OpenAravisCamera({.device = fake.address()}).
//
// Network rule (../shared/DEVICE-MOCKS.md): tests send traffic to loopback only. A test binary
// that uses this fixture starts with RunInPrivateNetwork(argc, argv) in its main(): it re-executes
// itself inside `unshare -n` (a network namespace whose only interface is loopback, with
// 127.0.0.2 and 127.0.0.3 added for a stereo pair), so no packet can leave the machine and no
// other test's camera on 127.0.0.1 interferes. Tests call SkipReasonWithoutPrivateNetwork() and
// GTEST_SKIP with it when the namespace could not be made.
//
// Aravis and GLib types stay in fake_gv_camera.cc.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "capture/camera.h"

namespace slshadow::testing {

// What the fake camera is about to send: the fill function returns the image for it.
struct FakeFrameRequest {
  uint64_t frame_id = 0;      // 16-bit GigE Vision id (starts at 65401, wraps to 1)
  int width = 0, height = 0;  // the client's region of interest
  capture::PixelFormat format = capture::PixelFormat::kMono8;
  uint32_t exposure_us = 0;  // the camera's exposure register when the frame is taken
  uint32_t gain_raw = 0;     // the camera's gain register (= gain in dB through the SFNC XML)
  // Hardware trigger (PulseLine): the tag given to the edge this frame answers (-1 without one).
  int64_t line_tag = -1;
};

// Returns a width x height image, CV_8UC1 for Mono8 and CV_16UC1 for Mono12 / Mono16. Runs on
// the fake camera's thread. An image of another size or type is a test bug: the frame is zeroed.
using FakeFill = std::function<cv::Mat(const FakeFrameRequest&)>;

struct FakeGvCameraOptions {
  std::string address = "127.0.0.1";  // 127.0.0.2 / .3 inside RunInPrivateNetwork
  std::string serial = "GV01";
  // false: Aravis's built-in GenICam XML (older names ExposureTimeAbs, GainRaw; Mono8/Mono16;
  // trigger sources Line0 (never fires) and Software).
  // true: the same XML with the SFNC names of real cameras: ExposureTime (µs), Gain (dB, on the
  // gain register), PixelFormat Mono12 added, and TriggerSource Line1, an emulated hardware line
  // that fires on PulseLine().
  bool sfnc_xml = false;
  double trigger_poll_hz = 1000;  // how often the camera polls its trigger register
  double frame_rate_hz = 25;      // free-run frame rate
  int keep_served = 64;           // how many served images ServedImage() remembers (0: none)
};

class FakeGvCamera {
 public:
  // Starts the camera; throws std::runtime_error when it cannot listen on the address.
  explicit FakeGvCamera(const FakeGvCameraOptions& options = {});
  ~FakeGvCamera();
  FakeGvCamera(const FakeGvCamera&) = delete;
  FakeGvCamera& operator=(const FakeGvCamera&) = delete;

  const std::string& address() const;
  const std::string& serial() const;

  // What every following frame shows (default: zeros). Thread-safe.
  void SetFill(FakeFill fill);
  // Fraction of GVSP packets (leader, data, trailer) dropped at random; 1 drops whole frames.
  void SetLostPacketRatio(double ratio);
  // Seeds GLib's global generator, which draws the dropped packets.
  static void SeedLoss(uint32_t seed);
  // Emulated hardware trigger: one rising edge on Line1 (needs sfnc_xml and TriggerSource Line1).
  // Edges are latched like a camera's trigger input does: each one gives one frame, even when the
  // fake camera's thread is descheduled past the next edge (the trigger register alone would
  // merge them), and that frame carries the edge's time as its device timestamp (`edge`, or now
  // when unset; ns since the epoch, as the fake camera stamps frames) and `tag` in
  // FakeFrameRequest::line_tag (e.g. what a projector showed at the edge).
  void PulseLine(int64_t tag = -1, std::chrono::system_clock::time_point edge = {});
  // Sets the free-run rate while running.
  void SetFrameRate(double hz);
  // The camera disappears: stops answering GVCP and sending GVSP (the object stays valid).
  void Destroy();

  // Frames the camera has filled and sent (or tried to send, packets dropped included).
  uint64_t frames_served() const;
  // The ids of all frames served so far, in order.
  std::vector<uint64_t> served_ids() const;
  // The image sent with this frame id, if it is among the last keep_served; empty otherwise.
  cv::Mat ServedImage(uint64_t frame_id) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Call first in main(): unless already inside, re-executes the program inside a private network
// namespace (unshare -n) with loopback up and 127.0.0.2 / 127.0.0.3 added. Returns only inside
// the namespace, or when one cannot be made (then SkipReasonWithoutPrivateNetwork() says why).
void RunInPrivateNetwork(int argc, char** argv);
// Empty inside the private namespace; otherwise the reason, for GTEST_SKIP.
std::string SkipReasonWithoutPrivateNetwork();

}  // namespace slshadow::testing
