// The SDL2 window projector against a real X server (a private Xvfb per test): what Show puts on
// the screen is read back from the X server (XScreenReader: MIT-SHM / XGetImage) and compared
// pixel for pixel with the pattern.
#include "capture/window_projector.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "capture/x11_screen.h"
#include "core/error.h"
#include "tests/capture/xvfb_server.h"

#if defined(__SANITIZE_ADDRESS__)
#include <dlfcn.h>
#endif

namespace slshadow::capture {
namespace {

using testing::XvfbServer;

#if defined(__SANITIZE_ADDRESS__)
// LeakSanitizer only: Mesa's software GL driver, loaded for the OpenGL renderer test, keeps blocks
// reachable from its own globals, and libGLX unloads the driver with the last context; at exit
// those blocks look leaked from an "<unknown module>" that no suppression can name (240 bytes).
// Loading the driver once more with RTLD_NODELETE keeps it mapped, so LSan sees the references.
[[maybe_unused]] const bool kMesaDriverPinned = [] {
  const char* path = "/usr/lib/x86_64-linux-gnu/dri/swrast_dri.so";
  if (dlopen(path, RTLD_NOW | RTLD_LOCAL | RTLD_NODELETE) != nullptr) return true;
  std::fprintf(stderr, "note: %s not pinned (%s)\n", path, dlerror());
  return false;
}();
#endif

// Patterns of every kind a scan projects: noise (all 256 levels, fixed seed), a ramp, stripes
// one pixel wide (any filtering or offset shows), full black and white.
std::vector<cv::Mat> TestPatterns(int width, int height) {
  std::vector<cv::Mat> out;
  cv::RNG rng(20261124);
  cv::Mat noise(height, width, CV_8UC1);
  rng.fill(noise, cv::RNG::UNIFORM, 0, 256);
  out.push_back(noise);
  cv::Mat ramp(height, width, CV_8UC1);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x)
      ramp.at<uint8_t>(y, x) = static_cast<uint8_t>((x + 3 * y) % 256);
  out.push_back(ramp);
  cv::Mat stripes(height, width, CV_8UC1);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) stripes.at<uint8_t>(y, x) = ((x + y / 2) % 2) ? 255 : 0;
  out.push_back(stripes);
  out.push_back(cv::Mat(height, width, CV_8UC1, cv::Scalar(255)));
  out.push_back(cv::Mat(height, width, CV_8UC1, cv::Scalar(0)));
  return out;
}

// Number of pixels of `screen` (BGR) whose B, G or R differs from the grey `pattern`.
int DifferingPixels(const cv::Mat& screen_bgr, const cv::Mat& pattern) {
  cv::Mat grey3;
  cv::cvtColor(pattern, grey3, cv::COLOR_GRAY2BGR);
  cv::Mat diff;
  cv::absdiff(screen_bgr, grey3, diff);
  cv::Mat any;
  cv::transform(diff, any, cv::Matx13f(1, 1, 1));
  return cv::countNonZero(any);
}

cv::Rect RectOf(const WindowGeometry& g) { return {g.x, g.y, g.width, g.height}; }

struct ScreenSize {
  int width, height;
};

class WindowProjectorScreen : public ::testing::TestWithParam<ScreenSize> {};

