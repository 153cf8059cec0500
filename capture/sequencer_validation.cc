// Sequencer (capture/internal/sequencer_impl.h): each frame and group of frames checked against
// the patterns, the retries, and settling after a fault.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <optional>

#include "capture/internal/sequencer_impl.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/progress.h"
#include "patterns/codec.h"

namespace slshadow::capture::internal {

const cv::Mat* Sequencer::Previous(CameraState& s, int k) {
  if (k == 0) return nullptr;
  if (s.prev_index != k - 1) {
    if (!writer_->Has(s.cam->name, k - 1)) return nullptr;
    s.prev = writer_->Load(s.cam->name, k - 1);
    s.prev_index = k - 1;
  }
  return &s.prev;
}

void Sequencer::EnsureReferences(CameraState& s) {
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

Verdict Sequencer::CheckFrame(CameraState& s, int k, const Frame& f, const cv::Mat* prev_override,
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

Verdict Sequencer::CheckGroup(CameraState& s, const SequenceModel::Group& g,
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
  return {false,
          model_->Name(k) + " and " + model_->Name(k + 1) + ", camera '" + s.cam->name + "'" + buf};
}

std::optional<std::vector<Frame>> Sequencer::AcquirePattern(int k,
                                                            const std::vector<const cv::Mat*>& prev,
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

std::optional<std::vector<Frame>> Sequencer::Settle(int group_attempt,
                                                    std::vector<std::string>* errors) {
  std::vector<Frame> before;
  for (int round = 0; round <= options_.max_retries + 1; ++round) {
    FlushAll();
    const Clock::time_point earliest =
        round == 0 ? Clock::time_point{}
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
        errors->push_back("settling on " + model_->Name(last_shown_) + ", camera '" + s.cam->name +
                          "': frame " + ToString(f.status) +
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

void Sequencer::AcceptReference(CameraState& s, int k, const cv::Mat& image) {
  if (std::find(model_->reference_frames.begin(), model_->reference_frames.end(), k) ==
      model_->reference_frames.end())
    return;
  s.reference_images[k] = image;
}

bool Sequencer::AcquireGroup(const SequenceModel::Group& g, StoreQueue& store) {
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

Verdict Sequencer::CheckPhaseSteps(CameraState& s, const SequenceModel::Group& g,
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
  if (count < options_.validation.min_samples || share <= 1 - options_.validation.min_complementary)
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

bool Sequencer::RecheckPairs(StoreQueue& store) {
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

}  // namespace slshadow::capture::internal
