// The twin's physics fitted from real images (issue 13, step 3): "model no more than a scene
// needs", measured. Each layer of sim/scene.h that the images can inform is fitted, and kept only
// when it lowers a held-out residual by more than noise explains:
//
//   (W, B: the white and black levels of WhiteBlackImages below.)
//   exposure   DN = E * FS * albedo * cos_p * (d_ref / d_p)^2 * (R(max) - R(min)) for white -
//   black,
//              so E = median over lit part pixels of (W - B) / (FS * factor) (factor from the
//              twin's geometry pass). Always kept (the core model has it).
//              E comes from the object with most lit pixels (the reference).
//   albedo_<o> each other object o (uniform albedo): its reflectance from the same ratio on its
//              own pixels relative to E, kept when it differs from the part file's.
//   albedo     checkerboard parts only: the dark squares' reflectance ("albedo_dark"), from the
//              same ratio on pixels of each square colour (exposure from the light squares).
//   illumination_<camera>  a smooth field G(u, v) = g0 + sum c_ij u^i v^j (1 <= i + j <= degree,
//              u = (x - w/2) / (w/2), v = (y - h/2) / (h/2)) multiplying everything the camera
//              sees: projector non-uniformity, vignetting beyond the model, the part's tilt to the
//              light. Least squares (one 4-sigma reweighting) of (W - B) / (FS * factor * range) =
//              E G on the reference pixels; value = RMS of G - 1 over the lit part.
//   ambient    B = E * FS * ambient * albedo: ambient = median of B / (E * FS * albedo).
//   black_level_<camera>  B = o + E * FS * ambient * albedo * G: a sensor offset o (DN) that does
//              not scale with reflectance, fitted jointly with ambient (least squares, one offset
//              per camera). Observable only when the camera sees more than one reflectance (a
//              checkerboard, objects of different albedo); otherwise ambient stands for both (the
//              black frame looks the same). Without a black frame the black level is the darker of
//              each inverse pair, which projector blur raises near stripe edges: ambient / offset
//              are then upper bounds (the reason says so).
//   global_light  a fraction g of the white level arrives scattered from the whole lit projector
//              image (interreflections, projector flare): a frame with lit fraction m reads
//              B + (W - B) ((1 - g) p + g m). Coarse inverse pairs (about half lit, stripes wide
//              against the blur) differ by (1 - g) (W - B): g = 1 - median over pixels of the
//              per-pixel median over those pairs of |P - I| / (W - B).
//   gamma      phase codecs only (binary patterns do not see a response): the N phase frames of
//              a period, normalised r_n = (I_n - B) / (W - B), average a0(gamma) = the mean of
//              (0.5 + 0.5 cos t)^gamma over a period (0.5 for a linear response), whatever the
//              phase, the blur (it keeps the mean) or the frame order; gamma inverts the median
//              of that average. No projector coordinate is needed, and noise enters linearly.
//   defocus    fringe contrast: the median ratio rho of the real fringe modulation to the focused
//              twin's (phase codecs: B' of the first period on x; Gray code: |P - I| of the
//              finest x bit) gives a Gaussian projector blur sigma = P / (pi sqrt 2) sqrt(-ln rho)
//              (P: the fringe period; 4 px for the finest Gray bit). Needs the twin's images.
//   noise      inverse pairs: r = (P + I) - (P' + I') of two pairs (or W + B) has variance
//              K S + 4 (sigma_read^2 + 1/12) DN^2 (S = the four values' sum, K = FS / full_well DN
//              per electron, 1/12 the quantisation), fitted by a line through per-bin robust
//              variances.
//
// Uncertainty: each value is also fitted on 8 horizontal bands of the image; sigma = standard
// deviation of the band values / sqrt(8) (bands absorb the pixels' spatial correlation). The
// least-squares layers (illumination, black level) use the delete-one-band jackknife instead,
// which does not see the bias of a mean of integer DN when the frames' noise is below 1 DN (up to
// ~0.3 DN at 8 bits): the keep floors cover it.
// Keep rule: |value - off value| > max(3 sigma, a practical floor)
// (workflows/pipeline/significance.h Significant: the rule the physics study judges layers by too)
// AND the residual on held-out pixels (odd sample rows; fits use even rows) drops by more than the
// stated fraction.
#pragma once

#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "sim/renderer.h"
#include "sim/scene.h"

