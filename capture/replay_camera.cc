#include "capture/replay_camera.h"

#include <algorithm>

#include "core/error.h"

namespace slshadow::capture {

ReplayCamera::ReplayCamera(const std::filesystem::path& imageset, ReplayCameraOptions options)
    : set_(ImageSet::Open(imageset)), options_(std::move(options)) {
  const auto names = set_.CameraNames();
  SLSHADOW_THROW_IF(names.empty(), imageset.string(), ": replay: the ImageSet has no images");
  if (options_.camera.empty()) options_.camera = names.front();
  SLSHADOW_THROW_IF(std::find(names.begin(), names.end(), options_.camera) == names.end(),
                    imageset.string(), ": replay: no images of camera '", options_.camera, "'");
  SLSHADOW_THROW_IF(options_.first_frame_id < 1 || options_.first_frame_id > 65535,
                    imageset.string(), ": replay: first_frame_id must be in [1, 65535] (got ",
                    options_.first_frame_id, ")");
  if (options_.serial.empty()) options_.serial = "replay-" + options_.camera;
  count_ = set_.PatternCount();
  for (int i = 0; i < count_; ++i) {
    const ImageRecord* r = set_.Find(options_.camera, i);
    SLSHADOW_THROW_IF(r == nullptr, imageset.string(), ": replay: camera '", options_.camera,
                      "' has no image of pattern ", i);
    bit_depth_ = r->bit_depth;
  }
  settings_.pixel_format = bit_depth_ == 8 ? PixelFormat::kMono8 : PixelFormat::kMono16;
  next_frame_id_ = static_cast<uint64_t>(options_.first_frame_id);
}

CameraInfo ReplayCamera::Info() const {
  CameraInfo info;
  info.backend = "replay";
  info.id = set_.dir().string() + ":" + options_.camera;
  info.vendor = "slshadow";
  info.model = "replay";
  info.serial = options_.serial;
  const RigDevice& cam = set_.rig().Camera(options_.camera);
  info.sensor_width = cam.model.width;
  info.sensor_height = cam.model.height;
  info.pixel_formats = bit_depth_ == 8
                           ? std::vector<PixelFormat>{PixelFormat::kMono8}
                           : std::vector<PixelFormat>{PixelFormat::kMono12, PixelFormat::kMono16};
  return info;
}

void ReplayCamera::Configure(const CameraSettings& settings) {
  const std::string what = "replay camera " + Info().id;
  settings.Check(what);
  SLSHADOW_THROW_IF(BitDepthOf(settings.pixel_format) != bit_depth_, what,
                    ": pixel_format: the recording is ", bit_depth_, "-bit, ",
                    ToString(settings.pixel_format), " cannot be served");
  const RigDevice& cam = set_.rig().Camera(options_.camera);
  SLSHADOW_THROW_IF(!settings.roi.Full() && (settings.roi.x != 0 || settings.roi.y != 0 ||
                                             settings.roi.width != cam.model.width ||
                                             settings.roi.height != cam.model.height),
                    what, ": roi: a replay serves the full recorded image (", cam.model.width, "x",
                    cam.model.height, ")");
  settings_ = settings;
}

void ReplayCamera::Stop() {
  started_ = false;
  pending_.clear();
}

void ReplayCamera::Trigger() {
  if (!started_ || settings_.trigger != TriggerMode::kSoftware) return;
  pending_.push_back(next_pattern_++);
}

Frame ReplayCamera::Grab(std::chrono::milliseconds /*timeout*/) {
  Frame frame;
  if (!started_) {
    frame.status = FrameStatus::kAborted;
    frame.message = "replay camera not started";
    return frame;
  }
  int pattern = 0;
  if (settings_.trigger == TriggerMode::kSoftware) {
    if (pending_.empty()) {
      frame.status = FrameStatus::kTimeout;
      frame.message = "no software trigger pending";
      ++statistics_.timeouts;
      return frame;
    }
    pattern = pending_.front();
    pending_.pop_front();
  } else {
    pattern = next_pattern_++;
  }
  if (pattern < 0 || pattern >= count_) {
    frame.status = FrameStatus::kTimeout;
    frame.message = "replay exhausted: the recording has patterns 0.." +
                    std::to_string(count_ - 1) + ", asked for " + std::to_string(pattern);
    ++statistics_.timeouts;
    return frame;
  }
  frame.image = set_.Load(options_.camera, pattern);
  frame.status = FrameStatus::kOk;
  frame.frame_id = next_frame_id_;
  next_frame_id_ = next_frame_id_ == 65535 ? 1 : next_frame_id_ + 1;
  frame.device_timestamp_ns = delivered_++ * 1000000ull;
  frame.host_timestamp = std::chrono::system_clock::now();
  frame.exposure_us = set_.Find(options_.camera, pattern)->exposure_us;
  ++statistics_.completed_frames;
  return frame;
}

}  // namespace slshadow::capture
