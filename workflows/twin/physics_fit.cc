#include "workflows/twin/physics_fit.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "core/error.h"
#include "core/statistics.h"
#include "core/string_printf.h"
#include "patterns/codec.h"
#include "workflows/pipeline/significance.h"
#include "workflows/twin/internal/physics_fit_layers.h"

namespace slshadow::twin {
// The tools workflows/twin/internal/physics_fit_layers.h declares.
namespace internal {

// Variance of the values within 4 robust sigmas of the median (the MAD alone is biased for
// integer-valued data: its median snaps to the grid).
double RobustVariance(const std::vector<double>& v) {
  if (v.size() < 8) return std::nan("");
  const double med = Median(std::vector<double>(v));
  std::vector<double> dev;
  dev.reserve(v.size());
  for (double x : v) dev.push_back(std::abs(x - med));
  const double gate = 4 * std::max(1.4826 * Median(std::move(dev)), 1.0);
  double sum = 0, ss = 0;
  int64_t n = 0;
  for (double x : v) {
    if (std::abs(x - med) > gate) continue;
    sum += x, ss += x * x, ++n;
  }
  const double mean = sum / static_cast<double>(n);
  return ss / static_cast<double>(n) - mean * mean;
}

// The keep rule's second half: the held-out residual with the layer on is below (1 - min_drop)
// of the one with it off.
bool HeldoutDrops(const PhysicsLayer& l, double min_drop) {
  return l.heldout_residual_on < (1 - min_drop) * l.heldout_residual_off;
}

int FindFrame(const std::vector<FrameInfo>& frames, FrameRole role, int axis, int bit,
              int frequency, int step) {
  for (size_t i = 0; i < frames.size(); ++i) {
    const FrameInfo& f = frames[i];
    if (f.role != role) continue;
    if (role == FrameRole::kWhite || role == FrameRole::kBlack) return static_cast<int>(i);
    if (f.axis != axis) continue;
    if ((role == FrameRole::kGrayBit || role == FrameRole::kGrayBitInverse) && f.bit == bit)
      return static_cast<int>(i);
    if (role == FrameRole::kPhase && f.frequency == frequency && f.step == step)
      return static_cast<int>(i);
  }
  return -1;
}

double Rms(const std::vector<double>& v) {
  if (v.empty()) return std::nan("");
  double s = 0;
  for (double x : v) s += x * x;
  return std::sqrt(s / static_cast<double>(v.size()));
}

std::vector<std::pair<int, int>> InversePairs(const std::vector<FrameInfo>& frames) {
  std::vector<std::pair<int, int>> pairs;
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role != FrameRole::kGrayBit) continue;
    const int inv =
        FindFrame(frames, FrameRole::kGrayBitInverse, frames[i].axis, frames[i].bit, 0, 0);
    if (inv >= 0) pairs.emplace_back(static_cast<int>(i), inv);
  }
  return pairs;
}

// Monomials u^i v^j, 1 <= i + j <= degree (u, v in [-1, 1] over the image).
std::vector<std::pair<int, int>> IlluminationTerms(int degree) {
  std::vector<std::pair<int, int>> t;
  for (int d = 1; d <= degree; ++d) {
    for (int j = 0; j <= d; ++j) t.emplace_back(d - j, j);
  }
  return t;
}

// 1 and the monomials of IlluminationTerms(degree) at (u, v), into out[0..terms.size()].
void MonomialRow(const std::vector<std::pair<int, int>>& terms, int degree, double u, double v,
                 double* out) {
  double pu[8] = {1}, pv[8] = {1};
  for (int k = 1; k <= degree && k < 8; ++k) pu[k] = pu[k - 1] * u, pv[k] = pv[k - 1] * v;
  out[0] = 1;
  for (size_t k = 0; k < terms.size(); ++k) out[k + 1] = pu[terms[k].first] * pv[terms[k].second];
}

