// A UVC camera through V4L2 (capture::Camera): the ioctls called directly (no libv4l2, whose raw
// syscalls would also bypass test shims), memory-mapped streaming, and poll() with the grab
// timeout. Pixel formats: GREY -> Mono8, Y16 -> Mono16, YUYV -> Mono8 (the luma bytes).
// Controls: exposure (V4L2_CID_EXPOSURE_ABSOLUTE, 100 us units, auto exposure switched to manual)
// and gain (V4L2_CID_GAIN) where the device has them; a setting the device lacks is an error
// naming it. UVC cameras have no trigger input: free-run streams; software trigger drops the
// frames already delivered, so Grab returns a frame exposed after Trigger(); hardware is refused.
// Tested against an LD_PRELOAD shim (tests/capture/v4l2_shim.cc).
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "capture/camera.h"

namespace slshadow::capture {

// The V4L2 nodes `dir`/videoN, sorted by N (capture nodes and others: open one to tell).
std::vector<std::string> ListV4l2Nodes(const std::string& dir = "/dev");

struct V4l2CameraOptions {
  int buffers = 4;  // mmap buffers requested, 2..32
  void Check() const;
};

class V4l2Camera : public Camera {
 public:
  // Opens `device` (e.g. /dev/video0) and checks it can capture and stream. Throws slshadow::Error
  // naming the device otherwise.
  explicit V4l2Camera(const std::string& device, V4l2CameraOptions options = {});
  ~V4l2Camera() override;
  V4l2Camera(const V4l2Camera&) = delete;
  V4l2Camera& operator=(const V4l2Camera&) = delete;

  CameraInfo Info() const override;
  void Configure(const CameraSettings& settings) override;
  CameraSettings Settings() const override;
  void Start() override;
  void Stop() override;
  void Trigger() override;
  Frame Grab(std::chrono::milliseconds timeout) override;
  void Flush() override;
  StreamStatistics Statistics() const override;
  std::vector<std::string> Warnings() const override;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slshadow::capture
