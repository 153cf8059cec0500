// The projector seam of capture/: what the sequencer needs from any projector. Backends: a
// fullscreen window on an HDMI output (SDL2), a DLP LightCrafter over USB (libusb), "none"
// (cameras-only stills under room light), and test projectors. Backend types (SDL, libusb)
// never appear in this header.
//
// Life cycle: Open (a backend factory) -> Load(images) once -> { Show(i) }* / ShowBlack().
#pragma once

#include <chrono>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

namespace slshadow::capture {

struct ProjectorInfo {
  std::string backend;        // "window", "lightcrafter", "none", ...
  std::string id;             // display index / geometry, USB path, ...
  int width = 0, height = 0;  // resolution in projector pixels (0 for "none")
  double refresh_hz = 0;      // 0 when unknown
};

class Projector {
 public:
  virtual ~Projector() = default;
  virtual ProjectorInfo Info() const = 0;
  // Uploads the whole sequence once (CV_8UC1, the projector's resolution). Throws
  // slshadow::Error naming the image index on a wrong size or type.
  virtual void Load(const std::vector<cv::Mat>& images) = 0;
  // Shows image i of the loaded sequence and returns when it has been presented (for a window:
  // after the buffer swap returned); the returned time is when it was presented. The image is on
  // the projector's output only after Latency() more.
  virtual std::chrono::steady_clock::time_point Show(int index) = 0;
  virtual std::chrono::steady_clock::time_point ShowBlack() = 0;
  // Present-to-light latency the sequencer waits after Show() before triggering cameras
  // (configured or measured by `slshadow latency`).
  virtual std::chrono::microseconds Latency() const = 0;
  virtual void SetLatency(std::chrono::microseconds latency) = 0;
  // Number of images loaded.
  virtual int size() const = 0;
};

}  // namespace slshadow::capture
