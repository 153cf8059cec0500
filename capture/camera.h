// The camera seam of capture/: one small interface every camera backend implements (Aravis for
// GigE Vision / USB3 Vision, V4L2 for UVC, replay of a recorded ImageSet, a simulator-backed
// camera built by the workflow layer). The shape follows OpenCV's IVideoCapture, with typed
// settings instead of integer property ids. Backend types (Aravis, GLib, V4L2) never appear in
// this header.
//
// Life cycle: Open (a backend factory) -> Configure -> Start -> { Trigger -> Grab }* -> Stop.
// Errors: a device that cannot be opened or refuses a setting throws slshadow::Error naming the
// device and the setting; a frame that did not arrive or arrived damaged is not an exception but
// a Frame whose status says why (DESIGN.md "Errors", tier c), so the sequencer can retry.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "core/enum_names.h"

namespace slshadow::capture {

enum class PixelFormat { kMono8, kMono12, kMono16 };
std::string ToString(PixelFormat format);                    // "Mono8", "Mono12", "Mono16"
PixelFormat PixelFormatFromString(const std::string& name);  // throws slshadow::Error
// The names (core/enum_names.h), for the devices file's reader.
inline constexpr EnumName<PixelFormat> kPixelFormatNames[] = {{PixelFormat::kMono8, "Mono8"},
                                                              {PixelFormat::kMono12, "Mono12"},
                                                              {PixelFormat::kMono16, "Mono16"}};
int BitDepthOf(PixelFormat format);  // 8 or 16: the depth of the stored image

enum class TriggerMode {
  kFreeRun,   // the camera streams at its own rate; Trigger() is a no-op
  kSoftware,  // one frame per Trigger()
  kHardware   // one frame per edge on the configured input line; Trigger() is a no-op
};
std::string ToString(TriggerMode mode);                      // "free-run", "software", "hardware"
TriggerMode TriggerModeFromString(const std::string& name);  // throws slshadow::Error
inline constexpr EnumName<TriggerMode> kTriggerModeNames[] = {{TriggerMode::kFreeRun, "free-run"},
                                                              {TriggerMode::kSoftware, "software"},
                                                              {TriggerMode::kHardware, "hardware"}};

// Region of interest in sensor pixels; width/height 0 means the full sensor.
struct Roi {
  int x = 0, y = 0, width = 0, height = 0;
  bool Full() const { return width == 0 && height == 0; }
};

struct CameraSettings {
  std::optional<double> exposure_us;  // unset: leave the device's value
  std::optional<double> gain_db;      // unset: leave the device's value
  PixelFormat pixel_format = PixelFormat::kMono8;
  Roi roi;
  TriggerMode trigger = TriggerMode::kSoftware;
  std::string trigger_line = "Line1";  // input line for kHardware
  // Transport (GigE Vision); 0 / unset keeps the backend's default.
  int packet_size_bytes = 0;
  int socket_buffer_bytes = 0;
  bool packet_resend = true;
  void Check(const std::string& what) const;  // throws slshadow::Error naming `what`
};

struct CameraInfo {
  std::string backend;  // "aravis", "v4l2", "replay", "sim", ...
  std::string id;       // the string the device was opened by
  std::string vendor, model, serial;
  int sensor_width = 0, sensor_height = 0;
  std::vector<PixelFormat> pixel_formats;
};

enum class FrameStatus {
  kOk,
  kTimeout,         // nothing arrived within the grab timeout
  kMissingPackets,  // arrived incomplete (GigE Vision packet loss)
  kSizeMismatch,    // payload of another size than configured
  kAborted,         // acquisition stopped or device lost while waiting
  kOtherError       // any other transport status; see Frame::message
};
std::string ToString(FrameStatus status);

struct Frame {
  FrameStatus status = FrameStatus::kOtherError;
  std::string message;               // why, when status != kOk (backend words, for the user)
  cv::Mat image;                     // CV_8UC1 or CV_16UC1 (Mono12 is stored in 16 bits), owned
  uint64_t frame_id = 0;             // device frame counter (GigE Vision: 16-bit, 0 invalid, wraps)
  uint64_t device_timestamp_ns = 0;  // 0 when the device has none
  std::chrono::system_clock::time_point host_timestamp{};
  double exposure_us = 0;  // the exposure the frame was taken with (0 when unknown)
  bool ok() const { return status == FrameStatus::kOk; }
};

// Per-stream counters reported at the end of a capture (GigE Vision stream statistics; backends
// without them leave zeros).
struct StreamStatistics {
  uint64_t completed_frames = 0;
  uint64_t failed_frames = 0;
  uint64_t missing_frames = 0;  // frame-id gaps seen by the transport
  uint64_t missing_packets = 0;
  uint64_t resend_requests = 0;
  uint64_t underruns = 0;
  uint64_t timeouts = 0;
};

class Camera {
 public:
  virtual ~Camera() = default;
  virtual CameraInfo Info() const = 0;
  // Applies the settings; throws slshadow::Error naming the device and the refused setting.
  // Call while stopped.
  virtual void Configure(const CameraSettings& settings) = 0;
  // The settings as the device now has them (read back: exposure, gain, ROI, granted buffers).
  virtual CameraSettings Settings() const = 0;
  virtual void Start() = 0;
  virtual void Stop() = 0;
  // Software trigger (kSoftware); a no-op in the other modes.
  virtual void Trigger() = 0;
  // Waits at most `timeout` for the next frame. Never throws for a missing or damaged frame.
  virtual Frame Grab(std::chrono::milliseconds timeout) = 0;
  // Drops frames already delivered but not grabbed (e.g. before a retry).
  virtual void Flush() {}
  // The sequencer says which pattern (index into the pattern sequence) the projector shows for
  // the next Trigger(). Real cameras ignore it; a replay camera serves that pattern's recorded
  // frame, a simulator-backed camera renders it (so resume and retries stay in step).
  virtual void ExpectPattern(int pattern_index) { (void)pattern_index; }
  virtual StreamStatistics Statistics() const { return {}; }
  // Warnings collected so far (e.g. a socket buffer capped by the kernel), each one line.
  virtual std::vector<std::string> Warnings() const { return {}; }
};

}  // namespace slshadow::capture
