// Capture with a projector that runs the pattern sequence itself (capture/sequence_projector.h: a
// DLP LightCrafter in pattern-sequence mode whose TRIG_OUT pulses every camera's hardware trigger
// line once per pattern). The host programs the sequence, starts it, and only grabs: one frame
// per pattern per camera, in real time, stored through the resumable ImageSet writer.
//
// The cameras are started first and given SequencerOptions::settle, at least 100 ms, to arm
// their trigger inputs. Then each run starts the device and grabs, per camera, one frame per
// pattern until it has one for every pattern or nothing comes within its grab timeout plus a
// period. Frames are matched to patterns by count and timestamp, per camera:
//  - consecutive frames lie one period apart (device timestamps when the camera has them, else
//    host ones; "one period" is anything in (0.5, 1.5) periods): a frame two or more periods
//    after its predecessor means the frame of the pattern in between is missing (the camera
//    missed its trigger, or the frame was lost in transport when the frame ids skip); one within
//    half a period is a spurious trigger (or a late frame) that cannot be told from the next;
//  - the first frame is the frame of pattern 0 when it arrived within one period of Start (no
//    later trigger can have come by then), or when the frames span every pattern of the
//    sequence. Otherwise (a frame missing at the start or the end, which one cannot be told)
//    nothing of the run is kept;
//  - a damaged frame (incomplete, wrong size) takes one pattern's place and is a fault there;
//  - no frame after the last one matched: that pattern's trigger never came; the projector is then
//    asked whether it is still there (CheckAlive), so an unplugged device is named.
// Each fault names the pattern (index and role) and the camera, never a shifted sequence: the
// patterns before the first fault of any camera are kept, the device is stopped, late frames are
// dropped, and the whole sequence runs again (the device starts at its first pattern) storing
// only the missing patterns, up to max_retries times. Then Capture throws slshadow::Error naming
// the pattern, the camera and why (the first run's cause first), and the staging folder stays
// resumable: `--resume` runs the sequence again and stores the missing patterns only.
//
// Validation (SequencerOptions::validate), after every run, per camera: every frame complete and
// of the rig camera's size and depth; white and black differ (lit share); each Gray bit and its
// inverse are complementary against the references (white and black, or the per-pixel max / min
// of the first phase steps), as in capture/sequencer.h. A failing pair is a fault of its first
// pattern (the device's flash holds other patterns, or the frames were taken of others).
// Stale frames cannot happen here (the projector triggers the camera), so there is no latency,
// settle or re-trigger; auto exposure is not available (the sequence has no white to iterate on).
#pragma once

#include <filesystem>
#include <vector>

#include "capture/sequence_projector.h"
#include "capture/sequencer.h"

namespace slshadow::capture {

// Captures `spec` with `cameras` (each set to TriggerMode::kHardware, wired to the projector's
// trigger output) and a projector that runs the sequence itself into the ImageSet `out`.
// SequencerOptions: max_retries (whole-sequence runs after a fault), settle (the arming time),
// validate, validation, writer, store_queue_images, stop, progress and extra apply; retry_backoff,
// max_latency and sleep_until do not; auto_exposure must be off. The summary's mean_pattern_ms
// is the runs' time (Start to the last frame grabbed) over the patterns they matched;
// CameraCaptureStats::missed_triggers counts the faults of each camera. Throws like Capture.
CaptureSummary CapturePatternSequence(const Rig& rig, const PatternSpec& spec,
                                      const std::vector<CaptureCamera>& cameras,
                                      SequenceProjector& projector,
                                      const std::filesystem::path& out,
                                      const SequencerOptions& options);

}  // namespace slshadow::capture
