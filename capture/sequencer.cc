#include "capture/sequencer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>

#include "capture/internal/sequence_checks.h"
#include "capture/internal/store_queue.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"
#include "patterns/codec.h"

namespace slshadow::capture {
namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

namespace {
using namespace internal;  // NOLINT: the sequencer's own internal pieces

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
            Projector& projector, const fs::path& out, const SequencerOptions& options)
      : rig_(rig),
        spec_(spec),
        projector_(projector),
        out_(out),
        options_(options),
        cameras_(cameras) {
    options_.Check();
    spec_.Check();
    CheckProjectorSize(rig, spec, "pattern spec", "rig '" + rig.name + "'");
    CheckCaptureCameras(rig, cameras);
    for (const auto& c : cameras) {
      CameraState s;
      s.cam = &c;
      s.settings = c.settings;
      s.full_scale = FullScale(c.settings.pixel_format);
      s.expected_depth = BitDepthOf(c.settings.pixel_format) == 8 ? CV_8U : CV_16U;
      const RigDevice& dev = rig.Camera(c.name);
      s.stride = SampleStride(options_.validation, dev.model.width, dev.model.height);
      states_.push_back(std::move(s));
    }
    // Rig camera order: the order frames are triggered, grabbed and reported.
    std::sort(states_.begin(), states_.end(), [&](const CameraState& a, const CameraState& b) {
      return rig.CameraIndex(a.cam->name) < rig.CameraIndex(b.cam->name);
    });
    images_ = GeneratePatterns(spec_);
    model_ = std::make_unique<SequenceModel>(spec_, images_);
    half_range_ = 0.5 * (spec_.intensity_max - spec_.intensity_min);
    validate_ = options_.validate;
    if (validate_ && projector_.Info().width <= 0) {
      // No projector shows the patterns. Frames replayed from a recorded capture still hold the
      // sequence, so they are checked as a live capture's would be; any other camera would film
      // one unchanging scene pattern after pattern, almost always a mistake in the devices file.
      bool all_replay = !cameras_.empty();
      for (const auto& c : cameras_)
        all_replay = all_replay && c.camera->Info().backend == "replay";
      SLSHADOW_THROW_IF(!all_replay, "capture: the projector (backend '", projector_.Info().backend,
                        "') shows none of the pattern spec's ", spec_.NumImages(),
                        " patterns, so the frames cannot be checked against them and every image "
                        "would show the same scene: name a projector in the devices file's "
                        "projector: entry, or pass --no-validate to store the frames unchecked");
    }
    summary_.validated = validate_;
  }

