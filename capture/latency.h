// Projector-to-camera latency: how long the sequencer must wait after Projector::Show() returns
// before it triggers the cameras, so that every frame shows the new image (`slshadow latency`).
// Works with any Camera and Projector: the projector switches between full black and full white,
// the camera watches, and a frame counts as "changed" when its mean grey value is past
// `threshold` of the way from the black reference to the white one.
//
//  - Software trigger: per repetition, a binary search over the wait d in [0, max_latency] (to
//    `resolution`): show black and let it settle, show white, wait d after Show returned,
//    trigger, grab. The latency is the largest per-repetition result: the smallest wait after
//    which the frame showed white in every repetition. It includes the camera's own trigger delay,
//    which is what the sequencer waits for too. A trial whose trigger left more than half the
//    resolution late (a busy machine) is repeated, so oversleeping cannot shorten the result.
//  - Free-run (and hardware trigger, where Trigger() is a no-op): after Show(white) the frames are
//    counted until one is white; the latency is the time that frame was grabbed minus Show's
//    return, an upper bound (it includes exposure and transfer).
#pragma once

#include <chrono>
#include <string>
#include <vector>

#include "capture/camera.h"
#include "capture/projector.h"

namespace slshadow::capture {

struct LatencyOptions {
  int repetitions = 5;
  std::chrono::microseconds resolution{1000};  // binary search step (software trigger)
  std::chrono::microseconds max_latency{
      500000};  // upper end of the search; also the settle time of the references
  std::chrono::milliseconds grab_timeout{2000};  // per frame
  double threshold = 0.5;  // fraction of the way from the black to the white reference mean
  double min_contrast_dn =
      10;              // white mean - black mean must exceed this (the camera sees the projector)
  void Check() const;  // throws slshadow::Error naming the field
};

struct LatencyMeasurement {
  std::string mode;                      // "software trigger" or "frame counting"
  std::chrono::microseconds latency{0};  // what to SetLatency() / write into devices.yaml
  std::vector<std::chrono::microseconds> per_repetition;
  std::vector<int> frames_until_change;  // frame counting: frames grabbed after Show until white
  double black_mean_dn = 0, white_mean_dn = 0;  // references
  int frames = 0;                               // frames grabbed in all
  int late_trials = 0;  // software trigger: trials repeated because the trigger left late
  std::string BriefReport() const;
};

// Measures with `camera` (configured, stopped: this starts and stops it) watching `projector`.
// Replaces the projector's loaded sequence with {black, white} and ends on black. Throws
// slshadow::Error when a frame does not arrive (naming its status), when the camera sees no
// contrast between black and white, or when no change is seen within max_latency.
LatencyMeasurement MeasureProjectorLatency(Camera& camera, Projector& projector,
                                           const LatencyOptions& options = {});

}  // namespace slshadow::capture
