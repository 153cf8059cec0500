#include "capture/latency.h"

#include <algorithm>
#include <cstdio>
#include <thread>

#include "core/error.h"

namespace slshadow::capture {

using std::chrono::microseconds;
using Clock = std::chrono::steady_clock;

void LatencyOptions::Check() const {
  SLSHADOW_THROW_IF(repetitions < 1, "latency: repetitions must be positive (got ", repetitions,
                    ")");
  SLSHADOW_THROW_IF(resolution.count() <= 0, "latency: resolution must be positive (got ",
                    resolution.count(), " us)");
  SLSHADOW_THROW_IF(max_latency < resolution, "latency: max_latency (", max_latency.count(),
                    " us) must be at least the resolution (", resolution.count(), " us)");
  SLSHADOW_THROW_IF(grab_timeout.count() <= 0, "latency: grab_timeout must be positive (got ",
                    grab_timeout.count(), " ms)");
  SLSHADOW_THROW_IF(!(threshold > 0 && threshold < 1), "latency: threshold must be in (0, 1) (got ",
                    threshold, ")");
  SLSHADOW_THROW_IF(!(min_contrast_dn > 0), "latency: min_contrast_dn must be positive (got ",
                    min_contrast_dn, ")");
}

std::string LatencyMeasurement::BriefReport() const {
  std::string per;
  for (size_t i = 0; i < per_repetition.size(); ++i) {
    char v[32];
    std::snprintf(v, sizeof v, "%s%.1f", i ? ", " : "", per_repetition[i].count() / 1000.0);
    per += v;
  }
  char line[256];
  std::snprintf(line, sizeof line,
                "latency %.1f ms (%s; per repetition [%s] ms; black %.1f DN, white %.1f DN; %d "
                "frames, %d late trials "
                "repeated)",
                latency.count() / 1000.0, mode.c_str(), per.c_str(), black_mean_dn, white_mean_dn,
                frames, late_trials);
  return line;
}

namespace {

class Session {
 public:
  Session(Camera& camera, Projector& projector, const LatencyOptions& options)
      : camera_(camera), projector_(projector), options_(options) {}

  double GrabMean() {
    const Frame frame = camera_.Grab(options_.grab_timeout);
    ++frames_;
    SLSHADOW_THROW_IF(!frame.ok(), "latency: camera '", camera_.Info().id,
                      "': frame not received (", ToString(frame.status),
                      frame.message.empty() ? "" : ": " + frame.message, ")");
    return cv::mean(frame.image)[0];
  }
  // One frame triggered `wait` after `shown` (software trigger). A trigger that left late (the
  // thread woke more than half the resolution after the planned time) would make the wait look
  // shorter than it was: that frame is dropped and the trial repeated with the image shown again.
  double TriggeredMean(Clock::time_point shown, microseconds wait, int index = -1) {
    for (int attempt = 0;; ++attempt) {
      std::this_thread::sleep_until(shown + wait);
      const bool late = Clock::now() - (shown + wait) > options_.resolution / 2;
      camera_.Trigger();
      const double mean = GrabMean();
      if (!late || index < 0 || attempt == 20) return mean;
      ++late_trials_;
      projector_.Show(1 - index);  // back to the other image, settled, then again
      std::this_thread::sleep_for(options_.max_latency);
      shown = projector_.Show(index);
    }
  }
  bool IsWhite(double mean) const { return mean > black_ + options_.threshold * (white_ - black_); }

  // Shows `index` (0 black, 1 white) and waits until the camera sees it (software trigger).
  void Settle(int index, microseconds wait) {
    const auto deadline = Clock::now() + options_.max_latency * 4;
    while (true) {
      const auto shown = projector_.Show(index);
      if (IsWhite(TriggeredMean(shown, wait)) == (index == 1)) return;
      SLSHADOW_THROW_IF(Clock::now() > deadline, "latency: camera '", camera_.Info().id,
                        "' did not see the projector turn ", index == 1 ? "white" : "black",
                        " within ", (options_.max_latency * 4).count() / 1000, " ms");
      wait = std::min(options_.max_latency, wait * 2 + options_.resolution);
    }
  }

