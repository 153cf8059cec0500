// Where the codecs break, against theory (issue 15, study 2): the decoder's errors under additive
// Gaussian sensor noise match the closed forms, and so do the break points read off a noise sweep.
//
// The view is the identity (camera pixel (u, v) sees projector pixel (u, v)), so no interpolation
// or blur mixes projector pixels, and images are 16-bit so camera quantisation adds nothing:
// the only error sources are the noise and the projector's own 8-bit patterns.
//  - Phase shifting, N equally spaced steps, least-squares phase (Surrel 1997; Bruning 1974):
//    sigma_phi = sqrt(2 / N) * sigma / B (rad), B the fringe amplitude in camera levels; in
//    projector pixels sigma_x = sigma_phi * P / (2 pi).
//  - Gray code with inverse frames: a bit is read from d = I_bit - I_inverse = +-C + n, n of
//    variance 2 sigma^2, C the camera contrast; it flips with p = Q(C / (sqrt(2) sigma)), and a
//    pixel of an n-bit axis decodes to a wrong column with 1 - (1 - p)^n.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <numbers>
#include <vector>

#include <opencv2/core.hpp>

#include "patterns/codec.h"
#include "patterns/synthetic.h"

namespace slshadow {
namespace {

constexpr int kW = 512, kH = 256;

void IdentityView(cv::Mat* mx, cv::Mat* my) {
  *mx = cv::Mat(kH, kW, CV_64FC1);
  *my = cv::Mat(kH, kW, CV_64FC1);
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      mx->at<double>(v, u) = u;
      my->at<double>(v, u) = v;
    }
  }
}

PatternSpec XOnly(PatternKind kind) {
  PatternSpec s;
  s.kind = kind;
  s.projector_width = kW;
  s.projector_height = kH;
  s.code_y = false;
  s.period_px = 16;
  return s;
}

DecodeOptions AcceptEverything() {
  DecodeOptions o;
  o.shadow_threshold = 0;
  o.contrast_threshold = 0;
  o.gray_edge_midpoint = false;
  return o;
}

// Standard deviation of the decoded column about the truth (projector px) over valid pixels;
// errors above a quarter period are unwrapping errors, counted apart.
struct PhaseStats {
  double sigma_px = 0;
  int64_t valid = 0, unwrap_errors = 0;
};

PhaseStats MeasurePhase(int steps, double sigma) {
  PatternSpec spec = XOnly(PatternKind::kPhaseShift);
  spec.phase_steps = steps;
  cv::Mat mx, my;
  IdentityView(&mx, &my);
  CameraSimOptions sim;
  sim.gain = 0.5;
  sim.offset = 40;
  sim.noise_sigma = sigma;
  sim.bit_depth = 16;
  sim.seed = 7 + static_cast<uint64_t>(steps);
  const ProjectorMap map = DecodePatterns(
      spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim), AcceptEverything());
  PhaseStats s;
  double sum2 = 0;
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const float x = map.proj_x.at<float>(v, u);
      if (!std::isfinite(x)) continue;
      const double e = x - u;
      if (std::abs(e) > spec.period_px / 4) {
        ++s.unwrap_errors;
        continue;
      }
      sum2 += e * e;
      ++s.valid;
    }
  }
  s.sigma_px = std::sqrt(sum2 / static_cast<double>(s.valid));
  return s;
}

TEST(DecodeTheory, PhaseNoiseFollowsTheSurrelBound) {
  const double amplitude = 0.5 * 0.5 * 255;  // gain x half the projector's 0..255 fringe swing
  for (const int steps : {3, 4, 8}) {
    for (const double sigma : {2.0, 4.0, 8.0}) {
      const PhaseStats s = MeasurePhase(steps, sigma);
      const double predicted =
          std::sqrt(2.0 / steps) * sigma / amplitude * 16 / (2 * std::numbers::pi);
      SCOPED_TRACE(testing::Message()
                   << "N = " << steps << ", sigma = " << sigma << " levels: measured " << s.sigma_px
                   << " px, predicted " << predicted << " px");
      std::printf("MEASURE phase N=%d sigma=%.0f levels: %.5f px (Surrel %.5f px, ratio %.4f)\n",
                  steps, sigma, s.sigma_px, predicted, s.sigma_px / predicted);
      EXPECT_GT(s.valid, int64_t{kW} * kH * 99 / 100);
      EXPECT_EQ(s.unwrap_errors, 0);
      // ~130 k samples: the standard deviation is known to 0.2 %; the 8-bit projector patterns
      // add a deterministic error of about 0.3 % of the variance at sigma = 2.
      EXPECT_NEAR(s.sigma_px / predicted, 1.0, 0.02);
    }
  }
}