LinearFit FitLinear(const std::vector<double>& x, const std::vector<double>& y,
                    const std::vector<int>& band, int p) {
  LinearFit f;
  const size_t n = y.size();
  f.rows = static_cast<int64_t>(n);
  if (n < static_cast<size_t>(10 * p)) return f;
  const auto solve = [&](const std::vector<char>& use, Eigen::VectorXd* beta,
                         std::vector<Eigen::VectorXd>* jack) {
    std::vector<Eigen::MatrixXd> ab(kBands, Eigen::MatrixXd::Zero(p, p));
    std::vector<Eigen::VectorXd> rb(kBands, Eigen::VectorXd::Zero(p));
    std::vector<int64_t> nb(kBands, 0);
    for (size_t i = 0; i < n; ++i) {
      if (!use[i]) continue;
      const Eigen::Map<const Eigen::VectorXd> xi(&x[i * static_cast<size_t>(p)], p);
      const auto b = static_cast<size_t>(band[i]);
      ab[b].selfadjointView<Eigen::Lower>().rankUpdate(xi);
      rb[b] += xi * y[i];
      ++nb[b];
    }
    Eigen::MatrixXd a = Eigen::MatrixXd::Zero(p, p);
    Eigen::VectorXd r = Eigen::VectorXd::Zero(p);
    for (int b = 0; b < kBands; ++b)
      a += ab[static_cast<size_t>(b)], r += rb[static_cast<size_t>(b)];
    const auto sym = [](const Eigen::MatrixXd& m) {
      return Eigen::MatrixXd(m.selfadjointView<Eigen::Lower>());
    };
    *beta = sym(a).ldlt().solve(r);
    if (!jack) return;
    jack->clear();
    for (int b = 0; b < kBands; ++b) {
      if (nb[static_cast<size_t>(b)] == 0) continue;
      jack->push_back(
          sym(a - ab[static_cast<size_t>(b)]).ldlt().solve(r - rb[static_cast<size_t>(b)]));
    }
  };
  std::vector<char> use(n, 1);
  Eigen::VectorXd beta;
  solve(use, &beta, nullptr);
  std::vector<double> res(n);
  for (size_t i = 0; i < n; ++i)
    res[i] = y[i] - Eigen::Map<const Eigen::VectorXd>(&x[i * static_cast<size_t>(p)], p).dot(beta);
  std::vector<double> abs_res(n);
  for (size_t i = 0; i < n; ++i) abs_res[i] = std::abs(res[i]);
  const double gate = 4 * 1.4826 * std::max(Median(std::vector<double>(abs_res)), 1e-12);
  for (size_t i = 0; i < n; ++i) use[i] = std::abs(res[i]) <= gate;
  f.inliers = std::count(use.begin(), use.end(), 1);
  solve(use, &f.beta, &f.jackknife);
  f.inlier = std::move(use);
  f.ok = f.beta.allFinite() && f.jackknife.size() >= 3;
  return f;
}

// Jackknife standard deviation of the coefficient k.
double CoefficientSigma(const LinearFit& fit, int k) {
  return JackknifeSigma(fit, [k](const Eigen::VectorXd& b) { return b(k); });
}

// The N phase frames of the first period on the coded axis (x unless only y is coded), spec
// indices; -1 where the sequence lacks one.
std::vector<int> FirstPeriodPhaseFrames(const PatternSpec& spec,
                                        const std::vector<FrameInfo>& frames) {
  const int axis = spec.code_x ? 0 : 1;
  std::vector<int> idx;
  for (int k = 0; k < spec.phase_steps; ++k)
    idx.push_back(FindFrame(frames, FrameRole::kPhase, axis, 0, 0, k));
  return idx;
}

}  // namespace internal

using internal::BandedValues;
using internal::BandOfRow;
using internal::FindFrame;
using internal::FirstPeriodPhaseFrames;
using internal::HeldoutDrops;
using internal::HeldOutRow;
using internal::IlluminationTerms;
using internal::InversePairs;
using internal::MonomialRow;
using internal::NormalisedCoordinate;
using internal::Pixel;
using internal::Rms;