// Every loaded pattern shown equals the X screen pixel for pixel; black is black.
TEST_P(WindowProjectorScreen, EveryPatternShownEqualsTheScreen) {
  const ScreenSize size = GetParam();
  XvfbServer xvfb(size.width, size.height);
  WindowProjector projector;
  const ProjectorInfo info = projector.Info();
  EXPECT_EQ(info.backend, "window");
  EXPECT_EQ(info.id, "display:0");
  ASSERT_EQ(info.width, size.width);
  ASSERT_EQ(info.height, size.height);
  const WindowGeometry g = projector.Geometry();
  EXPECT_EQ(g.x, 0);
  EXPECT_EQ(g.y, 0);
  XScreenReader screen(xvfb.display());
  ASSERT_EQ(screen.width(), size.width);

  XScreenReader plain(xvfb.display(), /*allow_shm=*/false);  // XGetImage, the other read-back path
  EXPECT_TRUE(screen.uses_shm());
  EXPECT_FALSE(plain.uses_shm());
  const std::vector<cv::Mat> patterns = TestPatterns(size.width, size.height);
  projector.Load(patterns);
  ASSERT_EQ(projector.size(), static_cast<int>(patterns.size()));
  projector.Show(0);
  EXPECT_EQ(DifferingPixels(plain.ReadBgr(RectOf(g)), patterns[0]), 0);
  EXPECT_EQ(cv::norm(plain.ReadGrey(RectOf(g)), patterns[0], cv::NORM_INF), 0);
  // Forwards, then backwards (every change of image), then black.
  std::vector<int> order;
  for (int i = 0; i < projector.size(); ++i) order.push_back(i);
  for (int i = projector.size() - 2; i >= 0; --i) order.push_back(i);
  for (int i : order) {
    projector.Show(i);
    EXPECT_EQ(DifferingPixels(screen.ReadBgr(RectOf(g)), patterns[static_cast<size_t>(i)]), 0)
        << "pattern " << i;
  }
  projector.ShowBlack();
  EXPECT_EQ(
      DifferingPixels(screen.ReadBgr(RectOf(g)), cv::Mat::zeros(size.height, size.width, CV_8UC1)),
      0);
  // A second sequence replaces the first.
  std::vector<cv::Mat> second = {patterns[1].clone()};
  cv::flip(second[0], second[0], 1);
  projector.Load(second);
  ASSERT_EQ(projector.size(), 1);
  projector.Show(0);
  EXPECT_EQ(DifferingPixels(screen.ReadBgr(RectOf(g)), second[0]), 0);
}

INSTANTIATE_TEST_SUITE_P(Sizes, WindowProjectorScreen,
                         ::testing::Values(ScreenSize{320, 200}, ScreenSize{912, 1140},
                                           ScreenSize{1280, 800}, ScreenSize{1920, 1080}),
                         [](const auto& p) {
                           return std::to_string(p.param.width) + "x" +
                                  std::to_string(p.param.height);
                         });

// One wide X screen (a 1920x1200 monitor and a 1280x800 projector side by side): the window at
// geometry 1920,0,1280,800 shows every pattern exactly there and touches no pixel outside it.
TEST(WindowProjector, WideScreenGeometryOffset) {
  XvfbServer xvfb(3200, 1200);
  XScreenReader screen(xvfb.display());
  const cv::Rect whole(0, 0, 3200, 1200);
  const cv::Mat before = screen.ReadBgr(whole);
  const std::vector<DisplayEntry> displays = ListDisplays();
  ASSERT_EQ(displays.size(), 1u);  // plain Xvfb: one display, the whole screen
  EXPECT_EQ(displays[0].bounds.width, 3200);
  EXPECT_EQ(displays[0].bounds.height, 1200);
  WindowProjectorOptions options;
  options.geometry = ParseWindowGeometry("1920,0,1280,800");
  WindowProjector projector(options);
  EXPECT_THROW(ListDisplays(), Error);  // not while a projector window is open
  EXPECT_EQ(projector.Info().id, "geometry:1920,0,1280,800");
  EXPECT_EQ(projector.Info().width, 1280);
  EXPECT_EQ(projector.Info().height, 800);
  const std::vector<cv::Mat> patterns = TestPatterns(1280, 800);
  projector.Load(patterns);
  const cv::Rect window(1920, 0, 1280, 800);
  for (int i = 0; i < projector.size(); ++i) {
    projector.Show(i);
    const cv::Mat now = screen.ReadBgr(whole);
    EXPECT_EQ(DifferingPixels(now(window), patterns[static_cast<size_t>(i)]), 0) << "pattern " << i;
    cv::Mat outside_diff;
    cv::absdiff(now, before, outside_diff);
    outside_diff(window).setTo(0);
    cv::Mat any;
    cv::transform(outside_diff, any, cv::Matx13f(1, 1, 1));
    EXPECT_EQ(cv::countNonZero(any), 0) << "pixels outside the window changed, pattern " << i;
  }
}