double Q(double z) { return 0.5 * std::erfc(z / std::numbers::sqrt2); }

// Fraction of the decoded pixels decoded to a wrong column (with these options every pixel
// decodes but those whose white frame is not brighter than their black one).
double GrayWrongFraction(double sigma, int64_t* decoded) {
  const PatternSpec spec = XOnly(PatternKind::kGrayCode);
  cv::Mat mx, my;
  IdentityView(&mx, &my);
  CameraSimOptions sim;
  sim.gain = 0.1;  // contrast C = 25.5 levels around 100: no clipping within 6 sigma
  sim.offset = 100;
  sim.noise_sigma = sigma;
  sim.bit_depth = 16;
  sim.seed = 11;
  const ProjectorMap map = DecodePatterns(
      spec, SimulateCameraImages(GeneratePatterns(spec), mx, my, sim), AcceptEverything());
  int64_t wrong = 0;
  *decoded = 0;
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const float x = map.proj_x.at<float>(v, u);
      if (!std::isfinite(x)) continue;
      ++*decoded;
      wrong += x != static_cast<float>(u);
    }
  }
  return static_cast<double>(wrong) / static_cast<double>(*decoded);
}

double GrayWrongPredicted(double sigma, int bits) {
  const double contrast = 0.1 * 255;
  return 1 - std::pow(1 - Q(contrast / (std::numbers::sqrt2 * sigma)), bits);
}

TEST(DecodeTheory, GrayCodeBitErrorsAndBreakPointFollowTheNormalTail) {
  const int bits = XOnly(PatternKind::kGrayCode).GrayBits(0);
  ASSERT_EQ(bits, 9);
  // The sweep: wrong-column fraction against noise, each point against 1 - (1 - p)^n.
  const std::vector<double> sigmas = {3, 4, 5, 6, 7, 8, 9};
  std::vector<double> measured;
  for (const double sigma : sigmas) {
    int64_t decoded = 0;
    const double f = GrayWrongFraction(sigma, &decoded);
    const double predicted = GrayWrongPredicted(sigma, bits);
    SCOPED_TRACE(testing::Message()
                 << "sigma " << sigma << ": wrong " << f << ", predicted " << predicted);
    // The white - black test (threshold 0) fails like a bit: white - black = C + n.
    const double shadowed = Q(0.1 * 255 / (std::numbers::sqrt2 * sigma)) * kW * kH;
    EXPECT_NEAR(static_cast<double>(int64_t{kW} * kH - decoded), shadowed,
                5 * std::sqrt(shadowed) + 3);
    // Binomial: with >= 300 expected wrong pixels, 5 standard errors stay within 30 %; below that
    // the count is checked against 5 standard errors of a Poisson count.
    const double expected = predicted * static_cast<double>(decoded);
    EXPECT_NEAR(f * static_cast<double>(decoded), expected, 5 * std::sqrt(expected) + 3);
    std::printf(
        "MEASURE gray sigma=%.0f levels: wrong %.5f (theory %.5f), undecoded %ld (theory %.0f)\n",
        sigma, f, predicted, static_cast<long>(int64_t{kW} * kH - decoded), shadowed);
    measured.push_back(f);
  }
  // The break point: the noise at which 1 % of the pixels decode to a wrong column, read off the
  // sweep by log-linear interpolation, against the same crossing of the closed form (bisection).
  const double limit = 0.01;
  double sweep_break = NAN;
  for (size_t i = 0; i + 1 < sigmas.size(); ++i) {
    if (measured[i] < limit && measured[i + 1] >= limit) {
      const double t = (std::log(limit) - std::log(measured[i])) /
                       (std::log(measured[i + 1]) - std::log(measured[i]));
      sweep_break = sigmas[i] + t * (sigmas[i + 1] - sigmas[i]);
    }
  }
  double lo = 1, hi = 30;
  for (int k = 0; k < 60; ++k) {
    const double mid = 0.5 * (lo + hi);
    (GrayWrongPredicted(mid, bits) < limit ? lo : hi) = mid;
  }
  std::printf("MEASURE gray break point (1 %% wrong): sweep %.3f levels, theory %.3f levels\n",
              sweep_break, lo);
  ASSERT_TRUE(std::isfinite(sweep_break)) << "the sweep never crossed " << limit;
  EXPECT_NEAR(sweep_break / lo, 1.0, 0.05)
      << "break point: sweep " << sweep_break << ", theory " << lo;
}

}  // namespace
}  // namespace slshadow
