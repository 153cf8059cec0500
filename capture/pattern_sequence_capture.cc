#include "capture/pattern_sequence_capture.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <optional>
#include <thread>

#include "capture/internal/sequence_checks.h"
#include "capture/internal/store_queue.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"
#include "patterns/codec.h"

namespace slshadow::capture {
namespace fs = std::filesystem;

namespace {
using namespace internal;  // NOLINT: the sequencers' shared internal pieces
using Clock = std::chrono::steady_clock;
using SysClock = std::chrono::system_clock;
constexpr std::chrono::microseconds kArmTime{100000};

struct SequenceCamera {
  const CaptureCamera* cam = nullptr;
  CameraInfo info;
  int stride = 1;
  double full_scale = 255;
  int expected_depth = CV_8U;
  FrameIdTracker ids;
  CameraCaptureStats stats;
  std::vector<char> queued;                 // [pattern]: stored before or queued for storage
  std::map<int, cv::Mat> reference_images;  // accepted frames of the reference patterns
};

// One run of the device's sequence: the frames of the patterns before the first fault.
struct SequenceRun {
  std::vector<std::vector<Frame>> frames;  // [pattern][camera], patterns 0 .. size() - 1
  std::string fault;                       // empty: every pattern matched
  bool stopped = false;                    // options.stop was raised
  double seconds = 0;                      // Start to the last frame grabbed
};

std::string Ms(double seconds) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f ms", 1e3 * seconds);
  return buf;
}

class PatternSequenceCapture {
 public:
  PatternSequenceCapture(const Rig& rig, const PatternSpec& spec,
                         const std::vector<CaptureCamera>& cameras, SequenceProjector& projector,
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
    SLSHADOW_THROW_IF(options_.auto_exposure,
                      "capture: auto exposure is not available when the projector runs the ",
                      "pattern sequence itself; set exposure_us per camera");
    CheckCaptureCameras(rig, cameras);
    for (const auto& c : cameras) {
      SLSHADOW_THROW_IF(
          c.settings.trigger != TriggerMode::kHardware, "capture: camera '", c.name,
          "': trigger is ", ToString(c.settings.trigger),
          "; with a projector that runs the sequence itself every camera ",
          "takes trigger: hardware on the line wired to the projector's trigger output");
      SequenceCamera s;
      s.cam = &c;
      s.full_scale = FullScale(c.settings.pixel_format);
      s.expected_depth = BitDepthOf(c.settings.pixel_format) == 8 ? CV_8U : CV_16U;
      const RigDevice& dev = rig.Camera(c.name);
      s.stride = SampleStride(options_.validation, dev.model.width, dev.model.height);
      cams_.push_back(std::move(s));
    }
    std::sort(cams_.begin(), cams_.end(), [&](const SequenceCamera& a, const SequenceCamera& b) {
      return rig.CameraIndex(a.cam->name) < rig.CameraIndex(b.cam->name);
    });
    images_ = GeneratePatterns(spec_);
    model_ = std::make_unique<SequenceModel>(spec_, images_);
    validate_ = options_.validate;
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
    summary_.images_total = n * static_cast<int>(cams_.size());
    for (auto& s : cams_) {
      s.queued.assign(static_cast<size_t>(n), 0);
      for (int k = 0; k < n; ++k) {
        s.queued[static_cast<size_t>(k)] = writer.Has(s.cam->name, k);
        summary_.images_before += s.queued[static_cast<size_t>(k)];
      }
    }
    projector_.Load(images_);
    for (auto& s : cams_) {
      s.cam->camera->Configure(s.cam->settings);
      s.info = s.cam->camera->Info();
      s.stats.serial = s.info.serial;
      s.stats.exposure_us = s.cam->settings.exposure_us.value_or(0);
      s.cam->camera->Start();
    }
    const CamerasStopper stop_cameras(cameras_);
    // Cameras arm their trigger input some time after AcquisitionStart: a pulse before that is
    // lost (a fault at pattern 0); give them the settle time, at least kArmTime.
    std::this_thread::sleep_for(std::max<std::chrono::microseconds>(options_.settle, kArmTime));
    const ProjectorInfo pinfo = projector_.Info();
    nlohmann::json start_note = {{"started", UtcTimestamp()},
                                 {"resumed", writer.resumed()},
                                 {"validate", validate_},
                                 {"projector", pinfo.backend},
                                 {"projector_id", pinfo.id},
                                 {"mode", "pattern-sequence"},
                                 {"frame_period_us", projector_.FramePeriod().count()}};
    for (const auto& s : cams_) {
      start_note["cameras"][s.cam->name] = CameraNote(s.info, s.cam->settings, s.stats.exposure_us);
      start_note["cameras"][s.cam->name]["trigger_line"] = s.cam->settings.trigger_line;
    }
    writer.AppendSession(start_note);

    StoreQueue store(writer, static_cast<size_t>(options_.store_queue_images));
    std::optional<Progress> progress;
    if (options_.progress) progress.emplace("capture", n - StoredPatterns());
    std::string failure, first_fault, last_fault;
    int matched = 0;
    double run_seconds = 0;
    try {
      for (int attempt = 0; StoredPatterns() < n; ++attempt) {
        if (Stopped()) {
          summary_.interrupted = true;
          break;
        }
        if (attempt > 0) ++summary_.retries;
        SequenceRun run = RunOnce();
        const std::string invalid =
            Validate(run);  // earlier than run.fault: it judges matched frames only
        const std::string fault = invalid.empty() ? run.fault : invalid;
        matched += static_cast<int>(run.frames.size());
        run_seconds += run.seconds;
        const int before = StoredPatterns();
        Store(run, attempt, store);
        if (progress) progress->Advance(StoredPatterns() - before);
        if (run.stopped) {
          summary_.interrupted = true;
          break;
        }
        if (fault.empty()) continue;
        (first_fault.empty() ? first_fault : last_fault) = fault;
        if (attempt >= options_.max_retries) {
          failure =
              "pattern-sequence capture failed after " + std::to_string(attempt + 1) +
              " run(s): " + first_fault +
              (last_fault.empty() || last_fault == first_fault ? "" : "; last run: " + last_fault);
          break;
        }
      }
    } catch (const Error& e) {
      failure = first_fault.empty() ? e.what() : first_fault + "; then: " + e.what();
    }
    progress.reset();
    std::string storage_error;
    try {
      store.Finish();
    } catch (const std::exception& e) {
      storage_error = e.what();
    }
    summary_.images_stored = store.stored();
    summary_.mean_pattern_ms = matched ? 1e3 * run_seconds / matched : 0;
    for (auto& s : cams_) {
      s.stats.stream = s.cam->camera->Statistics();
      s.stats.missing_frame_ids = s.ids.missing();
      s.stats.invalid_frame_ids = s.ids.invalid();
      summary_.cameras[s.cam->name] = s.stats;
    }
    summary_.seconds = std::chrono::duration<double>(Clock::now() - start).count();
    EndSession(writer, summary_, failure, storage_error);
    if (summary_.interrupted) return summary_;
    nlohmann::json extra = options_.extra.is_null() ? nlohmann::json::object() : options_.extra;
    extra["capture"]["sessions"] = writer.Sessions();
    extra["capture"]["mode"] = "pattern-sequence";
    extra["capture"]["frame_period_us"] = projector_.FramePeriod().count();
    writer.SetExtra(extra);
    writer.Commit();
    summary_.complete = true;
    return summary_;
  }