void WhiteBlackImages(const PatternSpec& spec, const std::vector<cv::Mat>& images, cv::Mat* white,
                      cv::Mat* black) {
  const int w = spec.WhiteFrameIndex(), b = spec.BlackFrameIndex();
  if (w >= 0 && b >= 0) {
    images.at(static_cast<size_t>(w)).convertTo(*white, CV_32F);
    images.at(static_cast<size_t>(b)).convertTo(*black, CV_32F);
    return;
  }
  const auto pairs = InversePairs(spec.Frames());
  SLSHADOW_THROW_IF(
      pairs.empty(),
      "white / black levels: the sequence has neither white and black frames nor inverse pairs");
  const cv::Mat& first = images.at(0);
  white->create(first.size(), CV_32FC1);
  black->create(first.size(), CV_32FC1);
  // Per row: hi_k = max(P_k, I_k), lo_k = min(P_k, I_k) of every pair, sorted across k by a
  // compare-exchange network over whole rows (vectorised), then the element n/2 of each.
  const auto medians = [&](auto zero) {
    using T = decltype(zero);
    cv::parallel_for_(cv::Range(0, first.rows), [&](const cv::Range& rows) {
      const size_t n = pairs.size(), w = static_cast<size_t>(first.cols);
      std::vector<T> hi(n * w), lo(n * w);
      for (int y = rows.start; y < rows.end; ++y) {
        for (size_t k = 0; k < n; ++k) {
          const T* p = images[static_cast<size_t>(pairs[k].first)].ptr<T>(y);
          const T* q = images[static_cast<size_t>(pairs[k].second)].ptr<T>(y);
          T* h = &hi[k * w];
          T* l = &lo[k * w];
          for (size_t x = 0; x < w; ++x) h[x] = std::max(p[x], q[x]), l[x] = std::min(p[x], q[x]);
        }
        for (size_t i = 0; i + 1 < n; ++i) {
          for (size_t j = i + 1; j < n; ++j) {
            for (std::vector<T>* v : {&hi, &lo}) {
              T* a = &(*v)[i * w];
              T* b = &(*v)[j * w];
              for (size_t x = 0; x < w; ++x) {
                const T lo_ab = std::min(a[x], b[x]), hi_ab = std::max(a[x], b[x]);
                a[x] = lo_ab, b[x] = hi_ab;
              }
            }
          }
        }
        const T* hm = &hi[(n / 2) * w];
        const T* lm = &lo[(n / 2) * w];
        float* wr = white->ptr<float>(y);
        float* br = black->ptr<float>(y);
        for (size_t x = 0; x < w; ++x) wr[x] = hm[x], br[x] = lm[x];
      }
    });
  };
  if (first.depth() == CV_8U) {
    medians(uint8_t{0});
  } else {
    medians(uint16_t{0});
  }
}

nlohmann::json PhysicsLayer::ToJson() const {
  nlohmann::json j = {{"name", name},
                      {"observable", observable},
                      {"kept", kept},
                      {"value", value},
                      {"sigma", sigma},
                      {"off_value", off_value},
                      {"unit", unit},
                      {"heldout_residual_off", heldout_residual_off},
                      {"heldout_residual_on", heldout_residual_on},
                      {"residual_unit", residual_unit},
                      {"samples", samples},
                      {"reason", reason}};
  if (!extra.empty()) j["extra"] = extra;
  return j;
}

void PhysicsFitOptions::Check() const {
  SLSHADOW_THROW_IF(stride_px < 1, "physics fit: stride_px must be >= 1 (got ", stride_px, ")");
  SLSHADOW_THROW_IF(!(min_factor >= 0), "physics fit: min_factor must be >= 0 (got ", min_factor,
                    ")");
  SLSHADOW_THROW_IF(!(min_heldout_drop >= 0 && min_heldout_drop < 1),
                    "physics fit: min_heldout_drop must be in [0, 1) (got ", min_heldout_drop, ")");
  SLSHADOW_THROW_IF(illumination_degree < 0 || illumination_degree > 4,
                    "physics fit: illumination_degree must be in 0..4 (got ", illumination_degree,
                    ")");
}