  CaptureSummary Run() {
    const auto start = Clock::now();
    ResumableImageSetWriter writer(out_, rig_, PatternSpecToJson(spec_), options_.writer);
    writer_ = &writer;
    const int n = spec_.NumImages();
    summary_.out = out_;
    summary_.staging = writer.staging_dir();
    summary_.resumed = writer.resumed();
    summary_.patterns = n;
    summary_.images_total = n * static_cast<int>(states_.size());
    for (const auto& s : states_) {
      for (int k = 0; k < n; ++k) summary_.images_before += writer.Has(s.cam->name, k);
    }
    // The projector gets the sequence plus a white and a black frame for the exposure assistant.
    std::vector<cv::Mat> loaded = images_;
    loaded.push_back(cv::Mat(spec_.projector_height, spec_.projector_width, CV_8UC1,
                             cv::Scalar(spec_.intensity_max)));
    loaded.push_back(cv::Mat(spec_.projector_height, spec_.projector_width, CV_8UC1,
                             cv::Scalar(spec_.intensity_min)));
    projector_.Load(loaded);
    for (auto& s : states_) {
      s.cam->camera->Configure(s.settings);
      s.info = s.cam->camera->Info();
      s.stats.serial = s.info.serial;
      s.cam->camera->Start();
    }
    const CamerasStopper stop_cameras(cameras_);
    ChooseExposures(writer);
    for (auto& s : states_) {
      s.stats.exposure_us = s.settings.exposure_us.value_or(0);
      s.info = s.cam->camera->Info();
    }
    nlohmann::json start_note = {{"started", UtcTimestamp()},
                                 {"resumed", writer.resumed()},
                                 {"validate", validate_},
                                 {"projector", projector_.Info().backend},
                                 {"latency_us", projector_.Latency().count()},
                                 {"settle_us", options_.settle.count()}};
    for (const auto& s : states_) {
      start_note["cameras"][s.cam->name] = CameraNote(s.info, s.settings, s.stats.exposure_us);
    }
    if (!summary_.auto_exposure_us.empty())
      start_note["auto_exposure_us"] = summary_.auto_exposure_us;
    writer.AppendSession(start_note);

    StoreQueue store(writer, static_cast<size_t>(options_.store_queue_images));
    std::optional<Progress> progress;
    const int todo_patterns = [&] {
      int t = 0;
      for (int k = 0; k < n; ++k) t += !AllStored(k);
      return t;
    }();
    if (options_.progress) progress.emplace("capture", todo_patterns);
    int acquired_patterns = 0;
    const auto acquire_start = Clock::now();
    const double acquire_cpu_start = ThreadCpuSeconds();
    device_time_ = {};
    device_cpu_s_ = 0;
    std::string failure;
    try {
      for (const auto& group : model_->groups) {
        bool all = true;
        for (int i = 0; i < group.size; ++i) all = all && AllStored(group.first + i);
        if (all) continue;
        if (Stopped()) {
          summary_.interrupted = true;
          break;
        }
        if (!AcquireGroup(group, store)) {
          summary_.interrupted = true;
          break;
        }
        acquired_patterns += group.size;
        if (progress) progress->Advance(group.size);
      }
    } catch (const Error& e) {
      failure = e.what();
    }
    progress.reset();
    const double acquire_s = std::chrono::duration<double>(Clock::now() - acquire_start).count();
    const double acquire_cpu_s = ThreadCpuSeconds() - acquire_cpu_start;
    std::string storage_error;
    try {
      store.Finish();
    } catch (const std::exception& e) {
      storage_error = e.what();
    }
    summary_.images_stored = store.stored();
    if (failure.empty() && storage_error.empty() && !summary_.interrupted && validate_ &&
        model_->references_last) {
      // White and black came last: now every Gray pair can be judged against them, and a pair
      // that fails (a stale frame the pattern-to-pattern check could not see) is taken again.
      try {
        StoreQueue again(writer, static_cast<size_t>(options_.store_queue_images));
        if (!RecheckPairs(again)) summary_.interrupted = true;
        again.Finish();
        summary_.images_stored += again.stored();
      } catch (const std::exception& e) {
        failure = e.what();
      }
    }
    summary_.wait_after_show_us = std::chrono::duration<double, std::micro>(BaseWait()).count();
    summary_.learned_latency_us = std::chrono::duration<double, std::micro>(learned_extra_).count();
    if (learned_extra_.count() > 0) {
      std::fprintf(stderr,
                   "warning: frames showed the previous pattern after the projector's latency "
                   "(%.1f ms) + settle (%.1f ms); "
                   "the capture waited %.1f ms longer after each Show from then on. Measure the "
                   "latency with "
                   "`slshadow latency` and set latency_us in the devices file.\n",
                   projector_.Latency().count() / 1000.0, options_.settle.count() / 1000.0,
                   summary_.learned_latency_us / 1000.0);
    }
    summary_.mean_pattern_ms = acquired_patterns ? 1e3 * acquire_s / acquired_patterns : 0;
    summary_.overhead_ms_per_pattern =
        acquired_patterns
            ? 1e3 * (acquire_s - std::chrono::duration<double>(device_time_).count()) /
                  acquired_patterns
            : 0;
    summary_.overhead_cpu_ms_per_pattern =
        acquired_patterns ? 1e3 * (acquire_cpu_s - device_cpu_s_) / acquired_patterns : 0;
    for (auto& s : states_) {
      s.stats.stream = s.cam->camera->Statistics();
      s.stats.missing_frame_ids = s.ids.missing();
      s.stats.invalid_frame_ids = s.ids.invalid();
      summary_.cameras[s.cam->name] = s.stats;
    }
    summary_.seconds = std::chrono::duration<double>(Clock::now() - start).count();
    EndSession(writer, summary_, failure, storage_error);
    if (summary_.interrupted) return summary_;
    for (const auto& s : states_) {
      for (int k = 0; k < n; ++k) {
        SLSHADOW_THROW_IF(!writer.Has(s.cam->name, k), "capture: camera '", s.cam->name,
                          "' has no image of ", model_->Name(k), " (internal)");
      }
    }
    nlohmann::json extra = options_.extra.is_null() ? nlohmann::json::object() : options_.extra;
    extra["capture"]["sessions"] = writer.Sessions();
    if (!summary_.auto_exposure_us.empty())
      extra["capture"]["auto_exposure_us"] = summary_.auto_exposure_us;
    extra["capture"]["learned_latency_us"] = summary_.learned_latency_us;
    extra["capture"]["wait_after_show_us"] = summary_.wait_after_show_us;
    writer.SetExtra(extra);
    writer.Commit();
    summary_.complete = true;
    return summary_;
  }

 private:
  bool Stopped() const { return options_.stop && options_.stop->load(); }