 private:
  bool Stopped() const { return options_.stop && options_.stop->load(); }

  // Patterns stored for every camera.
  int StoredPatterns() const {
    int stored = 0;
    for (int k = 0; k < spec_.NumImages(); ++k) {
      bool all = true;
      for (const auto& s : cams_) all = all && s.queued[static_cast<size_t>(k)];
      stored += all;
    }
    return stored;
  }

  // "; <why the projector is not there>" or "" when it answers as it should.
  std::string ProjectorState() {
    try {
      projector_.CheckAlive();
      return "";
    } catch (const Error& e) {
      return std::string("; ") + e.what();
    }
  }

  // Starts the device's sequence and grabs one frame per pattern per camera until every camera
  // has one per pattern or stayed silent for its timeout; stops the device, drops late frames,
  // and keeps the patterns before the first fault of any camera (MatchFrames).
  SequenceRun RunOnce() {
    SequenceRun run;
    const int n = spec_.NumImages();
    const auto period = projector_.FramePeriod();
    for (auto& s : cams_) s.cam->camera->Flush();
    const SysClock::time_point started = projector_.Start();
    const auto t0 = Clock::now();
    std::vector<std::vector<Frame>> got(cams_.size());
    std::vector<std::vector<int64_t>> lost_ids(cams_.size());
    std::vector<std::string> ended(cams_.size());  // why a camera's frames ended early
    for (int k = 0; k < n && !run.stopped; ++k) {
      for (size_t c = 0; c < cams_.size(); ++c) {
        if (!ended[c].empty()) continue;
        if (Stopped()) {
          run.stopped = true;
          break;
        }
        SequenceCamera& s = cams_[c];
        const auto timeout =
            s.cam->grab_timeout + std::chrono::ceil<std::chrono::milliseconds>(period);
        Frame f = s.cam->camera->Grab(timeout);
        if (f.status == FrameStatus::kTimeout || f.status == FrameStatus::kAborted) {
          s.stats.timeouts += f.status == FrameStatus::kTimeout;
          ended[c] = ": no frame within " + std::to_string(timeout.count()) + " ms" +
                     (f.message.empty() ? "" : " (" + f.message + ")") +
                     ": its trigger never came" + ProjectorState();
          continue;
        }
        ++s.stats.frames_grabbed;
        const int64_t lost = s.ids.Next(f.frame_id);
        const RigDevice& dev = rig_.Camera(s.cam->name);
        if (!f.ok() || f.image.cols != dev.model.width || f.image.rows != dev.model.height ||
            f.image.type() != CV_MAKETYPE(s.expected_depth, 1)) {
          // Still one trigger's frame: kept in the count, a fault at the pattern it takes.
          ++s.stats.damaged;
          if (f.ok()) {
            f.status = FrameStatus::kSizeMismatch;
            f.message = "of another size or depth than the rig camera";
          }
          f.device_timestamp_ns = 0;
        }
        got[c].push_back(std::move(f));
        lost_ids[c].push_back(lost);
      }
    }
    run.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
    std::string stop_error;
    try {
      projector_.Stop();
    } catch (const Error& e) {
      stop_error = std::string("stopping the sequence: ") + e.what();
    }
    // Frames of triggers after a fault (or spurious ones after the last pattern) are dropped.
    const auto drain =
        std::chrono::ceil<std::chrono::milliseconds>(period) + std::chrono::milliseconds(50);
    for (auto& s : cams_) {
      // Bounded, and a lost camera (kAborted at once, every time) ends it too.
      for (int i = 0; i < n; ++i) {
        const FrameStatus status = s.cam->camera->Grab(drain).status;
        if (status == FrameStatus::kTimeout || status == FrameStatus::kAborted) break;
        ++s.stats.extra_frames;
      }
    }
    int prefix = n;
    for (size_t c = 0; c < cams_.size(); ++c) {
      const auto [first_bad, why] =
          MatchFrames(got[c], lost_ids[c], started, ended[c], run.stopped);
      if (!why.empty()) ++cams_[c].stats.missed_triggers;
      if (first_bad >= prefix) continue;
      prefix = first_bad;
      run.fault = why.empty()
                      ? ""
                      : model_->Name(first_bad) + ", camera '" + cams_[c].cam->name + "'" + why;
    }
    if (run.fault.empty() && !stop_error.empty() && !run.stopped) run.fault = stop_error;
    for (int k = 0; k < prefix; ++k) {
      std::vector<Frame> round;
      for (size_t c = 0; c < cams_.size(); ++c)
        round.push_back(std::move(got[c][static_cast<size_t>(k)]));
      run.frames.push_back(std::move(round));
    }
    return run;
  }

