#include "capture/camera.h"

#include <cmath>

#include "core/error.h"

namespace slshadow::capture {

std::string ToString(PixelFormat value) { return EnumToString(value, kPixelFormatNames); }

PixelFormat PixelFormatFromString(const std::string& name) {
  return EnumFromString("pixel_format", name, kPixelFormatNames);
}

int BitDepthOf(PixelFormat format) { return format == PixelFormat::kMono8 ? 8 : 16; }

std::string ToString(TriggerMode value) { return EnumToString(value, kTriggerModeNames); }

TriggerMode TriggerModeFromString(const std::string& name) {
  return EnumFromString("trigger", name, kTriggerModeNames);
}

std::string ToString(FrameStatus status) {
  switch (status) {
    case FrameStatus::kOk:
      return "ok";
    case FrameStatus::kTimeout:
      return "timeout";
    case FrameStatus::kMissingPackets:
      return "missing packets";
    case FrameStatus::kSizeMismatch:
      return "size mismatch";
    case FrameStatus::kAborted:
      return "aborted";
    case FrameStatus::kOtherError:
      return "error";
  }
  return "unknown";
}

void CameraSettings::Check(const std::string& what) const {
  if (exposure_us) {
    SLSHADOW_THROW_IF(!std::isfinite(*exposure_us) || !(*exposure_us > 0), what,
                      ": exposure_us: must be a positive number of microseconds (got ",
                      *exposure_us, ")");
  }
  if (gain_db) {
    SLSHADOW_THROW_IF(!std::isfinite(*gain_db), what, ": gain_db: must be finite (got ", *gain_db,
                      ")");
  }
  SLSHADOW_THROW_IF(roi.x < 0 || roi.y < 0 || roi.width < 0 || roi.height < 0, what,
                    ": roi: offsets and sizes must not be negative (got ", roi.x, ",", roi.y, ",",
                    roi.width, ",", roi.height, ")");
  SLSHADOW_THROW_IF((roi.width == 0) != (roi.height == 0), what,
                    ": roi: width and height must both be 0 (full sensor) or both positive (got ",
                    roi.width, "x", roi.height, ")");
  SLSHADOW_THROW_IF(packet_size_bytes < 0, what, ": packet_size_bytes: must not be negative (got ",
                    packet_size_bytes, ")");
  SLSHADOW_THROW_IF(socket_buffer_bytes < 0, what,
                    ": socket_buffer_bytes: must not be negative (got ", socket_buffer_bytes, ")");
  SLSHADOW_THROW_IF(trigger == TriggerMode::kHardware && trigger_line.empty(), what,
                    ": trigger_line: a hardware trigger needs an input line (e.g. Line1)");
}

}  // namespace slshadow::capture
