// What workflows/twin/physics_fit.cc (the public physics fit) and
// workflows/twin/internal/physics_fit_layers.cc (one function per layer of FitPhysics) share: the
// tools both use (defined in physics_fit.cc) and the layer fits FitPhysics runs in order over one
// FitContext. Included only by those two.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/statistics.h"
#include "workflows/pipeline/significance.h"
#include "workflows/twin/physics_fit.h"

namespace slshadow::twin::internal {

// --- tools (workflows/twin/physics_fit.cc) ---

inline constexpr int kBands = pipeline::kSignificanceBands;

inline float Pixel(const cv::Mat& m, int y, int x) {
  return m.depth() == CV_8U ? static_cast<float>(m.at<uint8_t>(y, x))
                            : static_cast<float>(m.at<uint16_t>(y, x));
}

// Variance of the values within 4 robust sigmas of the median (the MAD alone is biased for
// integer-valued data: its median snaps to the grid).
double RobustVariance(const std::vector<double>& v);
double Rms(const std::vector<double>& v);

// The band of image row y (kBands horizontal bands), and whether the row is held out (odd sample
// rows; the fits use the even ones).
inline int BandOfRow(int y, int height) { return std::min(kBands - 1, y * kBands / height); }
inline bool HeldOutRow(int y, int stride_px) { return (y / stride_px) % 2 == 1; }

// Values of a statistic, all of them and per band of the image.
struct BandedValues {
  std::vector<double> all;
  std::vector<std::vector<double>> bands = std::vector<std::vector<double>>(kBands);
  void Add(int band, double v) {
    all.push_back(v);
    bands[static_cast<size_t>(band)].push_back(v);
  }
  // BandSigma (workflows/pipeline/significance.h) of `statistic` of each band's values; NaN for the
  // bands with `min_values` values or fewer.
  template <typename F>
  double Sigma(size_t min_values, F&& statistic) const {
    std::vector<double> v;
    for (const auto& b : bands) v.push_back(b.size() > min_values ? statistic(b) : std::nan(""));
    return pipeline::BandSigma(v);
  }
  double MedianSigma() const {
    return Sigma(20, [](const std::vector<double>& b) { return Median(std::vector<double>(b)); });
  }
};

// The keep rule's second half: the held-out residual with the layer on is below (1 - min_drop)
// of the one with it off.
bool HeldoutDrops(const PhysicsLayer& l, double min_drop);

int FindFrame(const std::vector<FrameInfo>& frames, FrameRole role, int axis, int bit,
              int frequency, int step);
std::vector<std::pair<int, int>> InversePairs(const std::vector<FrameInfo>& frames);
// The N phase frames of the first period on the coded axis (x unless only y is coded), spec
// indices; -1 where the sequence lacks one.
std::vector<int> FirstPeriodPhaseFrames(const PatternSpec& spec,
                                        const std::vector<FrameInfo>& frames);

// Monomials u^i v^j, 1 <= i + j <= degree (u, v in [-1, 1] over the image).
std::vector<std::pair<int, int>> IlluminationTerms(int degree);
// 1 and the monomials of IlluminationTerms(degree) at (u, v), into out[0..terms.size()].
void MonomialRow(const std::vector<std::pair<int, int>>& terms, int degree, double u, double v,
                 double* out);
inline double NormalisedCoordinate(int x, int size) { return (x - 0.5 * size) / (0.5 * size); }

// Linear least squares y = X beta over rows in bands (kBands), with one reweighting pass that
// drops rows beyond 4 robust sigmas of the first fit, and the delete-one-band solutions for a
// jackknife of any function of beta.
struct LinearFit {
  Eigen::VectorXd beta;
  std::vector<Eigen::VectorXd> jackknife;  // one per band that had rows
  int64_t rows = 0, inliers = 0;
  std::vector<char> inlier;  // per row: within the outlier gate (the rows the fit used)
  bool ok = false;
};
LinearFit FitLinear(const std::vector<double>& x, const std::vector<double>& y,
                    const std::vector<int>& band, int p);

// Jackknife standard deviation of a statistic over the delete-one-band solutions.
template <typename F>
double JackknifeSigma(const LinearFit& fit, F&& statistic) {
  std::vector<double> v;
  for (const auto& b : fit.jackknife) v.push_back(statistic(b));
  if (v.size() < 2) return std::nan("");
  const double mean = std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
  double ss = 0;
  for (double x : v) ss += (x - mean) * (x - mean);
  const double m = static_cast<double>(v.size());
  return std::sqrt((m - 1) / m * ss);
}
// Jackknife standard deviation of the coefficient k.
double CoefficientSigma(const LinearFit& fit, int k);

// --- the layers (workflows/twin/internal/physics_fit_layers.cc) ---

// One sampled pixel of a camera where the twin sees the part lit.
struct Sample {
  float white = 0, black = 0, factor = 0, albedo = 0;
  float gain = 1;         // the illumination field at the pixel (1 until that layer is kept)
  float twin_albedo = 0;  // the albedo the fitted twin renders there (after the albedo layers)
  int camera = 0, y = 0, x = 0, band = 0, object = 0;
  bool heldout = false;
};

// What every layer's fit reads: the inputs, the lit part pixels, and the fit built so far (its
// layers in the order fitted; a layer reads the values of those before it).
struct FitContext {
  // The white / black levels (CameraData's, else WhiteBlackImages) and the lit part pixels of
  // every camera; throws when fewer than 100 are found.
  FitContext(const PatternSpec& spec, const Scene& twin, const std::vector<CameraData>& cameras,
             const PhysicsFitOptions& options);

