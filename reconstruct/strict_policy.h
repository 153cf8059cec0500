// Strict mode: what a measurement chain should run with. A reconstruction whose calibration was
// not confirmed by its own captures, or that turned too few of its decoded pixels into points, is
// not a measurement: the command ends with a non-zero exit and writes nothing.
//
// A set of reconstructions of one capture (e.g. each camera against the projector, and stereo)
// violates strict mode when any of them
//   - has a calibration-check warning (calibration_check.h: the rig file does not fit);
//   - has no calibration check (e.g. camera-projector with one coded axis), unless a stereo
//     reconstruction of the same set checked that camera against the projector (the projector
//     error of one-axis stereo, a passed check that sees the camera-projector geometry);
//   - made points of less than min_point_share of its decoded pixels: points / valid pixels of
//     the reference camera (stereo: the mean over both cameras).
#pragma once

#include <string>
#include <vector>

#include "reconstruct/reconstruct.h"

namespace slshadow {

struct StrictOptions {
  bool enabled = false;
  // Least share of the valid (decoded) pixels that must become points, in [0, 1].
  double min_point_share = 0.5;
  void Check() const;  // throws slshadow::Error naming the field and the value
};

// Every violation of strict mode, one clause each ("left-projector: calibration check not
// available, because ..."); empty when the set passes (or is empty).
std::vector<std::string> StrictViolations(const std::vector<ReconstructSummary>& summaries,
                                          const StrictOptions& options);

// Throws slshadow::Error "<what>: --strict: <violations joined by '; '>; nothing written" when
// options.enabled and the set violates strict mode; else does nothing.
void EnforceStrict(const std::vector<ReconstructSummary>& summaries, const StrictOptions& options,
                   const std::string& what);

}  // namespace slshadow
