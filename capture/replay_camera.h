// ReplayCamera: plays one camera of any ImageSet (recorded real, or virtual) as a camera, so the
// sequencer, validation and storage run without hardware on real data.
//
// Frames: one per Trigger() in software mode (free-run and hardware mode: one per Grab(), as if
// the line had pulsed). The frame served is the recorded image of the pattern the sequencer
// announced with ExpectPattern() (or, never told, the next pattern in order); Grab() without a
// pending trigger, or past the last recorded pattern, returns kTimeout at once (nothing could
// arrive later). Frame ids count like GigE Vision's: 16-bit, from first_frame_id, 65535 -> 1
// (0 is invalid). The frame's exposure is the recorded one; pixels are bit-exact.
#pragma once

#include <deque>
#include <filesystem>
#include <memory>
#include <string>

#include "capture/camera.h"
#include "core/image_set.h"

namespace slshadow::capture {

struct ReplayCameraOptions {
  std::string camera;      // camera of the ImageSet to play (empty: its first camera)
  int first_frame_id = 1;  // 1..65535
  std::string serial;      // reported serial (empty: "replay-<camera>")
};

class ReplayCamera : public Camera {
 public:
  // Opens the ImageSet (throws slshadow::Error naming the folder or the unknown camera).
  ReplayCamera(const std::filesystem::path& imageset, ReplayCameraOptions options = {});
  CameraInfo Info() const override;
  // Accepts the recorded pixel format only (Mono8 for 8-bit sets, Mono16 or Mono12 for 16-bit)
  // and a full-sensor ROI; throws naming the setting otherwise. Exposure and gain are recorded
  // facts and are not changed by settings.
  void Configure(const CameraSettings& settings) override;
  CameraSettings Settings() const override { return settings_; }
  void Start() override { started_ = true; }
  void Stop() override;
  void Trigger() override;
  Frame Grab(std::chrono::milliseconds timeout) override;
  void Flush() override { pending_.clear(); }
  void ExpectPattern(int pattern_index) override { next_pattern_ = pattern_index; }
  StreamStatistics Statistics() const override { return statistics_; }
  // Number of recorded patterns.
  int size() const { return count_; }

 private:
  ImageSet set_;
  ReplayCameraOptions options_;
  CameraSettings settings_;
  int count_ = 0;
  int bit_depth_ = 8;
  bool started_ = false;
  std::deque<int> pending_;  // patterns of software triggers not yet grabbed
  int next_pattern_ = 0;     // the pattern the next trigger serves
  uint64_t next_frame_id_ = 1;
  uint64_t delivered_ = 0;
  StreamStatistics statistics_;
};

}  // namespace slshadow::capture
