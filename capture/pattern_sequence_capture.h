// Capture with a projector that runs the pattern sequence itself (capture/sequence_projector.h: a
// DLP LightCrafter in pattern-sequence mode whose TRIG_OUT pulses every camera's hardware trigger
// line once per pattern). The host programs the sequence, starts it, and only grabs: one frame
// per pattern per camera, in real time, stored through the resumable ImageSet writer.
//
// The cameras are started first and given SequencerOptions::settle, at least 100 ms, to arm
// their trigger inputs. Frames are matched to patterns by count and timestamp, per camera: the
// k-th frame must be the frame of pattern k. The first one must arrive within the first frame
// period after Start (host clock: so the time from a trigger to the frame's arrival, exposure and
// transfer included, must stay below one frame period); each later one one period after its
// predecessor (device timestamps when the camera has
// them, else host timestamps; "one period" is anything in (0.5, 1.5) periods). A frame that comes
// two or more periods after its predecessor means the camera missed the trigger of the pattern in
// between; one within half a period means a spurious trigger; no frame within the grab timeout
// (the camera's grab_timeout plus a period) means the trigger never came. Each is a detected
// fault that names the pattern (index and role), never a shifted sequence: the patterns before it
// are kept, the device is stopped, and the whole sequence runs again (the device starts at its
// first pattern) and only the missing patterns are stored, up to max_retries times. After a
// missing frame the projector is asked whether it is still there (CheckAlive), so an unplugged
// device is named in the error. Then Capture throws slshadow::Error naming the pattern, the camera
// and why (the first run's cause first), and the staging folder stays resumable: `--resume`
// runs the sequence again and stores the missing patterns only.
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
// max_latency and sleep_until do not; auto_exposure must be off. The summary's mean_pattern_ms is the time from
// Start to the last frame of a run over its patterns; CameraCaptureStats::missed_triggers counts
// the faults of each camera. Throws like capture::Capture.
CaptureSummary CapturePatternSequence(const Rig& rig, const PatternSpec& spec, const std::vector<CaptureCamera>& cameras,
                                      SequenceProjector& projector, const std::filesystem::path& out,
                                      const SequencerOptions& options);

}  // namespace slshadow::capture