const PhysicsLayer* PhysicsFit::Find(const std::string& name) const {
  for (const auto& l : layers) {
    if (l.name == name) return &l;
  }
  return nullptr;
}

bool PhysicsFit::Kept(const std::string& name) const {
  const PhysicsLayer* l = Find(name);
  return l && l->kept;
}

nlohmann::json PhysicsFit::ToJson() const {
  nlohmann::json j = nlohmann::json::array();
  for (const auto& l : layers) j.push_back(l.ToJson());
  return j;
}

std::string PhysicsFit::Table() const {
  std::string out;
  for (const auto& l : layers) {
    char buf[512];
    std::snprintf(buf, sizeof(buf), "  %-20s %-5s %12.5g +- %-10.3g %-10s %s\n", l.name.c_str(),
                  !l.observable ? "n/a" : (l.kept ? "kept" : "off"), l.value, l.sigma,
                  l.unit.c_str(), l.reason.c_str());
    out += buf;
  }
  return out;
}

Scene PhysicsFit::Apply(const Scene& twin, const Rig& rig, double projector_depth_mm,
                        uint64_t noise_seed) const {
  Scene scene = twin;
  if (const PhysicsLayer* e = Find("exposure")) scene.radiometry.exposure_fraction = e->value;
  if (const PhysicsLayer* d = Find("albedo_dark"); d && d->kept) {
    for (auto& o : scene.objects) {
      if (o.albedo.kind == Albedo::Kind::kCheckerboard) o.albedo.dark = d->value;
    }
  }
  for (auto& o : scene.objects) {
    if (const PhysicsLayer* a = Find("albedo_" + o.name);
        a && a->kept && o.albedo.kind == Albedo::Kind::kUniform) {
      o.albedo.value = a->value;
    }
  }
  if (Kept("ambient")) scene.layers.ambient = Find("ambient")->value;
  if (Kept("gamma")) {
    scene.layers.response_enabled = true;
    scene.layers.gamma = Find("gamma")->value;
  }
  if (Kept("defocus") && rig.projector) {
    const double sigma_px = Find("defocus")->value;
    auto& d = scene.layers.projector_defocus;
    d.enabled = true;
    d.focus_distance_mm = 1e7;  // focused far away: blur ~ 1 / depth, flat over a part's depth
    const double f_mm = rig.projector->model.fx() * d.pixel_pitch_um * 1e-3;
    // c = f^2 (D - d) / (N d (D - f)) mm on the sensor, sigma = c / (4 pitch): solve for N.
    const double c_mm = 4 * sigma_px * d.pixel_pitch_um * 1e-3;
    d.f_number = f_mm * f_mm * (d.focus_distance_mm - projector_depth_mm) /
                 (c_mm * projector_depth_mm * (d.focus_distance_mm - f_mm));
  }
  if (const PhysicsLayer* n = Find("noise"); n && n->kept) {
    scene.layers.noise_enabled = true;
    scene.layers.full_well_e = n->value;
    scene.layers.read_noise_e = n->extra.value("read_noise_e", 0.0);
    scene.layers.seed = noise_seed;
  }
  return scene;
}