namespace slshadow::twin {

struct PhysicsLayer {
  std::string
      name;  // "exposure", "albedo_<object>", "albedo_dark", "ambient", "gamma", "defocus", "noise"
  bool observable = true;  // false: the images cannot inform it (reason says why)
  bool kept = false;
  double value = 0;      // fitted value (unit below); noise: full well, electrons
  double sigma = 0;      // its standard uncertainty
  double off_value = 0;  // value meaning "layer off"
  std::string unit;
  double heldout_residual_off = 0;  // residual with the layer off / on (residual_unit)
  double heldout_residual_on = 0;
  std::string residual_unit;
  int64_t samples = 0;
  std::string reason;                               // why kept or left off, one sentence
  nlohmann::json extra = nlohmann::json::object();  // e.g. read noise, sigma in px
  nlohmann::json ToJson() const;
};

struct PhysicsFitOptions {
  int stride_px = 2;               // sample every stride-th pixel in x and y
  double min_factor = 0.02;        // ignore pixels whose geometric factor is below this
  double min_heldout_drop = 0.05;  // keep: held-out residual must drop by at least this fraction
  double gamma_floor = 0.05;       // keep gamma only if |gamma - 1| exceeds this as well
  double defocus_min_loss = 0.04;  // keep defocus only if the modulation loss exceeds this
  int illumination_degree = 2;  // polynomial degree of the illumination field, 0..4 (0: layer off)
  double illumination_floor =
      0.01;  // keep the field only if its RMS variation exceeds this as well
  double black_level_floor =
      0.002;  // keep an offset only if it exceeds this fraction of full scale as well
  double global_light_floor = 0.01;  // keep global light only if its fraction exceeds this as well
  void Check() const;
};

// What the real images of one camera are compared with: its images (spec order) and the focused
// twin's geometry pass of that camera (and, for defocus, the twin's rendered images).
struct CameraData {
  std::string camera;
  std::vector<cv::Mat> real;  // CV_8UC1 or CV_16UC1, spec.NumImages()
  const GeometryBuffer* geometry = nullptr;
  std::vector<cv::Mat> twin;  // rendered focused twin images (defocus fit); may be empty
  cv::Mat white, black;       // real white / black levels (WhiteBlackImages); computed when empty
  cv::Mat real_modulation,
      twin_modulation;             // FitDefocus's NormalisedModulation maps, kept for reuse
  cv::Mat twin_white, twin_black;  // FitDefocus's white / black levels of `twin`
};

struct PhysicsFit {
  std::vector<PhysicsLayer> layers;
  const PhysicsLayer* Find(const std::string& name) const;
  bool Kept(const std::string& name) const;
  // The twin scene with the fitted values of the kept layers (exposure always; albedo of a
  // checkerboard part; ambient, response gamma, projector defocus, noise with `noise_seed`).
  // `rig` and `depth_mm` (the part's typical depth along the projector axis) size the defocus
  // layer's physical parameters so that its blur sigma at that depth equals the fitted one.
  // The image layers (illumination, black level, global light) are not scene layers: the
  // rendered images get them from ApplyImageLayers below.
  Scene Apply(const Scene& twin, const Rig& rig, double projector_depth_mm,
              uint64_t noise_seed) const;
  nlohmann::json ToJson() const;
  std::string Table() const;  // one line per layer
};

// The fitted image layers the renderer does not model, applied to one camera's rendered twin
// images (spec order; empty Mats, frames not rendered, are left alone) in place: first
// global_light, I = B + (1 - g) (I - B) + g m_k (W - B) with m_k = pattern_means[k] and W, B the
// images' own white / black levels (WhiteBlackImages); then I' = o + G(x, y) I
// (black_level_<camera>, illumination_<camera>); rounded and saturated to the images' depth. No-op
// when none is kept.
void ApplyImageLayers(const PhysicsFit& fit, const PatternSpec& spec,
                      const std::vector<double>& pattern_means, const std::string& camera,
                      std::vector<cv::Mat>* images);
// Lit fraction of each projector image (mean / full scale).
std::vector<double> PatternMeans(const std::vector<cv::Mat>& projector_images);
// The illumination field G of `camera` (CV_32FC1, width x height); all ones when not kept.
cv::Mat IlluminationField(const PhysicsFit& fit, const std::string& camera, int width, int height);

// Fits exposure, the illumination field, albedo, ambient, black level, global light, gamma and
// noise (everything but defocus) from the real images
// and the twin's geometry (`twin` is the scene the geometry was traced with, albedo as given by
// the part). Throws slshadow::Error when the sequence has no white / black frame or no lit part
// pixel is found.
PhysicsFit FitPhysics(const PatternSpec& spec, const Scene& twin,
                      const std::vector<CameraData>& cameras,
                      const PhysicsFitOptions& options = {});

// Adds the defocus layer to `fit` from the real images against the twin's rendered images
// (cameras[i].twin, rendered with `fit` applied, focused).
void FitDefocus(const PatternSpec& spec, std::vector<CameraData>& cameras,
                const PhysicsFitOptions& options, PhysicsFit* fit);

// Per pixel white and black levels (CV_32FC1) of one camera's images: the white and black frames
// when the sequence has them, else the median over the Gray-code inverse pairs of max(P, I) and
// min(P, I) (a binary pair shows each pixel once lit and once dark). Throws when neither exists.
void WhiteBlackImages(const PatternSpec& spec, const std::vector<cv::Mat>& images, cv::Mat* white,
                      cv::Mat* black);

// Fringe modulation per pixel of one camera's images (CV_32FC1, NaN where not computable),
// normalised by white - black: phase codecs: B' / (W - B) of the first period on x, with
// B' = sqrt(2 var(I_n)) (independent of the frames' order); Gray code:
// |P - I| / (W - B) of the finest x bit. Used by FitDefocus and the multipath signature.
cv::Mat NormalisedModulation(const PatternSpec& spec, const std::vector<cv::Mat>& images);
// The same with the images' white and black levels already at hand.
cv::Mat NormalisedModulation(const PatternSpec& spec, const std::vector<cv::Mat>& images,
                             const cv::Mat& white, const cv::Mat& black);
// The frames NormalisedModulation reads (spec indices; -1 where the sequence lacks one).
std::vector<int> ModulationFrames(const PatternSpec& spec);
// The fringe period the modulation above refers to, projector px.
double ModulationPeriodPx(const PatternSpec& spec);

}  // namespace slshadow::twin
