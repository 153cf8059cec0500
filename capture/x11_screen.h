// Reads pixels back from an X server (XGetImage on the root window): what a window projector has
// put into the X framebuffer. Under Xvfb the framebuffer is the projector's "light", so this is
// how tests, `slshadow latency` and closed-loop fixtures see what is actually on the screen,
// independently of what the sequencer believes it showed. X11 types stay in the .cc file.
//
// Thread-safety: one reader per thread (each opens its own connection to the X server).
#pragma once

#include <memory>
#include <string>

#include <opencv2/core.hpp>

namespace slshadow::capture {

class XScreenReader {
 public:
  // Connects to `display_name` (e.g. ":93"); empty: $DISPLAY. Throws slshadow::Error naming the
  // display when the connection fails or the root window is not 24/32-bit TrueColor. Reads through
  // MIT-SHM when the server is local and offers it (allow_shm), else with plain XGetImage.
  explicit XScreenReader(const std::string& display_name = "", bool allow_shm = true);
  bool uses_shm() const;
  ~XScreenReader();
  XScreenReader(const XScreenReader&) = delete;
  XScreenReader& operator=(const XScreenReader&) = delete;

  const std::string& display_name() const;
  int width() const;  // default screen, pixels
  int height() const;

  // The screen content of `rect` (screen pixels, must lie inside the screen) as CV_8UC3 in BGR
  // order. Throws slshadow::Error for a rect outside the screen.
  cv::Mat ReadBgr(const cv::Rect& rect);
  // The same as CV_8UC1: the green channel (grey patterns drawn 1:1 have R = G = B).
  cv::Mat ReadGrey(const cv::Rect& rect);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  cv::Mat Read(const cv::Rect& rect, int channels);
};

}  // namespace slshadow::capture