  bool AllStored(int k) const {
    for (const auto& s : states_) {
      if (!writer_->Has(s.cam->name, k)) return false;
    }
    return true;
  }

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
  Clock::time_point WaitAfterShow(int attempt, Clock::time_point after = {}) {
    const auto until = std::max(last_show_ + BaseWait() + attempt * options_.retry_backoff, after);
    if (options_.sleep_until) {
      options_.sleep_until(until);
      return until;
    }
    if (until > Clock::now()) std::this_thread::sleep_until(until);
    return Clock::now();
  }

  // The latency was underestimated: a frame triggered at `fresh` (after the last Show) was the
  // first to show it. Every later Show waits that long (bounded by max_latency).
  void LearnLatency(Clock::time_point fresh) {
    const Clock::duration base = projector_.Latency() + options_.settle;
    const Clock::duration observed = fresh - last_show_ - base;
    const Clock::duration bound =
        std::max<Clock::duration>(Clock::duration{}, Clock::duration(options_.max_latency) - base);
    learned_extra_ = std::min(std::max(learned_extra_, observed), bound);
  }

  // Show pattern `index` (of the loaded sequence; show = false: re-trigger what the last Show
  // asked for, the display pipeline may still be bringing it), trigger every camera, grab every
  // camera. Never a second Show of a pattern whose first is not known to be on screen: a display
  // queues Shows, so a re-Show brings back older patterns behind the pending one.
  std::vector<Frame> TriggerRound(int index, int attempt, bool show = true,
                                  Clock::time_point after = {}) {
    struct AddTime {
      Clock::time_point t0;
      double cpu0;
      Clock::duration* sum;
      double* cpu_sum;
      ~AddTime() {
        *sum += Clock::now() - t0;
        *cpu_sum += ThreadCpuSeconds() - cpu0;
      }
    } add{Clock::now(), ThreadCpuSeconds(), &device_time_, &device_cpu_s_};
    for (auto& s : states_) s.cam->camera->ExpectPattern(index);
    if (show) {
      last_show_ = projector_.Show(index);
      last_shown_ = index;
    }
    last_trigger_ = WaitAfterShow(attempt, after);
    for (auto& s : states_) {
      // Free run: frames streamed before the pattern was on are stale by construction.
      if (s.settings.trigger == TriggerMode::kFreeRun) s.cam->camera->Flush();
      s.cam->camera->Trigger();
    }
    std::vector<Frame> frames;
    frames.reserve(states_.size());
    for (auto& s : states_) frames.push_back(s.cam->camera->Grab(s.cam->grab_timeout));
    return frames;
  }

  void FlushAll() {
    const auto t0 = Clock::now();
    const double cpu0 = ThreadCpuSeconds();
    for (auto& s : states_) s.cam->camera->Flush();
    device_time_ += Clock::now() - t0;
    device_cpu_s_ += ThreadCpuSeconds() - cpu0;
  }

  const cv::Mat* Previous(CameraState& s, int k) {
    if (k == 0) return nullptr;
    if (s.prev_index != k - 1) {
      if (!writer_->Has(s.cam->name, k - 1)) return nullptr;
      s.prev = writer_->Load(s.cam->name, k - 1);
      s.prev_index = k - 1;
    }
    return &s.prev;
  }

  void EnsureReferences(CameraState& s) {
    if (s.refs.ready()) return;
    for (int r : model_->reference_frames) {
      if (s.reference_images.count(r)) continue;
      if (!writer_->Has(s.cam->name, r)) return;
      s.reference_images[r] = writer_->Load(s.cam->name, r);
    }
    if (model_->reference_frames.empty()) return;
    if (model_->white_black) {
      s.reference_images.at(model_->reference_frames[0]).convertTo(s.refs.white, CV_32F);
      s.reference_images.at(model_->reference_frames[1]).convertTo(s.refs.black, CV_32F);
    } else {
      cv::Mat hi, lo;
      for (int r : model_->reference_frames) {
        cv::Mat f;
        s.reference_images.at(r).convertTo(f, CV_32F);
        hi = hi.empty() ? f.clone() : cv::max(hi, f);
        lo = lo.empty() ? f.clone() : cv::min(lo, f);
      }
      s.refs.white = hi;
      s.refs.black = lo;
    }
    const double lit_threshold = options_.validation.lit_threshold * s.full_scale / 255.0;
    ForEachSample(s.refs.white.rows, s.refs.white.cols, s.stride, [&](int y, int x) {
      const float w = s.refs.white.at<float>(y, x), k = s.refs.black.at<float>(y, x);
      if (w - k >= lit_threshold) s.refs.samples.push_back({y, x, 0.25f * (w - k), 0.5f * (w + k)});
    });
  }

