// Options checks, summaries, frame-id bookkeeping and board poses of the acquisition sequencer
// (capture/sequencer.h); the sequencer itself is in sequencer.cc.
#include <cstdio>
#include <istream>
#include <ostream>

#include "capture/sequencer.h"
#include "core/error.h"

namespace slshadow::capture {
namespace fs = std::filesystem;

void ValidationOptions::Check() const {
  SLSHADOW_THROW_IF(stride_px < 0 || stride_px > 64,
                    "validation.stride_px: must be in [0, 64] (got ", stride_px, ")");
  SLSHADOW_THROW_IF(target_samples < 1000, "validation.target_samples: must be >= 1000 (got ",
                    target_samples, ")");
  for (const auto& [name, v] :
       {std::pair{"min_pattern_change", min_pattern_change}, std::pair{"stale_ratio", stale_ratio},
        std::pair{"min_lit_share_floor", min_lit_share_floor},
        std::pair{"min_lit_share", min_lit_share},
        std::pair{"min_complementary", min_complementary}}) {
    SLSHADOW_THROW_IF(!(v >= 0 && v <= 1), "validation.", name, ": must be in [0, 1] (got ", v,
                      ")");
  }
  SLSHADOW_THROW_IF(!(change_threshold > 0) || !(lit_threshold > 0),
                    "validation: change_threshold and lit_threshold must be > 0");
  SLSHADOW_THROW_IF(min_samples < 1, "validation.min_samples: must be >= 1 (got ", min_samples,
                    ")");
}

void AutoExposureOptions::Check() const {
  SLSHADOW_THROW_IF(!(target_fraction > 0.1 && target_fraction < 1),
                    "auto_exposure.target_fraction: must be in (0.1, 1) (got ", target_fraction,
                    ")");
  SLSHADOW_THROW_IF(!(tolerance > 0 && tolerance < target_fraction),
                    "auto_exposure.tolerance: must be in (0, target) (got ", tolerance, ")");
  SLSHADOW_THROW_IF(!(percentile > 0.5 && percentile < 1),
                    "auto_exposure.percentile: must be in (0.5, 1) (got ", percentile, ")");
  SLSHADOW_THROW_IF(max_iterations < 1, "auto_exposure.max_iterations: must be >= 1 (got ",
                    max_iterations, ")");
  SLSHADOW_THROW_IF(!(min_exposure_us > 0 && max_exposure_us > min_exposure_us),
                    "auto_exposure: exposure bounds must satisfy 0 < min < max");
}

void SequencerOptions::Check() const {
  SLSHADOW_THROW_IF(settle.count() < 0, "settle: must be >= 0 (got ", settle.count(), " us)");
  SLSHADOW_THROW_IF(max_retries < 0 || max_retries > 100, "max_retries: must be in [0, 100] (got ",
                    max_retries, ")");
  SLSHADOW_THROW_IF(retry_backoff.count() < 0, "retry_backoff: must be >= 0 (got ",
                    retry_backoff.count(), " us)");
  SLSHADOW_THROW_IF(max_latency.count() < 0, "max_latency: must be >= 0 (got ", max_latency.count(),
                    " us)");
  SLSHADOW_THROW_IF(store_queue_images < 1, "store_queue_images: must be >= 1 (got ",
                    store_queue_images, ")");
  validation.Check();
  auto_exposure_options.Check();
}

int64_t FrameIdTracker::Next(uint64_t id) {
  if (id == 0) {
    ++invalid_;
    return 0;
  }
  int64_t skipped = 0;
  if (has_last_) {
    if (id <= 65535 && last_ <= 65535) {
      // 16-bit ids 1..65535: the ring has 65535 members.
      const uint64_t d = (id + 65535 - last_) % 65535;
      skipped = d == 0 ? 0 : static_cast<int64_t>(d) - 1;
    } else if (id > last_) {
      skipped = static_cast<int64_t>(id - last_ - 1);
    }
  }
  has_last_ = true;
  last_ = id;
  missing_ += skipped;
  return skipped;
}

nlohmann::json CameraCaptureStats::ToJson() const {
  return {{"serial", serial},
          {"frames_grabbed", frames_grabbed},
          {"frames_stored", frames_stored},
          {"timeouts", timeouts},
          {"damaged", damaged},
          {"stale", stale},
          {"not_complementary", not_complementary},
          {"missing_frame_ids", missing_frame_ids},
          {"invalid_frame_ids", invalid_frame_ids},
          {"exposure_us", exposure_us},
          {"min_complementary_share", min_complementary_share},
          {"pair_checks", pair_checks},
          {"missed_triggers", missed_triggers},
          {"extra_frames", extra_frames},
          {"stream",
           {{"completed_frames", stream.completed_frames},
            {"failed_frames", stream.failed_frames},
            {"missing_frames", stream.missing_frames},
            {"missing_packets", stream.missing_packets},
            {"resend_requests", stream.resend_requests},
            {"underruns", stream.underruns},
            {"timeouts", stream.timeouts}}}};
}

nlohmann::json CaptureSummary::ToJson() const {
  nlohmann::json j = {{"complete", complete},
                      {"interrupted", interrupted},
                      {"resumed", resumed},
                      {"validated", validated},
                      {"patterns", patterns},
                      {"images_total", images_total},
                      {"images_before", images_before},
                      {"images_stored", images_stored},
                      {"retries", retries},
                      {"seconds", seconds},
                      {"mean_pattern_ms", mean_pattern_ms},
                      {"overhead_ms_per_pattern", overhead_ms_per_pattern},
                      {"overhead_cpu_ms_per_pattern", overhead_cpu_ms_per_pattern},
                      {"wait_after_show_us", wait_after_show_us},
                      {"learned_latency_us", learned_latency_us}};
  for (const auto& [name, s] : cameras) j["cameras"][name] = s.ToJson();
  for (const auto& [name, us] : auto_exposure_us) j["auto_exposure_us"][name] = us;
  return j;
}

std::string CaptureSummary::BriefReport() const {
  char line[256];
  std::snprintf(line, sizeof(line),
                "%s: %d of %d images (%d stored now, %d before), %d patterns, %d retries, %.1f s%s",
                complete      ? "complete"
                : interrupted ? "interrupted"
                              : "incomplete",
                images_before + images_stored, images_total, images_stored, images_before, patterns,
                retries, seconds, resumed ? ", resumed" : "");
  std::string s = line;
  if (!validated) s += "\n  frames not checked against the patterns (--no-validate)";
  for (const auto& [name, c] : cameras) {
    // Stale and not complementary count the checks' findings: printed only where they ran.
    char checks[96] = "";
    if (validated) {
      std::snprintf(checks, sizeof(checks), "%lld stale, %lld not complementary, ",
                    static_cast<long long>(c.stale), static_cast<long long>(c.not_complementary));
    }
    std::snprintf(line, sizeof(line),
                  "\n  %s (%s): %lld grabbed, %lld timeouts, %lld damaged, %s%lld missing frame "
                  "ids, exposure %.0f us",
                  name.c_str(), c.serial.c_str(), static_cast<long long>(c.frames_grabbed),
                  static_cast<long long>(c.timeouts), static_cast<long long>(c.damaged), checks,
                  static_cast<long long>(c.missing_frame_ids), c.exposure_us);
    s += line;
  }
  return s;
}

fs::path PoseDir(const fs::path& out, int pose) {
  char name[32];
  std::snprintf(name, sizeof(name), "pose_%02d", pose);
  return out / name;
}

PosesSummary CapturePoses(const Rig& rig, const PatternSpec& spec,
                          const std::vector<CaptureCamera>& cameras, Projector& projector,
                          const fs::path& out, int num_poses, const SequencerOptions& options,
                          std::istream& input, std::ostream& prompt) {
  SLSHADOW_THROW_IF(num_poses < 1 || num_poses > 99, "--poses: must be in [1, 99] (got ", num_poses,
                    ")");
  std::error_code ec;
  fs::create_directories(out, ec);
  SLSHADOW_THROW_IF(ec, out.string(), ": cannot create folder: ", ec.message());
  PosesSummary result;
  for (int p = 0; p < num_poses; ++p) {
    const fs::path dir = PoseDir(out, p);
    if (fs::exists(dir / "manifest.json", ec)) {
      ++result.skipped;
      continue;
    }
    if (options.stop && options.stop->load()) {
      result.interrupted = true;
      break;
    }
    const bool partial = fs::exists(ResumableImageSetWriter::StagingDirFor(dir), ec);
    prompt << "pose " << p + 1 << " of " << num_poses
           << (partial ? " (continuing a partial capture)" : "")
           << ": place the board, then press Enter" << std::endl;
    std::string line;
    if (!std::getline(input, line) || (options.stop && options.stop->load())) {
      result.interrupted = true;  // end of input or Ctrl-C: stop, the poses so far are kept
      break;
    }
    SequencerOptions o = options;
    o.writer.overwrite = false;
    CaptureSummary s = Capture(rig, spec, cameras, projector, dir, o);
    const bool stopped = s.interrupted;
    result.poses.push_back(std::move(s));
    if (stopped) {
      result.interrupted = true;
      break;
    }
  }
  return result;
}

}  // namespace slshadow::capture
