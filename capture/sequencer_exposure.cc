// Sequencer (capture/internal/sequencer_impl.h): the exposure assistant, before the sequence.
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

void Sequencer::ChooseExposures(ResumableImageSetWriter& writer) {
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
      SLSHADOW_THROW_IF(!frames[c].ok(), "auto exposure: camera '", s.cam->name, "': white frame ",
                        ToString(frames[c].status), " ", frames[c].message);
      cv::Mat w;
      frames[c].image.convertTo(w, CV_32F);
      std::vector<float> lit;
      const double lit_threshold = options_.validation.lit_threshold * s.full_scale / 255.0;
      for (int y = 0; y < w.rows; y += 2) {
        const float* pw = w.ptr<float>(y);
        const float* pd = dark[c].empty() ? nullptr : dark[c].ptr<float>(y);
        for (int x = 0; x < w.cols; x += 2) {
          if (!pd || pw[x] - pd[x] >= lit_threshold || pw[x] >= s.full_scale) lit.push_back(pw[x]);
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

void Sequencer::SetExposure(CameraState& s, double exposure_us) {
  s.cam->camera->Stop();
  s.settings.exposure_us = exposure_us;
  s.cam->camera->Configure(s.settings);
  s.cam->camera->Start();
}

}  // namespace slshadow::capture::internal
