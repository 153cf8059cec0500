// The acquisition sequencer: drives the projector and the cameras through a pattern sequence and
// stores every accepted frame through the resumable ImageSet writer (core/image_set.h), so a
// capture interrupted by Ctrl-C, a crash or a lost camera continues with `resume`.
//
// Per pattern: Show -> wait latency + settle -> trigger every camera (stereo frames of one
// pattern come from the same trigger round) -> Grab with each camera's timeout -> validate ->
// retry (bounded) -> store. Storage runs on its own thread so PNG encoding and fsync do not
// pace the projector.
//
// Validation (only when the projector shows the patterns, i.e. its Info().width > 0), per camera,
// against what the pattern spec predicts (patterns/codec.h GeneratePatterns):
//  - the frame arrived complete (status kOk) and has the camera's size and the configured depth;
//  - stale frame: where consecutive patterns differ over the whole projector (every tile of an 8x8
//    grid changes in >= min_pattern_change of its pixels), a frame nearly equal to the previous one
//    means the projector had not switched yet: fewer than stale_ratio x expected of the lit pixels
//    changed by a quarter of the local contrast (white - black);
//  - complementary pairs: after the white and black references (or, for phase codecs, the
//    per-pixel max / min of the first phase steps), a Gray bit and its inverse must be on opposite
//    sides of (white + black) / 2 wherever both are decisive, in >= min_complementary of those
//    pixels; white and black must differ (lit area >= min_lit_share). A failing pair is taken
//    again as a whole. When white and black come first, they are taken with the first Gray pair
//    as one group, and that pair must lie between black and white (a stale white or black has
//    no predecessor to be compared with). When they come last (OpenCV order), every stored pair
//    is judged against them at the end and a failing pair is taken again.
//  Not covered: the first frame of a phase sequence has neither a predecessor nor references.
// A display queues Shows (what is on screen at t is the last Show issued before t - latency), so
// the sequencer never re-shows a pattern whose Show is not known to be on screen: a re-Show would
// bring older patterns back behind it, and relative checks could then pass with wrong frames.
// A frame that fails is triggered again without a new Show (Flush, wait latency + settle +
// learned + attempt x retry_backoff after the Show, trigger all cameras) up to max_retries times.
// A stale frame followed by a fresh one shows the latency was underestimated: the wait after every
// later Show grows to what was observed (learned, bounded by max_latency; in the summary, the
// manifest's extra.capture.learned_latency_us, and a warning to run `slshadow latency`). A pair
// (Gray bit + inverse, white + black) whose second frame or whose pair check fails is taken
// again as a whole, up to max_retries times: first the cameras are triggered until two frames a
// full wait apart are equal (the display has settled on the last Show, nothing pending), then the
// pair is shown again, its first frame checked against that settled frame. Then Capture throws
// slshadow::Error naming the pattern (index and role), the camera and why (the first attempt's
// cause first), and the staging folder stays resumable.
#pragma once

#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "capture/camera.h"
#include "capture/projector.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"