  const PatternSpec& spec;
  const Scene& twin;
  const std::vector<CameraData>& cameras;
  const PhysicsFitOptions& options;
  bool has_white_black = false;   // the sequence has white and black frames
  double fs = 0;                  // full scale, DN
  std::vector<FrameInfo> frames;  // spec.Frames()
  double range = 0;               // R(max) - R(min), linear
  const Albedo* board = nullptr;  // the checkerboard part's dark / light reflectances, if any
  std::vector<Sample> samples;
  int reference = 0;  // the object with most lit pixels: the exposure comes from it
  double e = 0;       // the exposure, once FitExposure has run
  PhysicsFit fit;

  // A pixel the exposure is fitted on: the reference object's (its light squares on a board).
  bool IsLight(const Sample& s) const {
    return s.object == reference && (!board || std::abs(s.albedo - board->light) < 1e-3);
  }
  bool IsDark(const Sample& s) const { return board && std::abs(s.albedo - board->dark) < 1e-3; }
  // (W - B) / (FS factor range G): exposure x albedo over the twin's albedo.
  double Ratio(const Sample& s) const {
    return (s.white - s.black) / (fs * s.factor * range * s.gain);
  }
};

// The white - black contrast a pixel needs to count as well lit: 0.3 x the median over the samples.
double WellLitContrast(const std::vector<Sample>& samples);

// The layers, in the order FitPhysics fits them (workflows/twin/physics_fit.h describes each); each
// appends its layers to ctx.fit. Gamma, global light and noise: physics_fit_response.cc.
void FitExposure(FitContext& ctx);               // exposure; sets ctx.e
void FitIlluminationFields(FitContext& ctx);     // illumination_<camera>; kept: the samples' gain
void FitObjectAlbedos(FitContext& ctx);          // albedo_<object>
void FitDarkSquares(FitContext& ctx);            // albedo_dark (a checkerboard part)
void FitAmbientAndBlackLevels(FitContext& ctx);  // ambient, black_level_<camera>
void FitGamma(FitContext& ctx);                  // gamma
void FitGlobalLight(FitContext& ctx);            // global_light
void FitNoise(FitContext& ctx);                  // noise

}  // namespace slshadow::twin::internal