  // Matches one camera's frames of a run to patterns (see the header): consecutive frames one
  // period apart, the first one anchored at pattern 0 by its arrival within a period after Start
  // (pattern 1's trigger comes no earlier) or by the count (frames spanning every pattern).
  // Returns the first pattern without a frame of its own and why ("" when stopped), or n.
  std::pair<int, std::string> MatchFrames(const std::vector<Frame>& f,
                                          const std::vector<int64_t>& lost_ids,
                                          SysClock::time_point started, const std::string& ended,
                                          bool stopped) const {
    const int n = spec_.NumImages();
    const double period_s = std::chrono::duration<double>(projector_.FramePeriod()).count();
    const std::string end = stopped ? "" : ended.empty() ? ": no frame (the run ended)" : ended;
    if (f.empty()) return {0, end};
    // Slots from device timestamps (host ones when the camera has none) relative to the last
    // complete frame; a damaged frame (no timestamp) takes the next slot, checked by the next one.
    std::vector<int64_t> slot = {0};
    std::vector<double> gap_s = {0};
    double spurious_s = 0;
    int64_t last_good = f[0].ok() ? 0 : -1;
    for (size_t j = 1; j < f.size(); ++j) {
      if (!f[j].ok() || last_good < 0) {
        slot.push_back(slot.back() + 1);
        gap_s.push_back(0);
        if (f[j].ok()) last_good = static_cast<int64_t>(j);
        continue;
      }
      const Frame& r = f[static_cast<size_t>(last_good)];
      const double dt =
          f[j].device_timestamp_ns != 0 && r.device_timestamp_ns != 0
              ? 1e-9 * (static_cast<double>(f[j].device_timestamp_ns) -
                        static_cast<double>(r.device_timestamp_ns))
              : std::chrono::duration<double>(f[j].host_timestamp - r.host_timestamp).count();
      const int64_t at = slot[static_cast<size_t>(last_good)] + std::llround(dt / period_s);
      if (at <= slot.back()) {  // a spurious frame: the slots end before it
        spurious_s = dt;
        break;
      }
      gap_s.push_back(dt);
      slot.push_back(at);
      last_good = static_cast<int64_t>(j);
    }
    const double first_s = std::chrono::duration<double>(f[0].host_timestamp - started).count();
    const bool anchored = first_s < period_s || (slot.back() == n - 1 && slot.size() == f.size());
    if (!anchored || slot.back() > n - 1) {
      return {0, ": cannot tell which pattern its first frame shows: it came " + Ms(first_s) +
                     " after Start (more than " + "the frame period " + Ms(period_s) +
                     ") and the frames span " + std::to_string(slot.back() + 1) + " of " +
                     std::to_string(n) +
                     " patterns: a frame is missing at the start or at the end" +
                     (ended.empty() ? "" : "; the last one" + ended)};
    }
    for (size_t j = 0; j < slot.size(); ++j) {
      const int k = static_cast<int>(j);
      if (slot[j] == static_cast<int64_t>(j) && !f[j].ok()) {
        return {k, ": frame " + ToString(f[j].status) +
                       (f[j].message.empty() ? "" : " (" + f[j].message + ")")};
      }
      if (slot[j] == static_cast<int64_t>(j)) continue;
      return {
          k, ": no frame: the next one came " + Ms(gap_s[j]) + " after " + model_->Name(k - 1) +
                 "'s (frame period " + Ms(period_s) + "): " +
                 (lost_ids[j] > 0 ? "the frame of this pattern was lost in transport (frame-id gap)"
                                  : "the camera missed this pattern's trigger")};
    }
    const int k = static_cast<int>(slot.size());
    if (slot.size() < f.size()) {
      return {k, ": a frame only " + Ms(spurious_s) + " after " + model_->Name(k - 1) +
                     "'s (frame period " + Ms(period_s) +
                     "): a spurious trigger or a late frame, this pattern's frame cannot be told"};
    }
    return {k, k == n ? "" : end};
  }

