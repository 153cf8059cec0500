#include "reconstruct/strict_policy.h"

#include <cmath>
#include <cstdio>

#include "core/error.h"

namespace slshadow {

namespace {

std::string Pair(const ReconstructSummary& s) { return s.camera + "-" + s.other_device; }

// A stereo reconstruction of the set that checked `camera` against the projector and passed.
bool CoveredByStereo(const std::vector<ReconstructSummary>& summaries, const std::string& camera) {
  for (const ReconstructSummary& s : summaries) {
    const CalibrationCheck& c = s.calibration_check;
    if (s.mode == ReconstructMode::kStereo && s.camera == camera && c.available && !c.warn &&
        c.residual == CalibrationResidual::kProjectorError)
      return true;
  }
  return false;
}

}  // namespace

void StrictOptions::Check() const {
  SLSHADOW_THROW_IF(!(min_point_share >= 0 && min_point_share <= 1),
                    "strict: min_point_share must be in [0, 1] (got ", min_point_share, ")");
}

std::vector<std::string> StrictViolations(const std::vector<ReconstructSummary>& summaries,
                                          const StrictOptions& options) {
  options.Check();
  std::vector<std::string> out;
  for (const ReconstructSummary& s : summaries) {
    const CalibrationCheck& c = s.calibration_check;
    if (c.warn) {
      out.push_back(Pair(s) + ": the calibration check warns (the rig file does not fit)");
    } else if (!c.available &&
               !(s.mode == ReconstructMode::kProjector && CoveredByStereo(summaries, s.camera))) {
      out.push_back(Pair(s) + ": no calibration check, because " + c.unavailable_reason);
    }
    const double valid =
        static_cast<double>(s.decode_status[static_cast<size_t>(PixelStatus::kValid)]) /
        (s.mode == ReconstructMode::kStereo ? 2.0 : 1.0);
    const double share = valid > 0 ? static_cast<double>(s.points) / valid : 0;
    if (share < options.min_point_share) {
      char line[200];
      std::snprintf(line, sizeof(line),
                    "%s: %lld points are %.1f %% of the %.0f valid pixels (under the %.1f %% "
                    "minimum)",
                    Pair(s).c_str(), static_cast<long long>(s.points), 100 * share, valid,
                    100 * options.min_point_share);
      out.push_back(line);
    }
  }
  return out;
}

void EnforceStrict(const std::vector<ReconstructSummary>& summaries, const StrictOptions& options,
                   const std::string& what) {
  if (!options.enabled) return;
  const std::vector<std::string> violations = StrictViolations(summaries, options);
  if (violations.empty()) return;
  std::string m;
  for (size_t k = 0; k < violations.size(); ++k) m += (k ? "; " : "") + violations[k];
  SLSHADOW_THROW(what, ": --strict: ", m, "; nothing written");
}

}  // namespace slshadow
