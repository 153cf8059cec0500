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
  // 10 s). set_display_env: also sets $DISPLAY, which SDL reads (call before any thread uses SDL).
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

}  // namespace slshadow::testing