  LatencyMeasurement Run() {
    LatencyMeasurement m;
    const ProjectorInfo info = projector_.Info();
    SLSHADOW_THROW_IF(info.width <= 0 || info.height <= 0, "latency: projector '", info.backend,
                      ":", info.id, "' has no image size (a 'none' projector cannot be measured)");
    projector_.Load({cv::Mat(info.height, info.width, CV_8UC1, cv::Scalar(0)),
                     cv::Mat(info.height, info.width, CV_8UC1, cv::Scalar(255))});
    const bool software = camera_.Settings().trigger == TriggerMode::kSoftware;
    m.mode = software ? "software trigger" : "frame counting";
    camera_.Start();
    try {
      // References, each after the longest wait.
      for (int index : {0, 1}) {
        const auto shown = projector_.Show(index);
        std::this_thread::sleep_until(shown + options_.max_latency);
        camera_.Flush();
        double& ref = index == 0 ? black_ : white_;
        ref = software ? TriggeredMean(Clock::now(), microseconds(0)) : GrabMean();
      }
      m.black_mean_dn = black_;
      m.white_mean_dn = white_;
      SLSHADOW_THROW_IF(white_ - black_ < options_.min_contrast_dn, "latency: camera '",
                        camera_.Info().id, "' sees no change between projector black (mean ",
                        black_, " DN) and white (mean ", white_, " DN); min_contrast_dn is ",
                        options_.min_contrast_dn, ": is it looking at the projector?");
      for (int r = 0; r < options_.repetitions; ++r) {
        if (software) {
          microseconds lo(0), hi = options_.max_latency;
          Settle(0, hi);
          if (!IsWhite(TriggeredMean(projector_.Show(1), hi, 1))) {
            SLSHADOW_THROW("latency: camera '", camera_.Info().id,
                           "' did not see the projector turn white within ", hi.count() / 1000,
                           " ms (max_latency)");
          }
          // Invariant: a wait of hi showed white; lo is the largest wait that showed black, or 0.
          bool zero_tried = false;
          while (hi - lo > options_.resolution || !zero_tried) {
            const microseconds mid = zero_tried ? lo + (hi - lo) / 2 : microseconds(0);
            zero_tried = true;
            Settle(0, hi);
            if (IsWhite(TriggeredMean(projector_.Show(1), mid, 1))) {
              hi = mid;
              if (mid.count() == 0) break;
            } else {
              lo = mid;
            }
          }
          m.per_repetition.push_back(hi);
        } else {
          projector_.Show(0);
          std::this_thread::sleep_for(options_.max_latency);
          camera_.Flush();
          const auto shown = projector_.Show(1);
          int count = 0;
          while (true) {
            const Frame frame = camera_.Grab(options_.grab_timeout);
            ++frames_;
            ++count;
            SLSHADOW_THROW_IF(!frame.ok(), "latency: camera '", camera_.Info().id,
                              "': frame not received (", ToString(frame.status), ")");
            if (IsWhite(cv::mean(frame.image)[0])) {
              m.per_repetition.push_back(
                  std::chrono::duration_cast<microseconds>(Clock::now() - shown));
              break;
            }
            SLSHADOW_THROW_IF(Clock::now() - shown > options_.max_latency * 4, "latency: camera '",
                              camera_.Info().id, "' did not see the projector turn white within ",
                              (options_.max_latency * 4).count() / 1000, " ms (", count,
                              " frames)");
          }
          m.frames_until_change.push_back(count);
        }
      }
      projector_.Show(0);
    } catch (...) {
      camera_.Stop();
      throw;
    }
    camera_.Stop();
    m.latency = *std::max_element(m.per_repetition.begin(), m.per_repetition.end());
    m.frames = frames_;
    return m;
  }

 private:
  Camera& camera_;
  Projector& projector_;
  const LatencyOptions& options_;
  double black_ = 0, white_ = 0;
  int frames_ = 0;
  int late_trials_ = 0;

 public:
  int late_trials() const { return late_trials_; }
};

}  // namespace

LatencyMeasurement MeasureProjectorLatency(Camera& camera, Projector& projector,
                                           const LatencyOptions& options) {
  options.Check();
  Session session(camera, projector, options);
  LatencyMeasurement m = session.Run();
  m.late_trials = session.late_trials();
  return m;
}

}  // namespace slshadow::capture