// Two monitors as SDL sees a laptop with a projector on HDMI (Xorg, dummy driver, xrandr): the
// fullscreen window on display 1 covers exactly that output, shows every pattern pixel for pixel
// and leaves display 0 alone.
TEST(WindowProjector, FullscreenOnSecondDisplay) {
  testing::XorgDummyServer xorg(1920, 1200, 1280, 800);
  const std::vector<DisplayEntry> displays = ListDisplays();
  ASSERT_EQ(displays.size(), 2u);
  EXPECT_EQ(displays[1].bounds.x, 1920);
  EXPECT_EQ(displays[1].bounds.width, 1280);
  EXPECT_GT(displays[1].refresh_hz, 0);
  XScreenReader screen(xorg.display());
  const cv::Rect monitor(0, 0, 1920, 1200);
  const cv::Mat before = screen.ReadBgr(monitor);
  WindowProjectorOptions options;
  options.display_index = 1;
  WindowProjector projector(options);
  EXPECT_EQ(projector.Info().id, "display:1");
  EXPECT_EQ(projector.Info().width, 1280);
  EXPECT_EQ(projector.Info().height, 800);
  EXPECT_GT(projector.Info().refresh_hz, 0);
  const WindowGeometry g = projector.Geometry();
  EXPECT_EQ(g.x, 1920);
  EXPECT_EQ(g.y, 0);
  const std::vector<cv::Mat> patterns = TestPatterns(1280, 800);
  projector.Load(patterns);
  for (int i = 0; i < projector.size(); ++i) {
    projector.Show(i);
    EXPECT_EQ(DifferingPixels(screen.ReadBgr(RectOf(g)), patterns[static_cast<size_t>(i)]), 0)
        << "pattern " << i;
    cv::Mat diff;
    cv::absdiff(screen.ReadBgr(monitor), before, diff);
    cv::Mat any;
    cv::transform(diff, any, cv::Matx13f(1, 1, 1));
    EXPECT_EQ(cv::countNonZero(any), 0) << "display 0 changed, pattern " << i;
  }
}

TEST(WindowProjector, WrongImagesAreRejectedAndTheSequenceKept) {
  XvfbServer xvfb(320, 200);
  WindowProjector projector;
  XScreenReader screen(xvfb.display());
  const std::vector<cv::Mat> patterns = TestPatterns(320, 200);
  projector.Load(patterns);
  auto expect_rejected = [&](const std::vector<cv::Mat>& images, const std::string& words) {
    try {
      projector.Load(images);
      ADD_FAILURE() << "accepted: " << words;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(words), std::string::npos) << e.what();
    }
  };
  expect_rejected({patterns[0], cv::Mat(200, 321, CV_8UC1, cv::Scalar(7))}, "image 1 is 321x200");
  expect_rejected({cv::Mat(201, 320, CV_8UC1)}, "image 0 is 320x201");
  expect_rejected({patterns[0], patterns[1], cv::Mat(200, 320, CV_8UC3)},
                  "image 2 is 320x200 not 8-bit grey");
  expect_rejected({cv::Mat(200, 320, CV_16UC1)}, "not 8-bit grey");
  // Nothing was replaced.
  ASSERT_EQ(projector.size(), static_cast<int>(patterns.size()));
  projector.Show(2);
  EXPECT_EQ(DifferingPixels(screen.ReadBgr({0, 0, 320, 200}), patterns[2]), 0);
  EXPECT_THROW(projector.Show(static_cast<int>(patterns.size())), Error);
  EXPECT_THROW(projector.Show(-1), Error);
  EXPECT_THROW(projector.SetLatency(std::chrono::microseconds(-1)), Error);
  EXPECT_THROW(screen.ReadBgr({300, 0, 64, 64}), Error);  // not inside the 320x200 screen
  EXPECT_THROW(XScreenReader(":999"), Error);             // no such X server
}

TEST(WindowProjector, ClearErrorsWithoutADisplayOrWithABadPlace) {
  {
    XvfbServer xvfb(320, 200);
    WindowProjectorOptions options;
    options.display_index = 1;
    try {
      WindowProjector projector(options);
      ADD_FAILURE() << "display 1 of 1 accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("display_index 1 does not exist (1 display(s)"),
                std::string::npos)
          << e.what();
    }
    options.display_index = 0;
    options.geometry = WindowGeometry{300, 0, 64, 64};
    try {
      WindowProjector projector(options);
      ADD_FAILURE() << "geometry off the screen accepted";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("geometry 300,0,64,64 does not lie on a display"),
                std::string::npos)
          << e.what();
    }
    // A failed open leaves nothing behind: the next one opens.
    WindowProjector projector;
    EXPECT_THROW(WindowProjector second, Error);  // one window projector per process
  }
  // No X server at all.
  unsetenv("DISPLAY");
  EXPECT_THROW(ListDisplays(), Error);
  try {
    WindowProjector projector;
    ADD_FAILURE() << "opened without a display";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("no display"), std::string::npos) << e.what();
  }
  EXPECT_THROW(ParseWindowGeometry("1920,0,1280"), Error);
  EXPECT_THROW(ParseWindowGeometry("1920,0,1280,800,1"), Error);
  EXPECT_THROW(ParseWindowGeometry("1920,0,0,800"), Error);
  WindowProjectorOptions bad;
  bad.renderer = "vulkan";
  EXPECT_THROW(bad.Check(), Error);
}