  Verdict CheckFrame(CameraState& s, int k, const Frame& f, const cv::Mat* prev_override,
                     int prev_pattern) {
    const std::string who = model_->Name(k) + ", camera '" + s.cam->name + "'";
    if (f.status == FrameStatus::kTimeout) {
      ++s.stats.timeouts;
      return {false, who + ": no frame within " + std::to_string(s.cam->grab_timeout.count()) +
                         " ms" + (f.message.empty() ? "" : " (" + f.message + ")")};
    }
    if (f.status != FrameStatus::kOk) {
      ++s.stats.damaged;
      return {false, who + ": frame " + ToString(f.status) +
                         (f.message.empty() ? "" : " (" + f.message + ")")};
    }
    const RigDevice& dev = rig_.Camera(s.cam->name);
    if (f.image.cols != dev.model.width || f.image.rows != dev.model.height ||
        f.image.type() != CV_MAKETYPE(s.expected_depth, 1)) {
      ++s.stats.damaged;
      return {false, who + ": frame of " + std::to_string(f.image.cols) + "x" +
                         std::to_string(f.image.rows) + ", " +
                         (f.image.depth() == CV_8U ? "8" : "16") + "-bit; the rig camera is " +
                         std::to_string(dev.model.width) + "x" + std::to_string(dev.model.height) +
                         ", " + ToString(s.settings.pixel_format)};
    }
    if (!validate_) return {};
    if (!prev_override && prev_pattern != k - 1)
      return {};  // out of sequence, nothing known on screen
    const double e = model_->Change(images_, half_range_, prev_pattern, k);
    const cv::Mat* prev = prev_override ? prev_override : Previous(s, k);
    if (prev == nullptr || e < options_.validation.min_pattern_change) return {};
    EnsureReferences(s);
    const double scale = s.full_scale / 255.0;
    int samples = 0;
    const double changed =
        ChangedShare(f.image, *prev, s.refs, options_.validation.lit_threshold * scale,
                     options_.validation.change_threshold * scale, s.stride, &samples);
    if (samples < options_.validation.min_samples) return {};
    const double lit =
        s.refs.ready() ? 1.0 : std::max(s.lit_estimate, options_.validation.min_lit_share_floor);
    const double needed = options_.validation.stale_ratio * e * lit;
    if (changed < needed) {
      ++s.stats.stale;
      char buf[256];
      std::snprintf(
          buf, sizeof(buf),
          ": frame nearly equal to %s: %.1f %% of the %s pixels changed, at least %.1f %% "
          "expected; the "
          "projector had not switched yet (raise latency_us or settle_us in the devices file)",
          model_->Name(prev_pattern).c_str(), 100 * changed, s.refs.ready() ? "lit" : "sampled",
          100 * needed);
      return {false, who + buf, true};
    }
    if (!s.refs.ready() && e >= 0.9) s.lit_estimate = std::max(s.lit_estimate, changed);
    return {};
  }

