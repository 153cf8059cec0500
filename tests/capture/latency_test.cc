// Projector-to-camera latency measured through a real X server: the SDL window projector under a
// private Xvfb, a camera double that reads the X screen (it stands for a physical camera watching
// the screen), and a projector double with a known added display delay.
#include "capture/latency.h"

#include <chrono>
#include <cstdio>

#include <gtest/gtest.h>

#include "capture/window_projector.h"
#include "core/error.h"
#include "tests/capture/screen_devices.h"
#include "tests/capture/xvfb_server.h"

namespace slshadow::capture {
namespace {

using std::chrono::microseconds;
using std::chrono::milliseconds;
using testing::DelayedProjector;
using testing::XScreenCamera;
using testing::XvfbServer;

LatencyOptions FastOptions() {
  LatencyOptions o;
  o.repetitions = 3;
  o.max_latency = milliseconds(200);
  o.resolution = microseconds(1000);
  return o;
}

// For a projector double whose delay runs on a thread of its own: what these tests prove is a
// lower bound (no repetition's wait is below the added delay). The search's upper end is not part
// of it: a loaded machine holds the delay thread or the screen camera back by a hundred ms and more
// at times, which a 200 ms range turned into "did not see the projector turn white". A 500 ms range
// leaves room for such stalls (a stall now lengthens the measured wait, which the tests allow);
// two repetitions keep the time of the longer search near that of three at 200 ms.
LatencyOptions LoadTolerantOptions() {
  LatencyOptions o = FastOptions();
  o.repetitions = 2;
  o.max_latency = milliseconds(500);
  return o;
}

// The software renderer has put the frame into the X framebuffer before Show returns, so a
// camera triggered right after Show sees it: the measured latency is exactly 0.
TEST(ProjectorLatency, WindowProjectorSoftwareTriggerIsZero) {
  XvfbServer xvfb(320, 200);
  WindowProjector projector;
  XScreenCamera camera(xvfb.display(), {40, 30, 200, 120});
  CameraSettings s;
  s.trigger = TriggerMode::kSoftware;
  camera.Configure(s);
  const LatencyMeasurement m = MeasureProjectorLatency(camera, projector, FastOptions());
  std::printf("window projector, screen camera: %s\n", m.BriefReport().c_str());
  EXPECT_EQ(m.mode, "software trigger");
  EXPECT_EQ(m.black_mean_dn, 0);
  EXPECT_EQ(m.white_mean_dn, 255);
  ASSERT_EQ(m.per_repetition.size(), 3u);
  EXPECT_EQ(m.latency.count(), 0);
  EXPECT_EQ(projector.size(), 2);  // {black, white} loaded
}

// A display that lights up 40 ms after Show returns: the measured wait is never below 40 ms (a
// camera triggered earlier cannot see white). The window under the delay runs without vsync, so
// the delay is the only latency (with vsync the delayed present would wait for the next tick too).
TEST(ProjectorLatency, AddedDisplayDelayIsFound) {
  XvfbServer xvfb(320, 200);
  WindowProjectorOptions no_vsync;
  no_vsync.vsync = false;
  WindowProjector window(no_vsync);
  const microseconds delay = milliseconds(40);
  DelayedProjector projector(window, delay);
  XScreenCamera camera(xvfb.display(), {0, 0, 320, 200});
  CameraSettings s;
  s.trigger = TriggerMode::kSoftware;
  camera.Configure(s);
  const LatencyMeasurement m = MeasureProjectorLatency(camera, projector, LoadTolerantOptions());
  std::printf("window projector + 40 ms display delay, screen camera: %s\n",
              m.BriefReport().c_str());
  ASSERT_EQ(m.per_repetition.size(), 2u);
  for (const microseconds wait : m.per_repetition) EXPECT_GE(wait, delay);
  EXPECT_LE(m.latency, LoadTolerantOptions().max_latency);
}

TEST(ProjectorLatency, FreeRunCountsFrames) {
  XvfbServer xvfb(320, 200);
  WindowProjectorOptions no_vsync;
  no_vsync.vsync = false;
  WindowProjector window(no_vsync);
  const microseconds delay = milliseconds(30);
  DelayedProjector projector(window, delay);
  XScreenCamera camera(xvfb.display(), {0, 0, 320, 200}, milliseconds(5));
  CameraSettings s;
  s.trigger = TriggerMode::kFreeRun;
  camera.Configure(s);
  const LatencyMeasurement m = MeasureProjectorLatency(camera, projector, LoadTolerantOptions());
  std::printf("window projector + 30 ms display delay, free-running screen camera: %s\n",
              m.BriefReport().c_str());
  EXPECT_EQ(m.mode, "frame counting");
  ASSERT_EQ(m.frames_until_change.size(), 2u);
  for (int n : m.frames_until_change) EXPECT_GE(n, 1);
  for (const microseconds wait : m.per_repetition) EXPECT_GE(wait, delay);
}

// A camera that does not look at the projector: one clear error.
TEST(ProjectorLatency, NoContrastIsAnError) {
  XvfbServer xvfb(3200, 1200);
  WindowProjectorOptions options;
  options.geometry = WindowGeometry{1920, 0, 1280, 800};
  WindowProjector projector(options);
  XScreenCamera camera(xvfb.display(), {0, 0, 640, 480});  // on the "monitor", not the projector
  CameraSettings s;
  camera.Configure(s);
  try {
    MeasureProjectorLatency(camera, projector, FastOptions());
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("sees no change between projector black"),
              std::string::npos)
        << e.what();
  }
  LatencyOptions bad = FastOptions();
  bad.threshold = 1.5;
  EXPECT_THROW(MeasureProjectorLatency(camera, projector, bad), Error);
  bad = FastOptions();
  bad.max_latency = microseconds(10);
  EXPECT_THROW(bad.Check(), Error);
}

}  // namespace
}  // namespace slshadow::capture
