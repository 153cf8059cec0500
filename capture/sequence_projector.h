// The second projector seam of capture/: a projector that runs the whole pattern sequence on its
// own clock and triggers the cameras itself (a DLP LightCrafter in pattern-sequence mode, its
// TRIG_OUT wired to every camera's trigger input). The host does not show patterns one by one:
// it programs the sequence, starts it, and only grabs (capture/pattern_sequence_capture.h).
// Projectors that show one image per host call (windows, a LightCrafter in video mode) implement
// capture/projector.h instead.
//
// Life cycle: Open (a backend factory) -> Load(images) once -> { Start -> (frames) -> Stop }*.
#pragma once

#include <chrono>
#include <vector>

#include <opencv2/core.hpp>

#include "capture/projector.h"

namespace slshadow::capture {

class SequenceProjector {
 public:
  virtual ~SequenceProjector() = default;
  virtual ProjectorInfo Info() const = 0;
  // Programs the device to show `images` (CV_8UC1, the projector's resolution) once each, in
  // order, one per FramePeriod(), pulsing its trigger output at the start of every pattern, and
  // not repeating. Throws slshadow::Error naming the image or what the device refused.
  virtual void Load(const std::vector<cv::Mat>& images) = 0;
  // Starts the loaded sequence at its first pattern; returns when the device has accepted the
  // command, with the host time it did (the first trigger comes no earlier).
  virtual std::chrono::system_clock::time_point Start() = 0;
  // Stops the sequence (the next Start begins at the first pattern again).
  virtual void Stop() = 0;
  // The time from one pattern (and trigger pulse) to the next.
  virtual std::chrono::microseconds FramePeriod() const = 0;
  // Asks the device whether it is still there and running the sequence; throws slshadow::Error
  // saying why not (unplugged, mode changed). Called after a camera missed a frame, to name the
  // cause in the capture's error.
  virtual void CheckAlive() = 0;
};

}  // namespace slshadow::capture