  // Group checks of one camera: white and black differ; a Gray bit and its inverse are
  // complementary; in the opening group (white, black, first Gray pair) the pair also lies
  // between black and white everywhere: a frame brighter than white or darker than black where
  // the patterns say otherwise means the white or black frame showed another pattern.
  Verdict CheckGroup(CameraState& s, const SequenceModel::Group& g,
                     const std::vector<const cv::Mat*>& f) {
    if (!validate_ || !g.pair) return {};
    const double scale = s.full_scale / 255.0;
    const double lit_threshold = options_.validation.lit_threshold * scale;
    const int stride = s.stride;
    char buf[320];
    if (model_->frames[static_cast<size_t>(g.first)].role == FrameRole::kPhase)
      return CheckPhaseSteps(s, g, f);
    References refs;
    const FrameRole role = model_->frames[static_cast<size_t>(g.first)].role;
    size_t pair_at = 0;
    if (role == FrameRole::kWhite) {
      f[0]->convertTo(refs.white, CV_32F);
      f[1]->convertTo(refs.black, CV_32F);
      const double lit = LitShare(refs, lit_threshold, stride);
      if (lit < options_.validation.min_lit_share) {
        ++s.stats.not_complementary;
        std::snprintf(buf, sizeof(buf),
                      ": white and black frames do not differ (%.2f %% of the image lit, at least "
                      "%.2f %% expected): "
                      "the projector did not switch, or this camera sees none of its light",
                      100 * lit, 100 * options_.validation.min_lit_share);
        return {false, model_->Name(g.first) + " and " + model_->Name(g.first + 1) + ", camera '" +
                           s.cam->name + "'" + buf};
      }
      if (!g.opening) return {};
      pair_at = 2;
      int64_t count = 0, outside = 0;
      const double tolerance = lit_threshold;
      for (size_t i = 2; i < 4; ++i) {
        ForEachSample(f[i]->rows, f[i]->cols, stride, [&](int y, int x) {
          const double v =
              f[i]->depth() == CV_8U ? f[i]->at<uint8_t>(y, x) : f[i]->at<uint16_t>(y, x);
          ++count;
          outside += v > refs.white.at<float>(y, x) + tolerance ||
                     v < refs.black.at<float>(y, x) - tolerance;
        });
      }
      const double share = count ? static_cast<double>(outside) / static_cast<double>(count) : 0.0;
      if (outside >= options_.validation.min_samples &&
          share > 1 - options_.validation.min_complementary) {
        ++s.stats.not_complementary;
        std::snprintf(buf, sizeof(buf),
                      ": %.1f %% of the pixels of %s / %s are brighter than the white frame or "
                      "darker than the black "
                      "frame: the white or black frame showed another pattern (raise latency_us or "
                      "settle_us)",
                      100 * share, model_->Name(g.first + 2).c_str(),
                      model_->Name(g.first + 3).c_str());
        return {false, model_->Name(g.first) + " and " + model_->Name(g.first + 1) + ", camera '" +
                           s.cam->name + "'" + buf};
      }
    } else {
      EnsureReferences(s);
      if (!s.refs.ready()) return {};
      refs = s.refs;
    }
    int samples = 0;
    const double q =
        ComplementaryShare(*f[pair_at], *f[pair_at + 1], refs, lit_threshold, stride, &samples);
    if (samples < options_.validation.min_samples) return {};
    s.stats.min_complementary_share = std::min(s.stats.min_complementary_share, q);
    ++s.stats.pair_checks;
    if (q >= options_.validation.min_complementary) return {};
    ++s.stats.not_complementary;
    std::snprintf(
        buf, sizeof(buf),
        ": not complementary: %.1f %% of %d decisive pixels are on opposite sides, at least %.1f "
        "%% expected; "
        "one of them shows another pattern (raise latency_us or settle_us in the devices file)",
        100 * q, samples, 100 * options_.validation.min_complementary);
    const int k = g.first + static_cast<int>(pair_at);
    return {false, model_->Name(k) + " and " + model_->Name(k + 1) + ", camera '" + s.cam->name +
                       "'" + buf};
  }

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
                                                   std::vector<std::string>* errors) {
    bool saw_stale = false;
    for (int attempt = 0; attempt <= options_.max_retries; ++attempt) {
      if (attempt > 0) {
        FlushAll();
        ++summary_.retries;
      }
      *attempts_used = attempt;
      std::vector<Frame> frames = TriggerRound(k, attempt + extra_wait, /*show=*/attempt == 0);
      errors->clear();
      bool stale = false;
      for (size_t c = 0; c < states_.size(); ++c) {
        CameraState& s = states_[c];
        const Frame& f = frames[c];
        if (f.status != FrameStatus::kTimeout && f.status != FrameStatus::kAborted) {
          ++s.stats.frames_grabbed;
          if (s.settings.trigger != TriggerMode::kFreeRun) s.ids.Next(f.frame_id);
        }
        const Verdict v = CheckFrame(s, k, f, prev[c], prev_pattern);
        if (!v.ok) errors->push_back(v.why);
        stale = stale || v.stale;
      }
      saw_stale = saw_stale || stale;
      if (errors->empty()) {
        if (saw_stale) LearnLatency(last_trigger_);
        return frames;
      }
    }
    return std::nullopt;
  }

  // After a failed group, before anything is shown again: triggers every camera until two rounds,
  // at least the current wait apart, give equal frames, so the display is known to show the last
  // Show and nothing is pending behind it. Returns those frames (of last_shown_), or nullopt
  // (and *errors) when it did not settle within max_retries + 2 rounds.
  std::optional<std::vector<Frame>> Settle(int group_attempt, std::vector<std::string>* errors) {
    std::vector<Frame> before;
    for (int round = 0; round <= options_.max_retries + 1; ++round) {
      FlushAll();
      const Clock::time_point earliest =
          round == 0
              ? Clock::time_point{}
              : last_trigger_ + std::max<Clock::duration>(BaseWait(), options_.retry_backoff);
      std::vector<Frame> frames =
          TriggerRound(last_shown_, group_attempt + round, /*show=*/false, earliest);
      errors->clear();
      for (size_t c = 0; c < states_.size(); ++c) {
        CameraState& s = states_[c];
        const Frame& f = frames[c];
        if (f.status != FrameStatus::kTimeout && f.status != FrameStatus::kAborted) {
          ++s.stats.frames_grabbed;
          if (s.settings.trigger != TriggerMode::kFreeRun) s.ids.Next(f.frame_id);
        }
        if (f.status == FrameStatus::kTimeout) ++s.stats.timeouts;
        if (!f.ok() && f.status != FrameStatus::kTimeout) ++s.stats.damaged;
        if (!f.ok())
          errors->push_back("settling on " + model_->Name(last_shown_) + ", camera '" +
                            s.cam->name + "': frame " + ToString(f.status) +
                            (f.message.empty() ? "" : " (" + f.message + ")"));
      }
      if (!errors->empty()) {
        before.clear();
        continue;
      }
      bool equal = !before.empty();
      for (size_t c = 0; equal && c < states_.size(); ++c) {
        const CameraState& s = states_[c];
        if (frames[c].image.size() != before[c].image.size() ||
            frames[c].image.type() != before[c].image.type()) {
          equal = false;
          break;
        }
        const double scale = s.full_scale / 255.0;
        int samples = 0;
        const double changed = ChangedShare(
            frames[c].image, before[c].image, s.refs, options_.validation.lit_threshold * scale,
            options_.validation.change_threshold * scale, s.stride, &samples);
        equal = changed <= kSettledChange;
      }
      if (equal) return frames;
      if (!before.empty()) LearnLatency(last_trigger_);  // the display was still changing
      before = std::move(frames);
    }
    errors->push_back("the display did not settle on " + model_->Name(last_shown_) + " within " +
                      std::to_string(options_.max_retries + 2) +
                      " frames (raise latency_us or settle_us)");
    return std::nullopt;
  }
  static constexpr double kSettledChange =
      0.01;  // share of samples allowed to change between settled frames

  void AcceptReference(CameraState& s, int k, const cv::Mat& image) {
    if (std::find(model_->reference_frames.begin(), model_->reference_frames.end(), k) ==
        model_->reference_frames.end())
      return;
    s.reference_images[k] = image;
  }

  // Acquires, checks and queues for storage one group; false when stopped before it was taken.
  bool AcquireGroup(const SequenceModel::Group& g, StoreQueue& store) {
    std::vector<std::vector<Frame>> frames(static_cast<size_t>(g.size));
    std::vector<int> retries(static_cast<size_t>(g.size), 0);
    std::vector<std::string> errors;
    // The first attempt's errors name the cause (e.g. the pattern the display never took); those
    // of the last group attempt follow when they differ.
    std::vector<std::string> first_errors;
    const auto fail = [&] {
      const std::string first = Join(first_errors), last = Join(errors);
      SLSHADOW_THROW("capture failed after ", options_.max_retries + 1,
                     " attempts: ", first.empty() ? last : first,
                     first.empty() || first == last ? "" : "; taken again as a group: " + last);
    };
    for (int group_attempt = 0; group_attempt <= options_.max_retries; ++group_attempt) {
      if (group_attempt > 0) ++summary_.retries;
      // Taken again (or out of sequence): first wait until the display shows the last Show with
      // nothing pending, so that the first frame can be compared with what is on screen.
      std::optional<std::vector<Frame>> settled;
      if ((group_attempt > 0 || out_of_sequence_) && last_shown_ >= 0) {
        if (group_attempt > 0)
          learned_extra_ = std::min<Clock::duration>(
              std::max<Clock::duration>(2 * learned_extra_, options_.retry_backoff),
              std::max<Clock::duration>(
                  Clock::duration{},
                  Clock::duration(options_.max_latency) - projector_.Latency() - options_.settle));
        settled = Settle(group_attempt, &errors);
        if (!settled) fail();
      }
      bool taken = true;
      for (int i = 0; i < g.size; ++i) {
        const int k = g.first + i;
        if (Stopped()) return false;  // between frames; a pair is taken whole or not at all
        std::vector<const cv::Mat*> prev(states_.size(), nullptr);
        int prev_pattern = k - 1;
        if (i > 0) {
          for (size_t c = 0; c < states_.size(); ++c)
            prev[c] = &frames[static_cast<size_t>(i - 1)][c].image;
        } else if (settled) {
          for (size_t c = 0; c < states_.size(); ++c) prev[c] = &(*settled)[c].image;
          prev_pattern = last_shown_;
        } else if (out_of_sequence_) {
          prev_pattern = -1;  // nothing shown by this run yet: no stale check
        }
        int attempts = 0;
        auto got = AcquirePattern(k, prev, prev_pattern, group_attempt, &attempts, &errors);
        retries[static_cast<size_t>(i)] += attempts;
        if (!got) {
          // The first frame of a group has only accepted frames before it: its failure is its own.
          // A failing second frame may accuse the first (a stale white looks like black): retake
          // both.
          if (i == 0 || !g.pair) fail();
          taken = false;
          break;
        }
        frames[static_cast<size_t>(i)] = std::move(*got);
      }
      if (taken && g.pair) {
        for (size_t c = 0; c < states_.size(); ++c) {
          std::vector<const cv::Mat*> mine;
          for (int i = 0; i < g.size; ++i) mine.push_back(&frames[static_cast<size_t>(i)][c].image);
          const Verdict v = CheckGroup(states_[c], g, mine);
          if (!v.ok) errors.push_back(v.why);
        }
      }
      if (taken && errors.empty()) {
        for (int i = 0; i < g.size; ++i) retries[static_cast<size_t>(i)] += group_attempt;
        break;
      }
      if (group_attempt == 0) first_errors = errors;
      if (group_attempt == options_.max_retries) fail();
    }
    for (int i = 0; i < g.size; ++i) {
      const int k = g.first + i;
      for (size_t c = 0; c < states_.size(); ++c) {
        CameraState& s = states_[c];
        Frame& f = frames[static_cast<size_t>(i)][c];
        ImageRecord r = RecordOf(*s.cam, s.info, s.settings, k, f, retries[static_cast<size_t>(i)]);
        s.prev = f.image;
        s.prev_index = k;
        AcceptReference(s, k, f.image);
        ++s.stats.frames_stored;
        store.Push(std::move(r), f.image);
      }
    }
    return true;
  }

  // The first period's N >= 4 phase steps: per lit pixel, I_n = A + C cos(2 pi n / N) +
  // S sin(2 pi n / N) fitted by least squares; a frame that shows another pattern leaves a
  // residual (rms over the steps) above a third of the modulation B = sqrt(C^2 + S^2) at many
  // pixels. (Three steps fit exactly: nothing to check.)
  Verdict CheckPhaseSteps(CameraState& s, const SequenceModel::Group& g,
                          const std::vector<const cv::Mat*>& f) {
    const int n = g.size;
    const double lit_threshold = options_.validation.lit_threshold * s.full_scale / 255.0;
    std::vector<double> c(static_cast<size_t>(n)), sn(static_cast<size_t>(n));
    for (int i = 0; i < n; ++i) {
      c[static_cast<size_t>(i)] = std::cos(2 * M_PI * i / n);
      sn[static_cast<size_t>(i)] = std::sin(2 * M_PI * i / n);
    }
    int64_t count = 0, bad = 0;
    std::vector<double> v(static_cast<size_t>(n));
    ForEachSample(f[0]->rows, f[0]->cols, s.stride, [&](int y, int x) {
      double a = 0, cc = 0, ss = 0;
      for (int i = 0; i < n; ++i) {
        const cv::Mat& m = *f[static_cast<size_t>(i)];
        v[static_cast<size_t>(i)] = m.depth() == CV_8U ? m.at<uint8_t>(y, x) : m.at<uint16_t>(y, x);
        a += v[static_cast<size_t>(i)];
        cc += v[static_cast<size_t>(i)] * c[static_cast<size_t>(i)];
        ss += v[static_cast<size_t>(i)] * sn[static_cast<size_t>(i)];
      }
      a /= n;
      cc *= 2.0 / n;
      ss *= 2.0 / n;
      const double b = std::sqrt(cc * cc + ss * ss);
      if (2 * b < lit_threshold) return;
      double r2 = 0;
      for (int i = 0; i < n; ++i) {
        const double e = v[static_cast<size_t>(i)] - a - cc * c[static_cast<size_t>(i)] -
                         ss * sn[static_cast<size_t>(i)];
        r2 += e * e;
      }
      ++count;
      bad += std::sqrt(r2 / n) > b / 3;
    });
    const double share = count ? static_cast<double>(bad) / static_cast<double>(count) : 0.0;
    if (count < options_.validation.min_samples ||
        share <= 1 - options_.validation.min_complementary)
      return {};
    ++s.stats.not_complementary;
    char buf[320];
    std::snprintf(buf, sizeof(buf),
                  ": the %d phase steps do not fit one sinusoid at %.1f %% of %lld modulated "
                  "pixels: one of them shows "
                  "another pattern (raise latency_us or settle_us in the devices file)",
                  n, 100 * share, static_cast<long long>(count));
    return {false, model_->Name(g.first) + " .. " + model_->Name(g.first + n - 1) + ", camera '" +
                       s.cam->name + "'" + buf};
  }

  // Judges every stored Gray pair against the references (white and black last) and takes a
  // failing pair again; false when stopped.
  bool RecheckPairs(StoreQueue& store) {
    for (auto& s : states_) {
      EnsureReferences(s);
      if (!s.refs.ready()) return true;
    }
    for (const auto& g : model_->groups) {
      if (!g.pair || model_->frames[static_cast<size_t>(g.first)].role != FrameRole::kGrayBit)
        continue;
      bool bad = false;
      for (auto& s : states_) {
        const cv::Mat a = writer_->Load(s.cam->name, g.first),
                      b = writer_->Load(s.cam->name, g.first + 1);
        bad = !CheckGroup(s, g, {&a, &b}).ok || bad;
      }
      if (!bad) continue;
      // The projector showed other patterns since: the first frame has no previous one to be
      // compared with; the pair check against the references judges both.
      out_of_sequence_ = true;
      const bool taken = AcquireGroup(g, store);
      out_of_sequence_ = false;
      if (!taken) return false;
    }
    return true;
  }

  // Exposure assistant: per camera, from the white frame, so that the brightest 1 % of the lit
  // area sits at target_fraction of full scale. A resumed capture reuses the journaled choice.
  void ChooseExposures(ResumableImageSetWriter& writer) {
    if (!options_.auto_exposure) return;
    for (const auto& session : writer.Sessions()) {
      if (!session.contains("auto_exposure_us")) continue;
      for (auto& s : states_) {
        if (session["auto_exposure_us"].contains(s.cam->name)) {
          summary_.auto_exposure_us[s.cam->name] =
              session["auto_exposure_us"][s.cam->name].get<double>();
        }
      }
    }
    if (summary_.auto_exposure_us.size() == states_.size()) {
      for (auto& s : states_) SetExposure(s, summary_.auto_exposure_us.at(s.cam->name));
      return;
    }
    summary_.auto_exposure_us.clear();
    const AutoExposureOptions& o = options_.auto_exposure_options;
    const int white = spec_.NumImages(), black = spec_.NumImages() + 1;
    const bool lit_by_projector = projector_.Info().width > 0;
    std::vector<cv::Mat> dark(states_.size());
    if (lit_by_projector) {
      std::vector<Frame> frames = TriggerRound(black, 0);
      for (size_t c = 0; c < states_.size(); ++c) {
        SLSHADOW_THROW_IF(!frames[c].ok(), "auto exposure: camera '", states_[c].cam->name,
                          "': black frame ", ToString(frames[c].status), " ", frames[c].message);
        frames[c].image.convertTo(dark[c], CV_32F);
      }
    }
    std::vector<bool> done(states_.size(), false);
    for (auto& s : states_) {
      if (!s.settings.exposure_us) SetExposure(s, 10000);
    }
    for (int it = 0; it < o.max_iterations; ++it) {
      std::vector<Frame> frames = TriggerRound(white, 0);
      bool all_done = true;
      for (size_t c = 0; c < states_.size(); ++c) {
        if (done[c]) continue;
        CameraState& s = states_[c];
        SLSHADOW_THROW_IF(!frames[c].ok(), "auto exposure: camera '", s.cam->name,
                          "': white frame ", ToString(frames[c].status), " ", frames[c].message);
        cv::Mat w;
        frames[c].image.convertTo(w, CV_32F);
        std::vector<float> lit;
        const double lit_threshold = options_.validation.lit_threshold * s.full_scale / 255.0;
        for (int y = 0; y < w.rows; y += 2) {
          const float* pw = w.ptr<float>(y);
          const float* pd = dark[c].empty() ? nullptr : dark[c].ptr<float>(y);
          for (int x = 0; x < w.cols; x += 2) {
            if (!pd || pw[x] - pd[x] >= lit_threshold || pw[x] >= s.full_scale)
              lit.push_back(pw[x]);
          }
        }
        const double exposure = *s.settings.exposure_us;
        double next = exposure;
        if (lit.empty()) {
          next = exposure * 4;  // nothing lit yet: much longer
        } else {
          const size_t at = std::min(
              lit.size() - 1, static_cast<size_t>(o.percentile * static_cast<double>(lit.size())));
          std::nth_element(lit.begin(), lit.begin() + static_cast<std::ptrdiff_t>(at), lit.end());
          const double level = lit[at] / s.full_scale;
          if (std::abs(level - o.target_fraction) <= o.tolerance) {
            done[c] = true;
            summary_.auto_exposure_us[s.cam->name] = exposure;
            continue;
          }
          next = level >= 0.999
                     ? exposure * 0.5
                     : exposure * std::clamp(o.target_fraction / std::max(level, 1e-3), 0.25, 4.0);
        }
        next = std::clamp(next, o.min_exposure_us, o.max_exposure_us);
        if (next == exposure) {  // at a bound: take it
          done[c] = true;
          summary_.auto_exposure_us[s.cam->name] = exposure;
          continue;
        }
        SetExposure(s, next);
        all_done = false;
      }
      if (all_done) break;
    }
    for (size_t c = 0; c < states_.size(); ++c) {
      if (!done[c]) {
        summary_.auto_exposure_us[states_[c].cam->name] = *states_[c].settings.exposure_us;
      }
    }
  }

  void SetExposure(CameraState& s, double exposure_us) {
    s.cam->camera->Stop();
    s.settings.exposure_us = exposure_us;
    s.cam->camera->Configure(s.settings);
    s.cam->camera->Start();
  }

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

}  // namespace

CaptureSummary Capture(const Rig& rig, const PatternSpec& spec,
                       const std::vector<CaptureCamera>& cameras, Projector& projector,
                       const fs::path& out, const SequencerOptions& options) {
  Sequencer sequencer(rig, spec, cameras, projector, out, options);
  return sequencer.Run();
}

}  // namespace slshadow::capture
