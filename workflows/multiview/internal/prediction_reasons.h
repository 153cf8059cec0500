// The coverage prediction's reasons as bytes (PredictedReason, coverage_prediction.h) and the
// helpers shared by the prediction (coverage_prediction.cc), its report and check
// (coverage_check.cc) and the light measured from a capture (captured_light.cc). Internal to
// workflows/multiview.
#pragma once

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/coverage_prediction.h"

namespace slshadow::multiview::internal {

constexpr auto kCovered = static_cast<uint8_t>(PredictedReason::kReconstructed);
constexpr auto kDark = static_cast<uint8_t>(PredictedReason::kTooDark);
constexpr auto kGrazing = static_cast<uint8_t>(PredictedReason::kGrazing);
constexpr auto kOccluded = static_cast<uint8_t>(PredictedReason::kOccluded);
constexpr auto kOutside = static_cast<uint8_t>(PredictedReason::kOutsideField);
constexpr auto kOnTable = static_cast<uint8_t>(PredictedReason::kOnTable);
static_assert(kCovered == static_cast<uint8_t>(CoverageReason::kCovered) &&
              kDark == static_cast<uint8_t>(CoverageReason::kNotReconstructed) &&
              kGrazing == static_cast<uint8_t>(CoverageReason::kGrazing) &&
              kOccluded == static_cast<uint8_t>(CoverageReason::kOccluded) &&
              kOutside == static_cast<uint8_t>(CoverageReason::kOutsideField) &&
              kOnTable == static_cast<uint8_t>(CoverageReason::kOnTable));

// The colour of a predicted reason: the CAD comparison's colour of the CoverageReason it is
// numbered as (cad_compare.h ReasonColor), so a coverage map and a scan's cad_coverage.ply read
// alike; too_dark takes not_reconstructed's red (what the scan would miss there).
inline std::array<uint8_t, 3> PredictedReasonColor(uint8_t reason) {
  return ReasonColor(static_cast<CoverageReason>(reason));
}

inline double Share(size_t a, size_t b) {
  return b ? static_cast<double>(a) / static_cast<double>(b) : 0;
}

// The specular lobe at tan^2(theta_h), 1 on the mirror direction
// (CoveragePredictionOptions::gloss). (Beckmann's distribution; GGX's heavier tail fits the kamino
// board's white frames no better: 0.37 against 0.41 DN RMS on pose 0's dark squares, the same
// coverage within 0.8 %.)
inline double GlossLobe(double tan2, double inv_alpha_sq) { return std::exp(-tan2 * inv_alpha_sq); }

}  // namespace slshadow::multiview::internal