// The sequencer calls Show from its own thread: the projector is created on one thread, used
// from two others in turn, and destroyed on a fourth; what is on the screen is right each time.
TEST(WindowProjector, ShowFromOtherThreads) {
  XvfbServer xvfb(640, 400);
  std::unique_ptr<WindowProjector> projector;
  std::thread([&] { projector = std::make_unique<WindowProjector>(); }).join();
  const std::vector<cv::Mat> patterns = TestPatterns(640, 400);
  std::thread([&] { projector->Load(patterns); }).join();
  for (int i = 0; i < projector->size(); ++i) {
    std::thread([&] {
      XScreenReader screen(xvfb.display());
      projector->Show(i);
      EXPECT_EQ(DifferingPixels(screen.ReadBgr({0, 0, 640, 400}), patterns[static_cast<size_t>(i)]),
                0)
          << i;
    }).join();
  }
  std::thread([&] { projector.reset(); }).join();
}

// The OpenGL renderer (Mesa llvmpipe under Xvfb) is pixel-exact too.
TEST(WindowProjector, OpenGlRendererEqualsTheScreen) {
  XvfbServer xvfb(640, 400);
  WindowProjectorOptions options;
  options.renderer = "opengl";
  WindowProjector projector(options);
  EXPECT_EQ(projector.RendererName(), "opengl");
  XScreenReader screen(xvfb.display());
  const std::vector<cv::Mat> patterns = TestPatterns(640, 400);
  projector.Load(patterns);
  for (int i = 0; i < projector.size(); ++i) {
    projector.Show(i);
    // A GL swap may reach the X server after it returns: wait (bounded) for the frame to land.
    int differing = -1;
    for (int k = 0; k < 200 && differing != 0; ++k) {
      differing =
          DifferingPixels(screen.ReadBgr({0, 0, 640, 400}), patterns[static_cast<size_t>(i)]);
      if (differing != 0) std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    EXPECT_EQ(differing, 0) << "pattern " << i;
  }
  const PresentLatency latency = projector.MeasurePresentLatency(10);
  std::printf("640x400 opengl renderer: %s\n", latency.BriefReport().c_str());
}

// Vsync pacing and present latency, measured and printed (no timed assertion beyond the causal
// one: with vsync, presents cannot run faster than the display refresh).
TEST(WindowProjector, VsyncPacingAndPresentLatencyMeasured) {
  XvfbServer xvfb(1280, 800);
  for (bool vsync : {true, false}) {
    WindowProjectorOptions options;
    options.vsync = vsync;
    WindowProjector projector(options);
    projector.Load(TestPatterns(1280, 800));
    const int frames = 60;
    projector.Show(0);
    const auto t0 = std::chrono::steady_clock::now();
    for (int i = 1; i <= frames; ++i) projector.Show(i % projector.size());
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const double fps = frames / seconds;
    const PresentLatency latency = projector.MeasurePresentLatency(10);
    std::printf("1280x800 %s renderer, vsync %s (display %.0f Hz): %.1f frames/s; %s\n",
                projector.RendererName().c_str(), vsync ? "on" : "off", projector.Info().refresh_hz,
                fps, latency.BriefReport().c_str());
    RecordProperty(vsync ? "vsync_fps" : "no_vsync_fps", std::to_string(fps));
    EXPECT_EQ(latency.samples, 20);
    // Per sample, call-to-screen = Show()'s duration + return-to-screen, so the medians keep that
    // order, and no median exceeds its maximum (a duration >= 0 check could not fail).
    EXPECT_GE(latency.call_to_screen_ms_median, latency.return_to_screen_ms_median);
    EXPECT_LE(latency.call_to_screen_ms_median, latency.call_to_screen_ms_max);
    EXPECT_LE(latency.return_to_screen_ms_median, latency.return_to_screen_ms_max);
    if (vsync) {
      ASSERT_GT(projector.Info().refresh_hz, 0);
      EXPECT_LT(fps, projector.Info().refresh_hz * 1.1);
    }
  }
}

}  // namespace
}  // namespace slshadow::capture