cv::Mat IlluminationField(const PhysicsFit& fit, const std::string& camera, int width, int height) {
  cv::Mat g(height, width, CV_32FC1, cv::Scalar(1));
  const PhysicsLayer* l = fit.Find("illumination_" + camera);
  if (!l || !l->kept) return g;
  const int degree = l->extra.at("degree").get<int>();
  const std::vector<std::pair<int, int>> terms = IlluminationTerms(degree);
  const auto& c = l->extra.at("coefficients");
  const std::vector<double> coefficients = c.get<std::vector<double>>();
  SLSHADOW_THROW_IF(c.size() != terms.size() + 1, "illumination field of '", camera,
                    "': ", c.size(), " coefficients for ", terms.size() + 1, " terms");
  // The field was fitted on images of extra.width x extra.height; scale coordinates to this size.
  const int fw = l->extra.value("width", width), fh = l->extra.value("height", height);
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    std::vector<double> row(terms.size() + 1);
    for (int y = rows.start; y < rows.end; ++y) {
      float* out = g.ptr<float>(y);
      const double v =
          NormalisedCoordinate(static_cast<int>(std::lround((y + 0.5) * fh / height - 0.5)), fh);
      for (int x = 0; x < width; ++x) {
        const double u =
            NormalisedCoordinate(static_cast<int>(std::lround((x + 0.5) * fw / width - 0.5)), fw);
        MonomialRow(terms, degree, u, v, row.data());
        double sum = 0;
        for (size_t k = 0; k < row.size(); ++k) sum += coefficients[k] * row[k];
        out[x] = static_cast<float>(sum);
      }
    }
  });
  return g;
}

std::vector<double> PatternMeans(const std::vector<cv::Mat>& projector_images) {
  std::vector<double> m;
  for (const cv::Mat& p : projector_images)
    m.push_back(cv::mean(p)[0] / (p.depth() == CV_8U ? 255.0 : 65535.0));
  return m;
}

void ApplyImageLayers(const PhysicsFit& fit, const PatternSpec& spec,
                      const std::vector<double>& pattern_means, const std::string& camera,
                      std::vector<cv::Mat>* images) {
  const PhysicsLayer* bl = fit.Find("black_level_" + camera);
  const double offset = bl && bl->kept ? bl->value : 0.0;
  const bool field = fit.Kept("illumination_" + camera);
  const double global = fit.Kept("global_light") ? fit.Find("global_light")->value : 0.0;
  if ((offset == 0 && !field && global == 0) || images->empty()) return;
  SLSHADOW_THROW_IF(pattern_means.size() != images->size(), "image layers: ", pattern_means.size(),
                    " pattern means for ", images->size(), " images");
  const auto first =
      std::find_if(images->begin(), images->end(), [](const cv::Mat& m) { return !m.empty(); });
  if (first == images->end()) return;
  const cv::Mat g = IlluminationField(fit, camera, first->cols, first->rows);
  cv::Mat white, black;
  if (global != 0) WhiteBlackImages(spec, *images, &white, &black);
  cv::parallel_for_(cv::Range(0, static_cast<int>(images->size())), [&](const cv::Range& r) {
    cv::Mat f;
    for (int i = r.start; i < r.end; ++i) {
      cv::Mat& img = (*images)[static_cast<size_t>(i)];
      if (img.empty()) continue;  // a frame not rendered
      img.convertTo(f, CV_32F);
      if (global != 0) {  // B + (1 - g) (I - B) + g m (W - B)
        const float keep = static_cast<float>(1 - global),
                    m = static_cast<float>(global * pattern_means[static_cast<size_t>(i)]);
        for (int y = 0; y < f.rows; ++y) {
          float* p = f.ptr<float>(y);
          const float* w = white.ptr<float>(y);
          const float* b = black.ptr<float>(y);
          for (int x = 0; x < f.cols; ++x) p[x] = b[x] + keep * (p[x] - b[x]) + m * (w[x] - b[x]);
        }
      }
      if (field) cv::multiply(f, g, f);
      f.convertTo(img, img.depth(), 1.0, offset);  // rounds and saturates
    }
  });
}

PhysicsFit FitPhysics(const PatternSpec& spec, const Scene& twin,
                      const std::vector<CameraData>& cameras, const PhysicsFitOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(cameras.empty(), "physics fit: no camera");
  internal::FitContext ctx(spec, twin, cameras, options);  // white / black, the lit part pixels
  internal::FitExposure(ctx);
  internal::FitIlluminationFields(ctx);
  internal::FitObjectAlbedos(ctx);
  internal::FitDarkSquares(ctx);
  internal::FitAmbientAndBlackLevels(ctx);
  internal::FitGamma(ctx);
  internal::FitGlobalLight(ctx);
  internal::FitNoise(ctx);
  return std::move(ctx.fit);
}