  // The frame of pattern k of camera c: from this run, an earlier run, or the staging folder;
  // nullptr when there is none yet.
  const cv::Mat* FrameOf(const SequenceRun& run, size_t c, int k, cv::Mat* holder) const {
    if (k < static_cast<int>(run.frames.size()))
      return &run.frames[static_cast<size_t>(k)][c].image;
    const auto kept = cams_[c].reference_images.find(k);
    if (kept != cams_[c].reference_images.end()) return &kept->second;
    if (!writer_->Has(cams_[c].cam->name, k)) return nullptr;
    *holder = writer_->Load(cams_[c].cam->name, k);
    return holder;
  }

  // Group checks over the matched frames (see the header); truncates run.frames at the first
  // failing group and returns why, or "".
  std::string Validate(SequenceRun& run) {
    if (!validate_) return "";
    const double lit_scale = options_.validation.lit_threshold / 255.0;
    for (size_t c = 0; c < cams_.size(); ++c) {
      SequenceCamera& s = cams_[c];
      const double lit_threshold = lit_scale * s.full_scale;
      References refs;
      std::vector<cv::Mat> held(model_->reference_frames.size());
      bool have_refs = !model_->reference_frames.empty();
      std::vector<const cv::Mat*> ref_images;
      for (size_t r = 0; r < model_->reference_frames.size() && have_refs; ++r) {
        const cv::Mat* m = FrameOf(run, c, model_->reference_frames[r], &held[r]);
        have_refs = m != nullptr;
        ref_images.push_back(m);
      }
      if (have_refs) {
        cv::Mat hi, lo;
        for (const cv::Mat* m : ref_images) {
          cv::Mat f;
          m->convertTo(f, CV_32F);
          hi = hi.empty() ? f.clone() : cv::max(hi, f);
          lo = lo.empty() ? f : cv::min(lo, f);
        }
        refs.white = hi;
        refs.black = lo;
      }
      for (const auto& g : model_->groups) {
        if (g.first + g.size > static_cast<int>(run.frames.size())) break;
        if (!g.pair) continue;
        const FrameRole role = model_->frames[static_cast<size_t>(g.first)].role;
        std::string why;
        int pair_at = -1;
        if (role == FrameRole::kWhite) {
          References wb;
          run.frames[static_cast<size_t>(g.first)][c].image.convertTo(wb.white, CV_32F);
          run.frames[static_cast<size_t>(g.first + 1)][c].image.convertTo(wb.black, CV_32F);
          const double lit = LitShare(wb, lit_threshold, s.stride);
          if (lit < options_.validation.min_lit_share) {
            char buf[200];
            std::snprintf(buf, sizeof buf,
                          ": white and black frames do not differ (%.2f %% of the image lit)",
                          100 * lit);
            why = model_->Name(g.first) + " and " + model_->Name(g.first + 1) + ", camera '" +
                  s.cam->name + "'" + buf;
          }
          if (g.opening) pair_at = g.first + 2;
        } else if (role == FrameRole::kGrayBit) {
          pair_at = g.first;
        }
        if (why.empty() && pair_at >= 0 && refs.ready()) {
          int samples = 0;
          const double q = ComplementaryShare(run.frames[static_cast<size_t>(pair_at)][c].image,
                                              run.frames[static_cast<size_t>(pair_at + 1)][c].image,
                                              refs, lit_threshold, s.stride, &samples);
          if (samples >= options_.validation.min_samples) {
            ++s.stats.pair_checks;
            s.stats.min_complementary_share = std::min(s.stats.min_complementary_share, q);
            if (q < options_.validation.min_complementary) {
              char buf[320];
              std::snprintf(buf, sizeof buf,
                            ": not complementary: %.1f %% of %d decisive pixels on opposite sides, "
                            "at least %.1f %% "
                            "expected: the frames do not show the programmed patterns (the "
                            "device's images differ "
                            "from the pattern spec, or the frames were taken of other patterns)",
                            100 * q, samples, 100 * options_.validation.min_complementary);
              why = model_->Name(pair_at) + " and " + model_->Name(pair_at + 1) + ", camera '" +
                    s.cam->name + "'" + buf;
            }
          }
        }
        if (!why.empty()) {
          ++s.stats.not_complementary;
          run.frames.resize(static_cast<size_t>(g.first));
          return why;
        }
      }
    }
    return "";
  }

