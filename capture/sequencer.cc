#include "capture/sequencer.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>

#include "capture/internal/sequencer_impl.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"
#include "patterns/codec.h"

namespace slshadow::capture {
namespace fs = std::filesystem;

namespace internal {

Sequencer::Sequencer(const Rig& rig, const PatternSpec& spec,
                     const std::vector<CaptureCamera>& cameras, Projector& projector,
                     const fs::path& out, const SequencerOptions& options)
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
    for (const auto& c : cameras_) all_replay = all_replay && c.camera->Info().backend == "replay";
    SLSHADOW_THROW_IF(!all_replay, "capture: the projector (backend '", projector_.Info().backend,
                      "') shows none of the pattern spec's ", spec_.NumImages(),
                      " patterns, so the frames cannot be checked against them and every image "
                      "would show the same scene: name a projector in the devices file's "
                      "projector: entry, or pass --no-validate to store the frames unchecked");
  }
  summary_.validated = validate_;
}

CaptureSummary Sequencer::Run() {
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
      acquired_patterns ? 1e3 * (acquire_s - std::chrono::duration<double>(device_time_).count()) /
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

bool Sequencer::AllStored(int k) const {
  for (const auto& s : states_) {
    if (!writer_->Has(s.cam->name, k)) return false;
  }
  return true;
}

Clock::time_point Sequencer::WaitAfterShow(int attempt, Clock::time_point after) {
  const auto until = std::max(last_show_ + BaseWait() + attempt * options_.retry_backoff, after);
  if (options_.sleep_until) {
    options_.sleep_until(until);
    return until;
  }
  if (until > Clock::now()) std::this_thread::sleep_until(until);
  return Clock::now();
}

void Sequencer::LearnLatency(Clock::time_point fresh) {
  const Clock::duration base = projector_.Latency() + options_.settle;
  const Clock::duration observed = fresh - last_show_ - base;
  const Clock::duration bound =
      std::max<Clock::duration>(Clock::duration{}, Clock::duration(options_.max_latency) - base);
  learned_extra_ = std::min(std::max(learned_extra_, observed), bound);
}

std::vector<Frame> Sequencer::TriggerRound(int index, int attempt, bool show,
                                           Clock::time_point after) {
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

void Sequencer::FlushAll() {
  const auto t0 = Clock::now();
  const double cpu0 = ThreadCpuSeconds();
  for (auto& s : states_) s.cam->camera->Flush();
  device_time_ += Clock::now() - t0;
  device_cpu_s_ += ThreadCpuSeconds() - cpu0;
}

}  // namespace internal

CaptureSummary Capture(const Rig& rig, const PatternSpec& spec,
                       const std::vector<CaptureCamera>& cameras, Projector& projector,
                       const fs::path& out, const SequencerOptions& options) {
  internal::Sequencer sequencer(rig, spec, cameras, projector, out, options);
  return sequencer.Run();
}

}  // namespace slshadow::capture