double ModulationPeriodPx(const PatternSpec& spec) {
  if (spec.kind == PatternKind::kGrayCode) return 4.0;  // the finest Gray bit: 2 px stripes
  return spec.PeriodsPx().front();
}

std::vector<int> ModulationFrames(const PatternSpec& spec) {
  const std::vector<FrameInfo> frames = spec.Frames();
  if (spec.kind != PatternKind::kGrayCode) return FirstPeriodPhaseFrames(spec, frames);
  const int axis = spec.code_x ? 0 : 1;
  return {FindFrame(frames, FrameRole::kGrayBit, axis, 0, 0, 0),
          FindFrame(frames, FrameRole::kGrayBitInverse, axis, 0, 0, 0)};
}

cv::Mat NormalisedModulation(const PatternSpec& spec, const std::vector<cv::Mat>& images) {
  cv::Mat w, b;
  WhiteBlackImages(spec, images, &w, &b);
  return NormalisedModulation(spec, images, w, b);
}

cv::Mat NormalisedModulation(const PatternSpec& spec, const std::vector<cv::Mat>& images,
                             const cv::Mat& w, const cv::Mat& b) {
  cv::Mat out(w.size(), CV_32FC1, cv::Scalar(std::nanf("")));
  const std::vector<int> idx = ModulationFrames(spec);
  for (int i : idx)
    SLSHADOW_THROW_IF(i < 0, "fringe modulation: the sequence lacks its finest fringe frames");
  const int n = static_cast<int>(idx.size());
  const bool bytes = images.at(static_cast<size_t>(idx[0])).depth() == CV_8U;
  cv::parallel_for_(cv::Range(0, w.rows), [&](const cv::Range& rows) {
    std::vector<const uint8_t*> p8(static_cast<size_t>(n));
    for (int y = rows.start; y < rows.end; ++y) {
      float* o = out.ptr<float>(y);
      const float* wr = w.ptr<float>(y);
      const float* br = b.ptr<float>(y);
      if (bytes) {
        for (int k = 0; k < n; ++k)
          p8[static_cast<size_t>(k)] =
              images[static_cast<size_t>(idx[static_cast<size_t>(k)])].ptr<uint8_t>(y);
      }
      for (int x = 0; x < w.cols; ++x) {
        const float range = wr[x] - br[x];
        if (range < 4) continue;
        if (bytes) {
          if (spec.kind == PatternKind::kGrayCode) {
            o[x] = std::abs(static_cast<float>(p8[0][x]) - static_cast<float>(p8[1][x])) / range;
          } else {
            float sum = 0, ss = 0;
            for (int k = 0; k < n; ++k) {
              const float v = p8[static_cast<size_t>(k)][x];
              sum += v, ss += v * v;
            }
            const float var =
                std::max(0.0f, ss / static_cast<float>(n) -
                                   (sum / static_cast<float>(n)) * (sum / static_cast<float>(n)));
            o[x] = std::sqrt(2 * var) / range;
          }
          continue;
        }
        if (spec.kind == PatternKind::kGrayCode) {
          o[x] = std::abs(Pixel(images[static_cast<size_t>(idx[0])], y, x) -
                          Pixel(images[static_cast<size_t>(idx[1])], y, x)) /
                 range;
        } else {
          // N equally spaced samples of A + B' cos(.) have variance B'^2 / 2 whatever their
          // order: the amplitude does not depend on frame order or phase.
          double s = 0, ss = 0;
          for (int k = 0; k < n; ++k) {
            const double v = Pixel(images[static_cast<size_t>(idx[static_cast<size_t>(k)])], y, x);
            s += v, ss += v * v;
          }
          const double var = std::max(0.0, ss / n - (s / n) * (s / n));
          o[x] = static_cast<float>(std::sqrt(2 * var) / range);
        }
      }
    }
  });
  return out;
}

