// The projector's and the sensor's layers of FitPhysics (workflows/twin/physics_fit.h): the
// projector response (gamma), global light and sensor noise; the radiometric layers are in
// physics_fit_layers.cc.
#include "workflows/twin/internal/physics_fit_layers.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <Eigen/Dense>

#include "core/error.h"
#include "core/statistics.h"
#include "core/string_printf.h"
#include "patterns/codec.h"
#include "workflows/pipeline/significance.h"

namespace slshadow::twin::internal {

namespace {

// a0(gamma): the mean of (0.5 + 0.5 cos t)^gamma over a period.
double PhaseMeanOfGamma(double g) {
  double sum = 0;
  const int steps = 360;
  for (int i = 0; i < steps; ++i)
    sum += std::pow(0.5 + 0.5 * std::cos(2 * M_PI * (i + 0.5) / steps), g);
  return sum / steps;
}

// The gamma whose a0 is `mean` (a0 decreases with gamma).
double GammaOfPhaseMean(double mean) {
  double lo = 0.2, hi = 5;
  for (int i = 0; i < 50; ++i) {
    const double mid = std::sqrt(lo * hi);
    (PhaseMeanOfGamma(mid) > mean ? lo : hi) = mid;
  }
  return std::sqrt(lo * hi);
}

}  // namespace

// --- projector response (gamma), phase codecs only ---
void FitGamma(FitContext& ctx) {
  const PatternSpec& spec = ctx.spec;
  const std::vector<Sample>& samples = ctx.samples;
  PhysicsLayer gamma;
  gamma.name = "gamma";
  gamma.unit = "exponent";
  gamma.off_value = 1;
  gamma.value = 1;
  gamma.residual_unit = "RMS of the mean normalised phase value - a0(gamma)";
  const int n = spec.phase_steps;
  std::vector<int> phase_frames;
  if (spec.kind != PatternKind::kGrayCode) phase_frames = FirstPeriodPhaseFrames(spec, ctx.frames);
  if (spec.kind == PatternKind::kGrayCode) {
    gamma.observable = false;
    gamma.reason = "binary patterns (0 / 255 only) do not see the projector's response";
  } else if (spec.intensity_min != 0 || spec.intensity_max != 255 ||
             std::find(phase_frames.begin(), phase_frames.end(), -1) != phase_frames.end()) {
    gamma.observable = false;
    gamma.reason = "phase frames do not span 0..255; the response fit needs them";
  } else {
    // Per well-lit pixel the mean of its normalised phase values, which is a0(gamma), the mean
    // of (0.5 + 0.5 cos)^gamma over a period, whatever the phase, blur or frame order.
    const double min_contrast = WellLitContrast(samples);
    BandedValues fit_mean;
    std::vector<double> held_mean;
    for (const Sample& s : samples) {
      if (s.white - s.black < min_contrast) continue;
      double m = 0;
      for (int k = 0; k < n; ++k) {
        const float p = Pixel(ctx.cameras[static_cast<size_t>(s.camera)]
                                  .real[static_cast<size_t>(phase_frames[static_cast<size_t>(k)])],
                              s.y, s.x);
        m += (p - s.black) / (s.white - s.black) / n;
      }
      if (s.heldout) {
        held_mean.push_back(m);
      } else {
        fit_mean.Add(s.band, m);
      }
    }
    if (fit_mean.all.size() < 100) {
      gamma.observable = false;
      gamma.reason = "too few well-lit pixels for the response fit";
    } else {
      gamma.value = GammaOfPhaseMean(Median(std::vector<double>(fit_mean.all)));
      gamma.sigma = fit_mean.Sigma(50, [](const std::vector<double>& b) {
        return GammaOfPhaseMean(Median(std::vector<double>(b)));
      });
      gamma.samples = static_cast<int64_t>(fit_mean.all.size());
      std::vector<double> off, on;
      const double on_level = PhaseMeanOfGamma(gamma.value);
      for (double m : held_mean) off.push_back(m - 0.5), on.push_back(m - on_level);
      gamma.heldout_residual_off = Rms(off);
      gamma.heldout_residual_on = Rms(on);
      const bool significant =
          pipeline::Significant(gamma.value - 1, gamma.sigma, ctx.options.gamma_floor);
      gamma.kept = significant && HeldoutDrops(gamma, ctx.options.min_heldout_drop);
      gamma.reason =
          gamma.kept
              ? StringPrintf(
                    "phase frames average %.3f of white, not 0.5: held-out residual %.4f -> %.4f",
                    on_level, gamma.heldout_residual_off, gamma.heldout_residual_on)
              : StringPrintf(
                    "a linear response fits within noise (gamma %.3f, held-out residual %.4f vs "
                    "%.4f)",
                    gamma.value, gamma.heldout_residual_off, gamma.heldout_residual_on);
    }
  }
  ctx.fit.layers.push_back(gamma);
}

namespace {

// The coarse inverse pairs (about half lit, the upper half of the bits) the global light is read
// from.
std::vector<std::pair<int, int>> CoarseInversePairs(const PatternSpec& spec,
                                                    const std::vector<FrameInfo>& frames) {
  const std::vector<double> means = PatternMeans(GeneratePatterns(spec));
  int max_bit[2] = {-1, -1};
  for (const FrameInfo& f : frames) {
    if (f.role == FrameRole::kGrayBit) max_bit[f.axis] = std::max(max_bit[f.axis], f.bit);
  }
  std::vector<std::pair<int, int>> coarse;
  for (const auto& [a, b] : InversePairs(frames)) {
    const FrameInfo& f = frames[static_cast<size_t>(a)];
    const double ma = means[static_cast<size_t>(a)], mb = means[static_cast<size_t>(b)];
    if (2 * f.bit >= max_bit[f.axis] && std::abs(ma - mb) < 0.1 && ma > 0.3 && ma < 0.7)
      coarse.emplace_back(a, b);
  }
  return coarse;
}

}  // namespace

// --- global light: (1 - gamma) of the white level is direct, gamma arrives scattered from the
// whole lit projector image, so a frame with lit fraction m reads B + (W - B) ((1 - g) p + g m).
// Coarse inverse pairs (both about half lit) then differ by (1 - g) (W - B) away from edges. ---
void FitGlobalLight(FitContext& ctx) {
  const std::vector<Sample>& samples = ctx.samples;
  const PhysicsFitOptions& options = ctx.options;
  PhysicsLayer gl;
  gl.name = "global_light";
  gl.unit = "fraction of white - black";
  gl.residual_unit = "RMS of |P - I| / (W - B) - (1 - g), coarse inverse pairs";
  const std::vector<std::pair<int, int>> coarse = CoarseInversePairs(ctx.spec, ctx.frames);
  if (!ctx.has_white_black) {
    gl.observable = false;
    gl.reason =
        "no white and black frames: the levels come from the inverse pairs themselves, so "
        "scattered light is folded into them";
  } else if (coarse.size() < 2) {
    gl.observable = false;
    gl.reason =
        "the sequence has too few coarse inverse pairs (about half lit) to separate direct from "
        "scattered light";
  } else {
    const double min_contrast = WellLitContrast(samples);
    BandedValues fit_r;
    std::vector<double> held_r;
    std::vector<double> per(coarse.size());
    for (const Sample& s : samples) {
      if (s.white - s.black < min_contrast) continue;
      const auto& real = ctx.cameras[static_cast<size_t>(s.camera)].real;
      for (size_t k = 0; k < coarse.size(); ++k) {
        per[k] = std::abs(Pixel(real[static_cast<size_t>(coarse[k].first)], s.y, s.x) -
                          Pixel(real[static_cast<size_t>(coarse[k].second)], s.y, s.x)) /
                 (s.white - s.black);
      }
      const double r = Median(
          std::vector<double>(per));  // a pixel near one bit's edge is outvoted by the others
      if (s.heldout) {
        held_r.push_back(r);
      } else {
        fit_r.Add(s.band, r);
      }
    }
    if (fit_r.all.size() < 100) {
      gl.observable = false;
      gl.reason = "too few well-lit pixels for the global-light fit";
    } else {
      gl.value = 1 - Median(std::vector<double>(fit_r.all));
      gl.sigma = fit_r.Sigma(
          20, [](const std::vector<double>& b) { return 1 - Median(std::vector<double>(b)); });
      gl.samples = static_cast<int64_t>(fit_r.all.size());
      std::vector<double> off, on;
      for (double r : held_r) off.push_back(r - 1), on.push_back(r - (1 - gl.value));
      gl.heldout_residual_off = Rms(off);
      gl.heldout_residual_on = Rms(on);
      gl.extra["pairs"] = coarse.size();
      const bool significant =
          gl.value > 0 && pipeline::Significant(gl.value, gl.sigma, options.global_light_floor);
      gl.kept = significant && HeldoutDrops(gl, options.min_heldout_drop);
      gl.reason =
          gl.kept ? StringPrintf(
                        "coarse stripes reach %.1f %% of white - black: %.1f %% of the light is "
                        "scattered from the lit "
                        "projector image; held-out residual %.3f -> %.3f",
                        100 * (1 - gl.value), 100 * gl.value, gl.heldout_residual_off,
                        gl.heldout_residual_on)
                  : StringPrintf(
                        "coarse stripes reach %.1f %% of white - black: direct light explains them",
                        100 * (1 - gl.value));
    }
  }
  ctx.fit.layers.push_back(gl);
}

namespace {

// One noise observation: s = the sum of two pairs' sums above the black level, r = their
// difference (four images' noise, no signal).
struct NoiseObservation {
  double s, r;
  bool held;
};

// The noise observations of up to ~40000 samples: sums of inverse pairs (and W + B when those
// frames exist), each ideally W + B, differenced two by two.
std::vector<NoiseObservation> NoiseObservations(const FitContext& ctx,
                                                const std::vector<std::pair<int, int>>& pairs) {
  const std::vector<Sample>& samples = ctx.samples;
  const double fs = ctx.fs;
  const size_t step = std::max<size_t>(1, samples.size() / 40000);
  // The signal is what sits above the black level (shot noise does not see the offset): 4 o_c.
  std::vector<double> offset4(ctx.cameras.size(), 0.0);
  for (size_t c = 0; c < ctx.cameras.size(); ++c) {
    const PhysicsLayer* bl = ctx.fit.Find("black_level_" + ctx.cameras[c].camera);
    offset4[c] = bl && bl->kept ? 4 * bl->value : 0.0;
  }
  std::vector<NoiseObservation> obs;
  for (size_t i = 0; i < samples.size(); i += step) {
    const Sample& s = samples[i];
    const auto& real = ctx.cameras[static_cast<size_t>(s.camera)].real;
    // Sums of pairs (and W + B when those frames exist), each ideally W + B; differences of
    // consecutive sums carry four images' noise and no signal.
    std::vector<double> sums;
    if (ctx.has_white_black) sums.push_back(s.white + s.black);
    bool saturated = false;
    for (const auto& [p, q] : pairs) {
      const double a = Pixel(real[static_cast<size_t>(p)], s.y, s.x),
                   b = Pixel(real[static_cast<size_t>(q)], s.y, s.x);
      saturated = saturated || a >= 0.98 * fs || b >= 0.98 * fs;
      sums.push_back(a + b);
    }
    if (saturated) continue;
    const double o4 = offset4[static_cast<size_t>(s.camera)];
    for (size_t k = 0; k + 1 < sums.size(); k += 2)
      obs.push_back({sums[k] + sums[k + 1] - o4, sums[k] - sums[k + 1], s.heldout});
  }
  return obs;
}

// The fitting (held = false) or held-out observations binned by signal into 10 quantile bins:
// per bin the median signal and the robust variance of r.
void BinnedVariance(const std::vector<NoiseObservation>& obs, bool held,
                    std::vector<double>* centre, std::vector<double>* var) {
  std::vector<const NoiseObservation*> o;
  for (const NoiseObservation& x : obs) {
    if (x.held == held) o.push_back(&x);
  }
  std::sort(o.begin(), o.end(),
            [](const NoiseObservation* a, const NoiseObservation* b) { return a->s < b->s; });
  const size_t bins = 10;
  for (size_t b = 0; b < bins && o.size() >= bins * 20; ++b) {
    const size_t lo = b * o.size() / bins, hi = (b + 1) * o.size() / bins;
    std::vector<double> r, s;
    for (size_t i = lo; i < hi; ++i) r.push_back(o[i]->r), s.push_back(o[i]->s);
    centre->push_back(Median(std::vector<double>(s)));
    var->push_back(RobustVariance(r));
  }
}

}  // namespace

// --- sensor noise from inverse pairs ---
void FitNoise(FitContext& ctx) {
  const double fs = ctx.fs;
  PhysicsLayer noise;
  noise.name = "noise";
  noise.unit = "full well, electrons";
  noise.off_value = 0;
  noise.residual_unit = "DN^2 RMS of the binned variance of P + I - W - B";
  const std::vector<std::pair<int, int>> pairs = InversePairs(ctx.frames);
  if (pairs.empty()) {
    noise.observable = false;
    noise.reason = "the sequence has no inverse pairs";
  } else {
    const std::vector<NoiseObservation> obs = NoiseObservations(ctx, pairs);
    std::vector<double> sc, sv, hc, hv;
    BinnedVariance(obs, false, &sc, &sv);
    BinnedVariance(obs, true, &hc, &hv);
    if (sc.size() < 3) {
      noise.observable = false;
      noise.reason = "too few pixels for the noise fit";
    } else {
      // Least squares var = K s + c.
      Eigen::MatrixXd a(static_cast<Eigen::Index>(sc.size()), 2);
      Eigen::VectorXd b(static_cast<Eigen::Index>(sc.size()));
      for (size_t i = 0; i < sc.size(); ++i) {
        a(static_cast<Eigen::Index>(i), 0) = sc[i];
        a(static_cast<Eigen::Index>(i), 1) = 1;
        b(static_cast<Eigen::Index>(i)) = sv[i];
      }
      const Eigen::Vector2d kc = a.colPivHouseholderQr().solve(b);
      const Eigen::VectorXd res = b - a * kc;
      const double dof = std::max<double>(1, static_cast<double>(sc.size()) - 2);
      const Eigen::Matrix2d cov = (res.squaredNorm() / dof) * (a.transpose() * a).inverse();
      const double k = kc(0), sigma_k = std::sqrt(std::max(0.0, cov(0, 0)));
      const double quant = 4.0 / 12.0;
      double mean_var = 0;
      for (double v : sv) mean_var += v / static_cast<double>(sv.size());
      std::vector<double> off, on;
      for (size_t i = 0; i < hc.size(); ++i) {
        off.push_back(hv[i] - quant);
        on.push_back(hv[i] - (k * hc[i] + kc(1)));
      }
      noise.heldout_residual_off = Rms(off);
      noise.heldout_residual_on = Rms(on);
      noise.samples = static_cast<int64_t>(obs.size());
      const bool above_quant = mean_var > 2 * quant;
      const bool significant = k > 0 && pipeline::Significant(k, sigma_k, 0);
      const bool drops = HeldoutDrops(noise, ctx.options.min_heldout_drop);
      if (k > 0) {
        noise.value = fs / k;
        noise.sigma = fs * sigma_k / (k * k);
        const double read_dn2 = std::max(0.0, kc(1) / 4 - 1.0 / 12);
        noise.extra["read_noise_e"] = std::sqrt(read_dn2) / k;
      }
      noise.extra["dn_per_electron"] = k;
      noise.extra["variance_offset_dn2"] = kc(1);
      noise.extra["mean_pair_variance_dn2"] = mean_var;
      noise.kept = above_quant && significant && drops;
      noise.reason = noise.kept ? StringPrintf(
                                      "inverse pairs vary by %.2f DN^2 (quantisation alone: "
                                      "%.2f), growing with signal: shot noise",
                                      mean_var, quant)
                                : StringPrintf(
                                      "inverse-pair variance %.2f DN^2 is what quantisation "
                                      "(%.2f) explains, or does not grow with signal",
                                      mean_var, quant);
    }
  }
  ctx.fit.layers.push_back(noise);
}

}  // namespace slshadow::twin::internal