namespace slshadow::capture {

// One camera as the sequencer uses it: the rig camera it plays, the device, its settings.
struct CaptureCamera {
  std::string name;          // a camera name of the rig
  Camera* camera = nullptr;  // not owned
  CameraSettings settings;
  std::chrono::milliseconds grab_timeout{1000};
};

struct ValidationOptions {
  // Check every stride-th pixel in x and y (jittered grid); 0: chosen per camera so that about
  // target_samples pixels are checked (1920x1200: every 8th; small images: every pixel).
  int stride_px = 0;
  int target_samples = 32768;
  double min_pattern_change =
      0.25;                  // pattern pairs changing less (in some tile) are not stale-checked
  double stale_ratio = 0.3;  // stale: changed share < stale_ratio x expected change share
  // Without references: a pixel changed when |frame - previous| >= this (8-bit grey levels,
  // scaled to the camera's full scale), and the lit share is taken as at least this floor.
  double change_threshold = 16;
  double min_lit_share_floor = 0.02;
  double lit_threshold = 12;       // lit: white - black >= this (8-bit grey levels, scaled)
  double min_lit_share = 0.01;     // white vs black: at least this share of the image lit
  double min_complementary = 0.9;  // share of decisive pixels on opposite sides in a Gray pair
  int min_samples = 64;            // fewer lit / decisive samples than this: the check is skipped
  void Check() const;
};

struct AutoExposureOptions {
  double target_fraction = 0.85;  // brightest 1 % of the lit area at this fraction of full scale
  double tolerance = 0.08;        // done when within target_fraction +- tolerance
  double percentile = 0.99;       // "brightest 1 %"
  int max_iterations = 6;
  double min_exposure_us = 10, max_exposure_us = 2e6;
  void Check() const;
};

struct SequencerOptions {
  std::chrono::microseconds settle{0};  // waited after the projector's latency
  int max_retries = 3;                  // extra attempts per pattern (and per pair)
  std::chrono::microseconds retry_backoff{std::chrono::milliseconds(20)};  // extra wait per attempt
  // Upper bound of the wait after a Show the capture may learn when frames show that the
  // projector's latency was underestimated (CaptureSummary::learned_latency_us).
  std::chrono::microseconds max_latency{std::chrono::seconds(1)};
  // Check every frame against the patterns. With a projector that shows nothing (backend none)
  // Capture refuses to run validated unless every camera replays a recorded capture.
  bool validate = true;
  ValidationOptions validation;
  bool auto_exposure = false;  // exposure assistant before the sequence
  AutoExposureOptions auto_exposure_options;
  // Writer: encoding, resume, overwrite, durability (core/image_set.h).
  ResumableImageSetWriterOptions writer;
  int store_queue_images = 64;  // frames waiting for storage before Capture waits
  // Set from another thread or a signal handler to stop between frames; the capture returns
  // with interrupted = true and the staging folder resumable.
  const std::atomic<bool>* stop = nullptr;
  bool progress = true;  // progress line on stderr (core/progress.h)
  // How the sequencer waits for the projector (until latency + settle + backoff after Show).
  // Empty: std::this_thread::sleep_until. Tests pass a virtual clock shared with a test projector.
  std::function<void(std::chrono::steady_clock::time_point)> sleep_until;
  nlohmann::json extra;  // caller's provenance, stored in the manifest's extra
  void Check() const;
};

// Counters of one camera in one capture run.
struct CameraCaptureStats {
  std::string serial;
  int64_t frames_grabbed = 0;  // frames that arrived (any status)
  int64_t frames_stored = 0;
  int64_t timeouts = 0;  // Grab returned kTimeout
  int64_t damaged = 0;   // arrived with another status than kOk, or a wrong size / depth
  int64_t stale = 0;     // rejected: still showed the previous pattern
  int64_t not_complementary =
      0;  // rejected with its pair: Gray bit / inverse (or white / black) check
  int64_t missing_frame_ids = 0;  // frame ids never grabbed (16-bit ids wrap 65535 -> 1; 0 invalid)
  int64_t invalid_frame_ids = 0;  // frames with id 0
  double exposure_us = 0;         // the exposure used (auto-exposure: the value chosen)
  // Lowest share of decisive pixels on opposite sides seen in a Gray pair check (1: none made);
  // how far the accepted pairs were from the min_complementary limit.
  double min_complementary_share = 1;
  int64_t pair_checks = 0;  // Gray pair complementarity checks made (enough decisive pixels)
  // Pattern-sequence capture (capture/pattern_sequence_capture.h): frames missed or not matching
  // their pattern's trigger (missing, two periods late, a spurious one), and frames that came
  // after the last pattern of a run.
  int64_t missed_triggers = 0;
  int64_t extra_frames = 0;
  StreamStatistics stream;  // the camera's own transport counters at the end
  nlohmann::json ToJson() const;
};

struct CaptureSummary {
  std::filesystem::path out;      // the ImageSet (when complete)
  std::filesystem::path staging;  // the staging folder (when interrupted)
  bool complete = false;          // committed
  bool interrupted = false;       // stopped by options.stop; resumable
  bool resumed = false;           // continued an existing staging folder
  bool validated = false;         // frames were checked (stale, complementary); else counters are 0
  int patterns = 0;               // in the sequence
  int images_total = 0;           // patterns x cameras
  int images_before = 0;          // already stored when this run started (resume)
  int images_stored = 0;          // stored by this run
  int retries = 0;                // extra attempts, all patterns
  // The wait after a Show this capture ended with (latency + settle + what it learned from stale
  // frames); above latency_us + settle_us the configured latency was too low: measure it with
  // `slshadow latency`.
  double wait_after_show_us = 0;
  double learned_latency_us = 0;  // what the capture added to latency + settle (0: none)
  double seconds = 0;
  double mean_pattern_ms = 0;  // wall time per pattern acquired by this run
  // The sequencer's own cost per pattern acquired: wall time minus the time inside device calls
  // (projector Show, the latency / settle wait, camera Trigger, Grab, Flush): validation, frame-id
  // bookkeeping, queueing for storage (including waiting for a full storage queue).
  double overhead_ms_per_pattern = 0;
  // The same on the sequencer thread's CPU clock (what it costs where the machine is not busy
  // with other work; the wall figure above also holds the time the thread waited for a core).
  double overhead_cpu_ms_per_pattern = 0;
  std::map<std::string, CameraCaptureStats> cameras;
  std::map<std::string, double> auto_exposure_us;  // chosen exposures (auto-exposure)
  std::string BriefReport() const;
  nlohmann::json ToJson() const;
};

// Captures `spec` with `cameras` (each a rig camera) and `projector` into the ImageSet `out`.
// Throws slshadow::Error on bad arguments, on a camera or projector that refuses its settings,
// and when a pattern fails max_retries + 1 times (message: pattern, camera, why; the staging
// folder stays resumable). Returns interrupted = true when options.stop was raised.
CaptureSummary Capture(const Rig& rig, const PatternSpec& spec,
                       const std::vector<CaptureCamera>& cameras, Projector& projector,
                       const std::filesystem::path& out, const SequencerOptions& options);

// Board poses one after another (`slshadow capture --poses N`): before each pose, writes a prompt
// to `prompt` and waits for a line on `input` (Enter); pose p goes to OUT/pose_PP (two digits),
// an ImageSet each, the layout `slshadow calibrate rig --imagesets OUT/pose_*` reads. Poses
// already complete are skipped; with options.writer.resume a partial pose is continued.
struct PosesSummary {
  std::vector<CaptureSummary> poses;  // the poses captured by this run
  bool interrupted = false;
  int skipped = 0;  // already complete
};
PosesSummary CapturePoses(const Rig& rig, const PatternSpec& spec,
                          const std::vector<CaptureCamera>& cameras, Projector& projector,
                          const std::filesystem::path& out, int num_poses,
                          const SequencerOptions& options, std::istream& input,
                          std::ostream& prompt);
// OUT/pose_PP.
std::filesystem::path PoseDir(const std::filesystem::path& out, int pose);

// Frame-id bookkeeping: counts ids that were never seen between consecutive frames. GigE Vision
// ids are 16-bit, 0 is invalid and 65535 is followed by 1; larger ids count up without wrapping.
class FrameIdTracker {
 public:
  // Returns the number of ids skipped before `id` (0 for the first frame, an invalid id or a
  // repeated id).
  int64_t Next(uint64_t id);
  int64_t missing() const { return missing_; }
  int64_t invalid() const { return invalid_; }

 private:
  bool has_last_ = false;
  uint64_t last_ = 0;
  int64_t missing_ = 0, invalid_ = 0;
};

}  // namespace slshadow::capture
