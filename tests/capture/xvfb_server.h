// Test fixture: a private Xvfb X server, started on a free display number and stopped at the end.
//   Xvfb -displayfd FD -screen 0 WxHx24 -nolisten tcp
// Xvfb picks the first free display number itself and writes it to FD once it accepts
// connections, so there is no race with other servers and no polling.
#pragma once

#include <sys/types.h>

#include <string>

namespace slshadow::testing {

class XvfbServer {
 public:
  // Starts the server (throws std::runtime_error if Xvfb cannot start or does not answer within
  // 15 s). The server gets SIGTERM when the thread that started it ends (PR_SET_PDEATHSIG), so a
  // crashed test leaves none behind; start it on the test's own thread. set_display_env: also sets
  // $DISPLAY, which SDL reads (call before any thread uses SDL).
  XvfbServer(int width, int height, bool set_display_env = true);
  ~XvfbServer();  // SIGTERM, then waits for the process
  XvfbServer(const XvfbServer&) = delete;
  XvfbServer& operator=(const XvfbServer&) = delete;

  const std::string& display() const { return display_; }  // ":N"
  int width() const { return width_; }
  int height() const { return height_; }

 private:
  pid_t pid_ = -1;
  std::string display_;
  int width_, height_;
};

// Test fixture: an Xorg server with the dummy video driver (xserver-xorg-video-dummy) and two
// monitors side by side, set up with xrandr the way a laptop sees a projector on HDMI:
//   DUMMY0 at 0,0 (the monitor), DUMMY1 at monitor_width,0 (the projector).
// SDL then reports two displays, so the display-index path of the window projector is tested.
// Xorg runs as root here (the project's machines); it reads only the generated config (no input
// devices), logs into a temporary folder and is stopped at the end.
class XorgDummyServer {
 public:
  // Modes must be among the dummy driver's (e.g. 1920x1200, 1280x800, 1024x768). Throws
  // std::runtime_error if Xorg or xrandr fails.
  XorgDummyServer(int monitor_width, int monitor_height, int projector_width, int projector_height,
                  bool set_display_env = true);
  ~XorgDummyServer();
  XorgDummyServer(const XorgDummyServer&) = delete;
  XorgDummyServer& operator=(const XorgDummyServer&) = delete;
  const std::string& display() const { return display_; }

 private:
  pid_t pid_ = -1;
  std::string display_;
  std::string dir_;
};

}  // namespace slshadow::testing