  // Queues the matched patterns not stored yet, every camera's frame of each.
  void Store(const SequenceRun& run, int attempt, StoreQueue& store) {
    for (size_t k = 0; k < run.frames.size(); ++k) {
      for (size_t c = 0; c < cams_.size(); ++c) {
        SequenceCamera& s = cams_[c];
        if (s.queued[k]) continue;
        const Frame& f = run.frames[k][c];
        const auto& refs = model_->reference_frames;
        if (std::find(refs.begin(), refs.end(), static_cast<int>(k)) != refs.end())
          s.reference_images[static_cast<int>(k)] = f.image;
        s.queued[k] = 1;
        ++s.stats.frames_stored;
        store.Push(RecordOf(*s.cam, s.info, s.cam->settings, static_cast<int>(k), f, attempt),
                   f.image);
      }
    }
  }

  const Rig& rig_;
  PatternSpec spec_;
  SequenceProjector& projector_;
  fs::path out_;
  SequencerOptions options_;
  std::vector<SequenceCamera> cams_;
  const std::vector<CaptureCamera>& cameras_;  // the caller's, alive for the capture
  std::vector<cv::Mat> images_;
  std::unique_ptr<SequenceModel> model_;
  bool validate_ = true;
  ResumableImageSetWriter* writer_ = nullptr;
  CaptureSummary summary_;
};

}  // namespace

CaptureSummary CapturePatternSequence(const Rig& rig, const PatternSpec& spec,
                                      const std::vector<CaptureCamera>& cameras,
                                      SequenceProjector& projector, const fs::path& out,
                                      const SequencerOptions& options) {
  PatternSequenceCapture capture(rig, spec, cameras, projector, out, options);
  return capture.Run();
}

}  // namespace slshadow::capture
