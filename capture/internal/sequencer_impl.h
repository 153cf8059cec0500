// The sequencer behind capture::Capture (capture/sequencer.h), one class in three files:
// sequencer.cc (the run: show, wait, trigger, grab, store, and the timing it learns),
// sequencer_validation.cc (each frame and each group of frames checked against the patterns, the
// retries, settling after a fault) and sequencer_exposure.cc (the exposure assistant). Included
// only by those files.
#pragma once

#include <chrono>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "capture/internal/sequence_checks.h"
#include "capture/internal/store_queue.h"
#include "capture/sequencer.h"
#include "core/image_set.h"

namespace slshadow::capture::internal {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

struct CameraState {
  const CaptureCamera* cam = nullptr;
  int stride = 1;  // validation sampling stride for this camera's image size
  CameraInfo info;
  CameraSettings settings;
  double full_scale = 255;
  int expected_depth = CV_8U;
  cv::Mat prev;  // accepted frame of pattern prev_index
  int prev_index = -1;
  References refs;
  std::map<int, cv::Mat> reference_images;  // accepted frames of the reference patterns
  double lit_estimate = 0;  // without references: largest changed share seen on a full-change pair
  FrameIdTracker ids;
  CameraCaptureStats stats;
};

struct Verdict {
  bool ok = true;
  std::string why;
  bool stale = false;  // the frame still showed the pattern before: the display had not switched
};

class Sequencer {
 public:
  Sequencer(const Rig& rig, const PatternSpec& spec, const std::vector<CaptureCamera>& cameras,
            Projector& projector, const fs::path& out, const SequencerOptions& options);

  CaptureSummary Run();

 private:
  bool Stopped() const { return options_.stop && options_.stop->load(); }

  bool AllStored(int k) const;

  // Frames of pattern k for every camera from one trigger round; each verdict per camera.
  struct Round {
    std::vector<Frame> frames;
    std::vector<Verdict> verdicts;
    bool ok = true;
  };

  // The wait after a Show before the cameras are triggered: the projector's latency, the settle
  // time, and what this capture learned of an underestimated latency.
  Clock::duration BaseWait() const {
    return projector_.Latency() + options_.settle + learned_extra_;
  }

  // Waits until the last Show + BaseWait() + attempt x retry_backoff (and at least `after`);
  // returns the time waited for (the trigger time).
  Clock::time_point WaitAfterShow(int attempt, Clock::time_point after = {});

  // The latency was underestimated: a frame triggered at `fresh` (after the last Show) was the
  // first to show it. Every later Show waits that long (bounded by max_latency).
  void LearnLatency(Clock::time_point fresh);

  // Show pattern `index` (of the loaded sequence; show = false: re-trigger what the last Show
  // asked for, the display pipeline may still be bringing it), trigger every camera, grab every
  // camera. Never a second Show of a pattern whose first is not known to be on screen: a display
  // queues Shows, so a re-Show brings back older patterns behind the pending one.
  std::vector<Frame> TriggerRound(int index, int attempt, bool show = true,
                                  Clock::time_point after = {});

  void FlushAll();

  const cv::Mat* Previous(CameraState& s, int k);

  void EnsureReferences(CameraState& s);

  Verdict CheckFrame(CameraState& s, int k, const Frame& f, const cv::Mat* prev_override,
                     int prev_pattern);

  // Group checks of one camera: white and black differ; a Gray bit and its inverse are
  // complementary; in the opening group (white, black, first Gray pair) the pair also lies
  // between black and white everywhere: a frame brighter than white or darker than black where
  // the patterns say otherwise means the white or black frame showed another pattern.
  Verdict CheckGroup(CameraState& s, const SequenceModel::Group& g,
                     const std::vector<const cv::Mat*>& f);

  static std::string Join(const std::vector<std::string>& errors) {
    std::string all;
    for (const auto& e : errors) all += (all.empty() ? "" : "; ") + e;
    return all;
  }

  // Acquires pattern k for every camera, with retries; nullopt (and *errors) when every attempt
  // failed. prev: per camera the frame of prev_pattern to compare with (nullptr: the stored frame
  // of k-1). Pattern k is shown once: a stale, missing or damaged frame is triggered again after a
  // longer wait, never re-shown (see TriggerRound). A stale frame followed by a fresh one teaches
  // the capture its real latency (LearnLatency).
  std::optional<std::vector<Frame>> AcquirePattern(int k, const std::vector<const cv::Mat*>& prev,
                                                   int prev_pattern, int extra_wait,
                                                   int* attempts_used,
                                                   std::vector<std::string>* errors);

  // After a failed group, before anything is shown again: triggers every camera until two rounds,
  // at least the current wait apart, give equal frames, so the display is known to show the last
  // Show and nothing is pending behind it. Returns those frames (of last_shown_), or nullopt
  // (and *errors) when it did not settle within max_retries + 2 rounds.
  std::optional<std::vector<Frame>> Settle(int group_attempt, std::vector<std::string>* errors);
  static constexpr double kSettledChange =
      0.01;  // share of samples allowed to change between settled frames

  void AcceptReference(CameraState& s, int k, const cv::Mat& image);

  // Acquires, checks and queues for storage one group; false when stopped before it was taken.
  bool AcquireGroup(const SequenceModel::Group& g, StoreQueue& store);

  // The first period's N >= 4 phase steps: per lit pixel, I_n = A + C cos(2 pi n / N) +
  // S sin(2 pi n / N) fitted by least squares; a frame that shows another pattern leaves a
  // residual (rms over the steps) above a third of the modulation B = sqrt(C^2 + S^2) at many
  // pixels. (Three steps fit exactly: nothing to check.)
  Verdict CheckPhaseSteps(CameraState& s, const SequenceModel::Group& g,
                          const std::vector<const cv::Mat*>& f);

  // Judges every stored Gray pair against the references (white and black last) and takes a
  // failing pair again; false when stopped.
  bool RecheckPairs(StoreQueue& store);

  // Exposure assistant: per camera, from the white frame, so that the brightest 1 % of the lit
  // area sits at target_fraction of full scale. A resumed capture reuses the journaled choice.
  void ChooseExposures(ResumableImageSetWriter& writer);

  void SetExposure(CameraState& s, double exposure_us);

  const Rig& rig_;
  PatternSpec spec_;
  Projector& projector_;
  fs::path out_;
  SequencerOptions options_;
  std::vector<CameraState> states_;
  const std::vector<CaptureCamera>& cameras_;  // the caller's, alive for the capture
  std::vector<cv::Mat> images_;
  std::unique_ptr<SequenceModel> model_;
  bool validate_ = true;
  Clock::duration
      device_time_{};        // inside device calls (see CaptureSummary::overhead_ms_per_pattern)
  double device_cpu_s_ = 0;  // the same on the thread's CPU clock
  bool out_of_sequence_ =
      false;  // re-taking a pair out of sequence: settle first, compare with what is on screen
  double half_range_ = 127.5;         // half the pattern intensity range (SequenceModel::Change)
  Clock::time_point last_show_{};     // when the last Show returned
  int last_shown_ = -1;               // its pattern
  Clock::time_point last_trigger_{};  // when the last trigger round was triggered
  Clock::duration
      learned_extra_{};  // wait added to latency + settle after a stale frame (LearnLatency)
  ResumableImageSetWriter* writer_ = nullptr;
  CaptureSummary summary_;
};

}  // namespace slshadow::capture::internal