void FitDefocus(const PatternSpec& spec, std::vector<CameraData>& cameras,
                const PhysicsFitOptions& options, PhysicsFit* fit) {
  PhysicsLayer d;
  d.name = "defocus";
  d.unit = "projector px (Gaussian sigma)";
  d.residual_unit = "RMS of the normalised fringe modulation";
  const double period = ModulationPeriodPx(spec);
  struct Obs {
    double real, twin;
    int band;
    bool held;
  };
  std::vector<Obs> obs;
  for (CameraData& cam : cameras) {
    if (cam.twin.empty()) continue;
    if (cam.white.empty() || cam.black.empty())
      WhiteBlackImages(spec, cam.real, &cam.white, &cam.black);
    cam.real_modulation = NormalisedModulation(spec, cam.real, cam.white, cam.black);
    WhiteBlackImages(spec, cam.twin, &cam.twin_white, &cam.twin_black);
    cam.twin_modulation = NormalisedModulation(spec, cam.twin, cam.twin_white, cam.twin_black);
    const cv::Mat& mr = cam.real_modulation;
    const cv::Mat& mt = cam.twin_modulation;
    const GeometryBuffer& g = *cam.geometry;
    for (int y = 0; y < g.height; y += options.stride_px) {
      for (int x = 0; x < g.width; x += options.stride_px) {
        if (g.visibility.at<uint8_t>(y, x) != 2) continue;
        const float a = mr.at<float>(y, x), b = mt.at<float>(y, x);
        if (!std::isfinite(a) || !std::isfinite(b) || b < 0.05f) continue;
        obs.push_back({a, b, BandOfRow(y, g.height), HeldOutRow(y, options.stride_px)});
      }
    }
  }
  if (obs.size() < 100) {
    d.observable = false;
    d.reason = "too few lit pixels with fringe modulation";
    fit->layers.push_back(d);
    return;
  }
  BandedValues r;
  for (const Obs& o : obs) {
    if (!o.held) r.Add(o.band, o.real / o.twin);
  }
  const double rho = Median(std::vector<double>(r.all));
  const double sigma_rho = r.MedianSigma();
  const auto sigma_of = [&](double q) {
    return q < 1 ? period / (M_PI * std::sqrt(2.0)) * std::sqrt(-std::log(q)) : 0.0;
  };
  d.value = sigma_of(rho);
  // d sigma / d rho at rho (finite difference), for the uncertainty.
  const double h = 1e-4;
  d.sigma = rho < 1 - 2 * h ? std::abs(sigma_of(rho + h) - sigma_of(rho - h)) / (2 * h) * sigma_rho
                            : std::nan("");
  d.samples = static_cast<int64_t>(r.all.size());
  std::vector<double> off, on;
  for (const Obs& o : obs) {
    if (!o.held) continue;
    off.push_back(o.real - o.twin);
    on.push_back(o.real - std::min(1.0, rho) * o.twin);
  }
  d.heldout_residual_off = Rms(off);
  d.heldout_residual_on = Rms(on);
  d.extra["modulation_ratio"] = rho;
  d.extra["modulation_ratio_sigma"] = sigma_rho;
  d.extra["period_px"] = period;
  const double loss = 1 - rho;
  const bool significant =
      loss > 0 && pipeline::Significant(loss, sigma_rho, options.defocus_min_loss);
  d.kept = significant && HeldoutDrops(d, options.min_heldout_drop);
  d.reason =
      d.kept
          ? StringPrintf(
                "fringes reach %.1f %% of the focused twin's modulation: held-out residual %.4f -> "
                "%.4f",
                100 * rho, d.heldout_residual_off, d.heldout_residual_on)
          : StringPrintf(
                "fringe modulation %.1f %% of the focused twin's: focus explains it within noise",
                100 * rho);
  fit->layers.push_back(d);
}

}  // namespace slshadow::twin
