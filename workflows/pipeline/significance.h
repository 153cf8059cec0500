// The one rule by which slshadow judges that a physics layer matters. `slshadow shadow` keeps a
// layer fitted from real images when its value departs from the layer's "off" value
// (workflows/twin/physics_fit.h); the physics study (study 3, key `effects` of a study file) calls
// a layer needed when switching it off changes the cloud's RMS or p95 error. Both ask the same
// question of an effect: does it exceed three standard uncertainties (what noise and sampling
// explain) and a practical floor (the smallest change that matters)?
//
// Both take the standard uncertainty from the same figure computed on disjoint horizontal bands of
// the image (kSignificanceBands of them): the bands' standard deviation / sqrt(bands), which
// absorbs the pixels' spatial correlation that a per-pixel formula would miss.
#pragma once

#include <vector>

namespace slshadow::pipeline {

inline constexpr int kSignificanceBands = 8;

// What an effect must exceed: max(3 sigma, floor). NaN when sigma is NaN (nothing exceeds it).
double SignificanceThreshold(double sigma, double floor);

// |effect| > SignificanceThreshold(sigma, floor).
bool Significant(double effect, double sigma, double floor);

// The standard uncertainty of a figure from its values on disjoint bands: the standard deviation
// of the finite values / sqrt(their count). NaN with fewer than two finite values.
double BandSigma(const std::vector<double>& band_values);

}  // namespace slshadow::pipeline
