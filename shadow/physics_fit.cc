#include "shadow/physics_fit.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "core/error.h"
#include "patterns/codec.h"
#include "shadow/significance.h"

namespace slshadow::shadow {
namespace {

constexpr int kBands = kSignificanceBands;

float Pixel(const cv::Mat& m, int y, int x) {
  return m.depth() == CV_8U ? static_cast<float>(m.at<uint8_t>(y, x))
                            : static_cast<float>(m.at<uint16_t>(y, x));
}

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(mid), v.end());
  return v[mid];
}

// Variance of the values within 4 robust sigmas of the median (the MAD alone is biased for
// integer-valued data: its median snaps to the grid).
double RobustVariance(const std::vector<double>& v) {
  if (v.size() < 8) return std::nan("");
  const double med = Median(v);
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

// The band of image row y (kBands horizontal bands), and whether the row is held out (odd sample
// rows; the fits use the even ones).
int BandOfRow(int y, int height) { return std::min(kBands - 1, y * kBands / height); }
bool HeldOutRow(int y, int stride_px) { return (y / stride_px) % 2 == 1; }

// Values of a statistic, all of them and per band of the image.
struct BandedValues {
  std::vector<double> all;
  std::vector<std::vector<double>> bands = std::vector<std::vector<double>>(kBands);
  void Add(int band, double v) {
    all.push_back(v);
    bands[static_cast<size_t>(band)].push_back(v);
  }
  // BandSigma (shadow/significance.h) of `statistic` of each band's values; NaN for the bands with
  // `min_values` values or fewer.
  template <typename F>
  double Sigma(size_t min_values, F&& statistic) const {
    std::vector<double> v;
    for (const auto& b : bands) v.push_back(b.size() > min_values ? statistic(b) : std::nan(""));
    return BandSigma(v);
  }
  double MedianSigma() const {
    return Sigma(20, [](const std::vector<double>& b) { return Median(b); });
  }
};

// The keep rule's second half: the held-out residual with the layer on is below (1 - min_drop)
// of the one with it off.
bool HeldoutDrops(const PhysicsLayer& l, double min_drop) {
  return l.heldout_residual_on < (1 - min_drop) * l.heldout_residual_off;
}

struct Sample {
  float white = 0, black = 0, factor = 0, albedo = 0;
  float gain = 1;         // the illumination field at the pixel (1 until that layer is kept)
  float twin_albedo = 0;  // the albedo the fitted twin renders there (after the albedo layers)
  int camera = 0, y = 0, x = 0, band = 0, object = 0;
  bool heldout = false;
};

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

std::string Fmt(const char* format, double a, double b = 0, double c = 0, double d = 0) {
  char buf[256];
  std::snprintf(buf, sizeof(buf), format, a, b, c, d);
  return buf;
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

// The white - black contrast a pixel needs to count as well lit: 0.3 x the median over the samples.
double WellLitContrast(const std::vector<Sample>& samples) {
  std::vector<double> contrast;
  contrast.reserve(samples.size());
  for (const Sample& s : samples) contrast.push_back(s.white - s.black);
  return 0.3 * Median(std::move(contrast));
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

std::string TermName(const std::pair<int, int>& t) {
  const auto power = [](const char* v, int k) {
    return k == 0   ? std::string()
           : k == 1 ? std::string(v)
                    : v + std::string("^") + std::to_string(k);
  };
  const std::string a = power("u", t.first), b = power("v", t.second);
  return a.empty() ? b : b.empty() ? a : a + " " + b;
}

double NormalisedCoordinate(int x, int size) { return (x - 0.5 * size) / (0.5 * size); }

// Linear least squares y = X beta over rows in bands (kBands), with one reweighting pass that
// drops rows beyond 4 robust sigmas of the first fit, and the delete-one-band solutions for a
// jackknife of any function of beta.
struct LinearFit {
  Eigen::VectorXd beta;
  std::vector<Eigen::VectorXd> jackknife;  // one per band that had rows
  int64_t rows = 0, inliers = 0;
  bool ok = false;
};

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
  const double gate = 4 * 1.4826 * std::max(Median(abs_res), 1e-12);
  for (size_t i = 0; i < n; ++i) use[i] = std::abs(res[i]) <= gate;
  f.inliers = std::count(use.begin(), use.end(), 1);
  solve(use, &f.beta, &f.jackknife);
  f.ok = f.beta.allFinite() && f.jackknife.size() >= 3;
  return f;
}

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

}  // namespace

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

namespace {

// The lit part pixels of every camera the fit reads (every stride-th pixel where the twin sees the
// part lit with a geometric factor of at least min_factor, white level not saturated).
std::vector<Sample> LitPartSamples(const std::vector<CameraData>& cameras,
                                   const std::vector<cv::Mat>& whites,
                                   const std::vector<cv::Mat>& blacks, double fs,
                                   const PhysicsFitOptions& options) {
  std::vector<Sample> samples;
  for (size_t c = 0; c < cameras.size(); ++c) {
    const CameraData& cam = cameras[c];
    const GeometryBuffer& g = *cam.geometry;
    const int n2 = g.samples_per_axis * g.samples_per_axis;
    for (int y = 0; y < g.height; y += options.stride_px) {
      for (int x = 0; x < g.width; x += options.stride_px) {
        if (g.visibility.at<uint8_t>(y, x) != 2 || g.object_id.at<int32_t>(y, x) < 0) continue;
        Sample s;
        const size_t base =
            (static_cast<size_t>(y) * static_cast<size_t>(g.width) + static_cast<size_t>(x)) *
            static_cast<size_t>(n2);
        for (int k = 0; k < n2; ++k) {
          s.factor += g.factor[base + static_cast<size_t>(k)] / static_cast<float>(n2);
          s.albedo += g.albedo[base + static_cast<size_t>(k)] / static_cast<float>(n2);
        }
        if (s.factor < options.min_factor) continue;
        s.white = whites[c].at<float>(y, x);
        s.black = blacks[c].at<float>(y, x);
        if (s.white >= 0.98 * fs) continue;  // saturated
        s.camera = static_cast<int>(c);
        s.y = y;
        s.x = x;
        s.band = BandOfRow(y, g.height);
        s.object = g.object_id.at<int32_t>(y, x);
        s.heldout = HeldOutRow(y, options.stride_px);
        samples.push_back(s);
      }
    }
  }
  return samples;
}

// What every layer's fit reads: the inputs, the lit part pixels, and the fit built so far (its
// layers in the order fitted; a layer reads the values of those before it).
struct FitContext {
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

FitContext::FitContext(const PatternSpec& spec_in, const Scene& twin_in,
                       const std::vector<CameraData>& cameras_in,
                       const PhysicsFitOptions& options_in)
    : spec(spec_in), twin(twin_in), cameras(cameras_in), options(options_in) {
  std::vector<cv::Mat> whites(cameras.size()), blacks(cameras.size());
  for (size_t c = 0; c < cameras.size(); ++c) {
    if (cameras[c].white.empty() || cameras[c].black.empty()) {
      WhiteBlackImages(spec, cameras[c].real, &whites[c], &blacks[c]);
    } else {
      whites[c] = cameras[c].white, blacks[c] = cameras[c].black;
    }
  }
  has_white_black = spec.WhiteFrameIndex() >= 0 && spec.BlackFrameIndex() >= 0;
  fs = cameras[0].real.at(0).depth() == CV_8U ? 255.0 : 65535.0;
  frames = spec.Frames();
  range = (spec.intensity_max - spec.intensity_min) / 255.0;

  for (const auto& o : twin.objects) {
    if (o.albedo.kind == Albedo::Kind::kCheckerboard) board = &o.albedo;
  }

  samples = LitPartSamples(cameras, whites, blacks, fs, options);
  SLSHADOW_THROW_IF(
      samples.size() < 100, "physics fit: only ", samples.size(),
      " lit part pixels in the twin; is the part in front of the cameras at the estimated pose?");

  // The exposure comes from the object with most lit pixels; the others get their own
  // exposure x albedo ratio (FitObjectAlbedo).
  std::vector<int64_t> per_object(twin.objects.size(), 0);
  for (const Sample& s : samples) ++per_object[static_cast<size_t>(s.object)];
  reference =
      static_cast<int>(std::max_element(per_object.begin(), per_object.end()) - per_object.begin());
}

// `value` of the fitting (not held-out) samples that `select` picks, all and per band.
template <typename Select, typename Value>
BandedValues FittingValues(const std::vector<Sample>& samples, Select&& select, Value&& value) {
  BandedValues v;
  for (const Sample& s : samples) {
    if (!s.heldout && select(s)) v.Add(s.band, value(s));
  }
  return v;
}

// --- exposure (from the light squares of a checkerboard) ---
void FitExposure(FitContext& ctx) {
  const std::vector<Sample>& samples = ctx.samples;
  const double fs = ctx.fs, range = ctx.range;
  const BandedValues v = FittingValues(
      samples, [&](const Sample& s) { return ctx.IsLight(s); },
      [&](const Sample& s) { return ctx.Ratio(s); });
  SLSHADOW_THROW_IF(v.all.size() < 50, "physics fit: too few lit part pixels to fit the exposure (",
                    v.all.size(), ")");
  PhysicsLayer exposure;
  exposure.name = "exposure";
  exposure.unit = "fraction of full scale";
  exposure.value = Median(v.all);
  exposure.sigma = v.MedianSigma();
  exposure.off_value = ctx.twin.radiometry.exposure_fraction;
  exposure.samples = static_cast<int64_t>(v.all.size());
  exposure.residual_unit = "DN RMS of white - black";
  {
    std::vector<double> off, on;
    for (const Sample& s : samples) {
      if (!s.heldout || !ctx.IsLight(s)) continue;
      off.push_back(s.white - s.black - exposure.off_value * fs * s.factor * range);
      on.push_back(s.white - s.black - exposure.value * fs * s.factor * range);
    }
    exposure.heldout_residual_off = Rms(off);
    exposure.heldout_residual_on = Rms(on);
  }
  exposure.kept = true;
  exposure.reason =
      "core radiometry: exposure x albedo from white - black over the twin's geometric factor";
  if (ctx.board) exposure.reason += " (light squares)";
  ctx.fit.layers.push_back(exposure);
  ctx.e = exposure.value;
  if (ctx.twin.objects.size() > 1)
    ctx.fit.layers.back().reason +=
        " (object '" + ctx.twin.objects[static_cast<size_t>(ctx.reference)].name + "')";
}

// --- illumination field of camera c: on the reference pixels (W - B) / (FS factor range) =
// E G(u, v). When kept, the samples of camera c get the field as their gain. ---
PhysicsLayer FitIlluminationField(FitContext& ctx, size_t c,
                                  const std::vector<std::pair<int, int>>& terms) {
  std::vector<Sample>& samples = ctx.samples;
  const PhysicsFitOptions& options = ctx.options;
  const double fs = ctx.fs, range = ctx.range, e = ctx.e;
  const int p = 1 + static_cast<int>(terms.size());
  const GeometryBuffer& g = *ctx.cameras[c].geometry;
  PhysicsLayer il;
  il.name = "illumination_" + ctx.cameras[c].camera;
  il.unit = "RMS of G - 1";
  il.residual_unit = "DN RMS of white - black, reference pixels";
  const auto row = [&](const Sample& s, double* out) {
    MonomialRow(terms, options.illumination_degree, NormalisedCoordinate(s.x, g.width),
                NormalisedCoordinate(s.y, g.height), out);
  };
  std::vector<double> x, y;
  std::vector<int> bands;
  for (const Sample& s : samples) {
    if (s.heldout || s.camera != static_cast<int>(c) || !ctx.IsLight(s)) continue;
    x.resize(x.size() + static_cast<size_t>(p));
    row(s, &x[x.size() - static_cast<size_t>(p)]);
    y.push_back(ctx.Ratio(s) / e);
    bands.push_back(s.band);
  }
  const LinearFit lf = FitLinear(x, y, bands, p);
  if (!lf.ok) {
    il.observable = false;
    il.reason = "too few reference pixels spread over the image for the illumination field";
    return il;
  }
  std::vector<double> buf(static_cast<size_t>(p));
  const auto field = [&](const Eigen::VectorXd& beta, const Sample& s) {
    row(s, buf.data());
    return Eigen::Map<const Eigen::VectorXd>(buf.data(), p).dot(beta);
  };
  // The field's RMS deviation from 1 over the lit part: on up to ~20000 of its pixels.
  std::vector<double> lit_rows;
  {
    int64_t count = 0;
    for (const Sample& s : samples) count += s.camera == static_cast<int>(c);
    const int64_t step = std::max<int64_t>(1, count / 20000);
    int64_t i = 0;
    for (const Sample& s : samples) {
      if (s.camera != static_cast<int>(c) || i++ % step) continue;
      lit_rows.resize(lit_rows.size() + static_cast<size_t>(p));
      row(s, &lit_rows[lit_rows.size() - static_cast<size_t>(p)]);
    }
  }
  const Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>>
      lit_basis(lit_rows.data(),
                static_cast<Eigen::Index>(lit_rows.size() / static_cast<size_t>(p)), p);
  const auto rms_dev = [&](const Eigen::VectorXd& beta) {
    return lit_basis.rows() ? std::sqrt(((lit_basis * beta).array() - 1).square().mean()) : 0.0;
  };
  il.value = rms_dev(lf.beta);
  il.sigma = JackknifeSigma(lf, rms_dev);
  il.samples = lf.inliers;
  const Eigen::VectorXd lit_field = lit_basis * lf.beta;
  const double lo = lit_field.size() ? lit_field.minCoeff() : 1.0,
               hi = lit_field.size() ? lit_field.maxCoeff() : 1.0;
  nlohmann::json names = nlohmann::json::array(), coeffs = nlohmann::json::array(),
                 sigmas = nlohmann::json::array();
  for (int k = 0; k < p; ++k) {
    names.push_back(k == 0 ? std::string("1") : TermName(terms[static_cast<size_t>(k - 1)]));
    coeffs.push_back(lf.beta(k));
    sigmas.push_back(CoefficientSigma(lf, k));
  }
  il.extra = {
      {"degree", options.illumination_degree},
      {"terms", names},
      {"coefficients", coeffs},
      {"coefficient_sigmas", sigmas},
      {"width", g.width},
      {"height", g.height},
      {"min", lo},
      {"max", hi},
      {"coordinates",
       "u = (x - width/2) / (width/2), v = (y - height/2) / (height/2), x, y pixel centres"}};
  std::vector<double> off, on;
  for (const Sample& s : samples) {
    if (!s.heldout || s.camera != static_cast<int>(c) || !ctx.IsLight(s)) continue;
    const double model = e * fs * s.factor * range;
    off.push_back(s.white - s.black - model);
    on.push_back(s.white - s.black - model * field(lf.beta, s));
  }
  il.heldout_residual_off = Rms(off);
  il.heldout_residual_on = Rms(on);
  const bool significant =
      il.value > 0 && Significant(il.value, il.sigma, options.illumination_floor);
  il.kept = significant && HeldoutDrops(il, options.min_heldout_drop);
  il.reason =
      il.kept ? Fmt("the lit part is %.3f..%.3f of its mean brightness, smoothly: held-out "
                    "residual %.2f -> %.2f DN",
                    lo, hi, il.heldout_residual_off, il.heldout_residual_on)
              : Fmt("uniform within noise (field %.3f..%.3f, held-out residual %.2f vs %.2f DN)",
                    lo, hi, il.heldout_residual_off, il.heldout_residual_on);
  if (il.kept) {
    for (Sample& s : samples) {
      if (s.camera == static_cast<int>(c)) s.gain = static_cast<float>(field(lf.beta, s));
    }
  }
  return il;
}

void FitIlluminationFields(FitContext& ctx) {
  const std::vector<std::pair<int, int>> terms = IlluminationTerms(ctx.options.illumination_degree);
  for (size_t c = 0; c < ctx.cameras.size() && !terms.empty(); ++c)
    ctx.fit.layers.push_back(FitIlluminationField(ctx, c, terms));
}

// --- exposure x albedo of object o (not the reference; uniform albedo) ---
PhysicsLayer FitObjectAlbedo(const FitContext& ctx, size_t o) {
  const std::vector<Sample>& samples = ctx.samples;
  const double fs = ctx.fs, range = ctx.range, e = ctx.e;
  const SceneObject& object = ctx.twin.objects[o];
  PhysicsLayer a;
  a.name = "albedo_" + object.name;
  a.unit = "reflectance";
  a.off_value = object.albedo.value;
  a.residual_unit = "DN RMS of white - black on this object";
  const BandedValues v = FittingValues(
      samples, [&](const Sample& s) { return s.object == static_cast<int>(o); },
      [&](const Sample& s) { return object.albedo.value * ctx.Ratio(s) / e; });
  if (v.all.size() < 200) {
    a.observable = false;
    a.reason = "too few lit pixels on this object";
    return a;
  }
  a.value = Median(v.all);
  a.sigma = v.MedianSigma();
  a.samples = static_cast<int64_t>(v.all.size());
  std::vector<double> off, on;
  for (const Sample& s : samples) {
    if (!s.heldout || s.object != static_cast<int>(o)) continue;
    off.push_back(s.white - s.black - e * fs * s.factor * s.gain * range);
    on.push_back(s.white - s.black -
                 e * fs * s.factor * s.gain * range * a.value / object.albedo.value);
  }
  a.heldout_residual_off = Rms(off);
  a.heldout_residual_on = Rms(on);
  const bool significant = Significant(a.value - a.off_value, a.sigma, 0.01);
  a.kept = significant && HeldoutDrops(a, ctx.options.min_heldout_drop);
  a.reason =
      a.kept ? Fmt("reflects %.3f, not %.3f, relative to the reference object: held-out "
                   "residual %.2f -> %.2f DN",
                   a.value, a.off_value, a.heldout_residual_off, a.heldout_residual_on)
             : Fmt("the file's albedo %.3f fits within noise (fitted %.3f)", a.off_value, a.value);
  return a;
}

void FitObjectAlbedos(FitContext& ctx) {
  for (size_t o = 0; o < ctx.twin.objects.size(); ++o) {
    if (static_cast<int>(o) == ctx.reference ||
        ctx.twin.objects[o].albedo.kind != Albedo::Kind::kUniform)
      continue;
    ctx.fit.layers.push_back(FitObjectAlbedo(ctx, o));
  }
}

// --- the checkerboard's dark squares (albedo_dark), when the part is a checkerboard ---
void FitDarkSquares(FitContext& ctx) {
  if (!ctx.board) return;
  const std::vector<Sample>& samples = ctx.samples;
  const Albedo* board = ctx.board;
  const double fs = ctx.fs, range = ctx.range, e = ctx.e;
  PhysicsLayer dark;
  dark.name = "albedo_dark";
  dark.unit = "reflectance";
  dark.off_value = board->dark;
  dark.residual_unit = "DN RMS of white - black, dark squares";
  const BandedValues d = FittingValues(
      samples, [&](const Sample& s) { return ctx.IsDark(s); },
      [&](const Sample& s) { return board->dark * ctx.Ratio(s) / e; });
  if (d.all.size() < 50) {
    dark.observable = false;
    dark.reason = "too few dark-square pixels lit";
  } else {
    dark.value = Median(d.all);
    dark.sigma = d.MedianSigma();
    dark.samples = static_cast<int64_t>(d.all.size());
    std::vector<double> off, on;
    for (const Sample& s : samples) {
      if (!s.heldout || !ctx.IsDark(s)) continue;
      const double g = s.factor * s.gain / board->dark;
      off.push_back(s.white - s.black - e * fs * g * board->dark * range);
      on.push_back(s.white - s.black - e * fs * g * dark.value * range);
    }
    dark.heldout_residual_off = Rms(off);
    dark.heldout_residual_on = Rms(on);
    const bool significant = Significant(dark.value - dark.off_value, dark.sigma, 0.005);
    dark.kept = significant && HeldoutDrops(dark, ctx.options.min_heldout_drop);
    dark.reason = dark.kept ? Fmt("dark squares reflect %.3f of the light ones' exposure, not "
                                  "%.3f: held-out residual %.2f -> %.2f DN",
                                  dark.value / board->light, board->dark / board->light,
                                  dark.heldout_residual_off, dark.heldout_residual_on)
                            : "the part's dark reflectance already fits within noise";
  }
  ctx.fit.layers.push_back(dark);
}

// The albedo the fitted twin renders at each sample (after the albedo layers).
void SetTwinAlbedos(FitContext& ctx) {
  for (Sample& s : ctx.samples) {
    s.twin_albedo = s.albedo;
    if (ctx.IsDark(s) && ctx.fit.Kept("albedo_dark"))
      s.twin_albedo = static_cast<float>(ctx.fit.Find("albedo_dark")->value);
    const SceneObject& o = ctx.twin.objects[static_cast<size_t>(s.object)];
    if (o.albedo.kind == Albedo::Kind::kUniform && ctx.fit.Kept("albedo_" + o.name)) {
      s.twin_albedo = static_cast<float>(ctx.fit.Find("albedo_" + o.name)->value);
    }
  }
}

// What ambient light scales in the black frame: E FS albedo G.
double AmbientRegressor(const FitContext& ctx, const Sample& s) {
  return ctx.e * ctx.fs * s.twin_albedo * s.gain;
}

// Ambient's keep rule (alone, or with the black-level offsets in).
bool KeepAmbient(const PhysicsLayer& amb, const PhysicsFitOptions& options) {
  const bool significant = amb.value > 0 && Significant(amb.value, amb.sigma, 0.002);
  return significant && HeldoutDrops(amb, options.min_heldout_drop);
}

// --- ambient alone: B = E FS ambient albedo G ---
PhysicsLayer FitAmbient(const FitContext& ctx) {
  const std::vector<Sample>& samples = ctx.samples;
  const PhysicsFitOptions& options = ctx.options;
  PhysicsLayer amb;
  amb.name = "ambient";
  amb.unit = "fraction of projector white";
  amb.residual_unit = "DN RMS of the black frame";
  const BandedValues v = FittingValues(
      samples, [](const Sample& s) { return !(s.twin_albedo < 0.02f); },
      [&](const Sample& s) { return s.black / AmbientRegressor(ctx, s); });
  amb.value = Median(v.all);
  amb.sigma = v.MedianSigma();
  amb.samples = static_cast<int64_t>(v.all.size());
  std::vector<double> off, on;
  for (const Sample& s : samples) {
    if (!s.heldout) continue;
    off.push_back(s.black);
    on.push_back(s.black - amb.value * AmbientRegressor(ctx, s));
  }
  amb.heldout_residual_off = Rms(off);
  amb.heldout_residual_on = Rms(on);
  amb.kept = KeepAmbient(amb, options);
  amb.reason =
      amb.kept ? Fmt("the black frame is lit: %.2f DN mean; held-out residual %.2f -> %.2f DN",
                     amb.heldout_residual_off, amb.heldout_residual_off, amb.heldout_residual_on)
               : Fmt("the black frame is dark within noise (held-out RMS %.2f DN)",
                     amb.heldout_residual_off);
  return amb;
}

// The black-level offsets' columns in the joint fit, per camera; -1 where not observable: an
// offset is observable on a camera whose lit pixels span reflectances (the coefficient of variation
// of albedo x G above 0.25). *cols: the joint fit's unknowns (ambient and the observable offsets).
std::vector<int> BlackLevelColumns(const FitContext& ctx, int* cols) {
  const size_t nc = ctx.cameras.size();
  std::vector<int> column(nc, -1);
  *cols = 1;
  for (size_t c = 0; c < nc; ++c) {
    double sum = 0, ss = 0;
    int64_t n = 0;
    for (const Sample& s : ctx.samples) {
      if (s.heldout || s.camera != static_cast<int>(c)) continue;
      const double r = s.twin_albedo * s.gain;
      sum += r, ss += r * r, ++n;
    }
    const double mean = n ? sum / static_cast<double>(n) : 0.0;
    const double cv =
        n > 100 && mean > 0
            ? std::sqrt(std::max(0.0, ss / static_cast<double>(n) - mean * mean)) / mean
            : 0.0;
    if (cv > 0.25) column[c] = (*cols)++;
  }
  return column;
}

// The black frame of the cameras with an offset column, least squares: B = o_c + ambient E FS
// albedo G (with_ambient: unknowns ambient, then the offsets in their columns), else B = o_c
// (the offsets alone, one column less: o_c = the mean black level of camera c).
LinearFit FitBlackFrame(const FitContext& ctx, const std::vector<int>& column, int cols,
                        bool with_ambient) {
  const int shift = with_ambient ? 0 : 1;
  std::vector<double> x, y;
  std::vector<int> bands;
  for (const Sample& s : ctx.samples) {
    if (s.heldout || column[static_cast<size_t>(s.camera)] < 0) continue;
    const size_t at = x.size();
    x.resize(at + static_cast<size_t>(cols - shift), 0.0);
    if (with_ambient) x[at] = AmbientRegressor(ctx, s);
    x[at + static_cast<size_t>(column[static_cast<size_t>(s.camera)] - shift)] = 1;
    y.push_back(s.black);
    bands.push_back(s.band);
  }
  return FitLinear(x, y, bands, cols - shift);
}

// RMS of camera's held-out black-frame residual B - o - ambient E FS albedo G, with o from `beta`
// (column - shift; none when null).
double BlackFrameResidual(const FitContext& ctx, const std::vector<int>& column, int camera,
                          double ambient, const Eigen::VectorXd* beta, int shift) {
  std::vector<double> r;
  for (const Sample& s : ctx.samples) {
    if (!s.heldout || s.camera != camera) continue;
    const double o = beta ? (*beta)(column[static_cast<size_t>(camera)] - shift) : 0.0;
    r.push_back(s.black - o - ambient * AmbientRegressor(ctx, s));
  }
  return Rms(r);
}

// The layer of a camera whose offset the black frame cannot tell from ambient light.
PhysicsLayer UnobservableBlackLevel(const std::string& camera) {
  PhysicsLayer bl;
  bl.name = "black_level_" + camera;
  bl.unit = "DN";
  bl.observable = false;
  bl.reason =
      "one reflectance in view: a black-level offset and ambient light look alike in the "
      "black frame; ambient stands for both";
  return bl;
}

// The offset of camera c from the joint fit `both`, judged against ambient alone (`amb`).
PhysicsLayer FitBlackLevel(const FitContext& ctx, const std::vector<int>& column, size_t c,
                           const LinearFit& both, const PhysicsLayer& amb) {
  const PhysicsFitOptions& options = ctx.options;
  if (column[c] < 0) {
    PhysicsLayer bl = UnobservableBlackLevel(ctx.cameras[c].camera);
    bl.residual_unit = "DN RMS of the black frame";
    return bl;
  }
  PhysicsLayer bl;
  bl.name = "black_level_" + ctx.cameras[c].camera;
  bl.unit = "DN";
  bl.residual_unit = "DN RMS of the black frame";
  const int k = column[c];
  bl.value = both.beta(k);
  bl.sigma = CoefficientSigma(both, k);
  bl.samples = both.inliers;
  bl.heldout_residual_off =
      BlackFrameResidual(ctx, column, static_cast<int>(c), amb.kept ? amb.value : 0.0, nullptr, 0);
  bl.heldout_residual_on =
      BlackFrameResidual(ctx, column, static_cast<int>(c), both.beta(0), &both.beta, 0);
  const bool significant = Significant(bl.value, bl.sigma, options.black_level_floor * ctx.fs);
  bl.kept = significant && HeldoutDrops(bl, options.min_heldout_drop);
  return bl;
}

// With an offset kept: ambient judged again with the offsets in (offsets + ambient against offsets
// alone); when ambient is then left off, the kept offsets take their values from `only`.
void RejudgeAmbientWithOffsets(const FitContext& ctx, const std::vector<int>& column,
                               const LinearFit& both, const LinearFit& only,
                               PhysicsLayer* amb_layer, std::vector<PhysicsLayer>* offsets) {
  PhysicsLayer& amb = *amb_layer;
  amb.value = both.beta(0);
  amb.sigma = CoefficientSigma(both, 0);
  std::vector<double> off2, on2;
  for (const Sample& s : ctx.samples) {
    if (!s.heldout || column[static_cast<size_t>(s.camera)] < 0) continue;
    const int k = column[static_cast<size_t>(s.camera)];
    off2.push_back(s.black - only.beta(k - 1));
    on2.push_back(s.black - both.beta(k) - both.beta(0) * AmbientRegressor(ctx, s));
  }
  amb.heldout_residual_off = Rms(off2);
  amb.heldout_residual_on = Rms(on2);
  amb.kept = KeepAmbient(amb, ctx.options);
  amb.reason =
      amb.kept ? Fmt("the black frame scales with reflectance beyond the offset: %.4f of white; "
                     "held-out residual %.2f -> %.2f DN",
                     amb.value, amb.heldout_residual_off, amb.heldout_residual_on)
               : Fmt("with the black-level offset in, the black frame does not scale with "
                     "reflectance (%.4f +- %.4f); held-out residual %.2f vs %.2f DN",
                     amb.value, amb.sigma, amb.heldout_residual_off, amb.heldout_residual_on);
  for (size_t c = 0; c < offsets->size(); ++c) {
    PhysicsLayer& bl = (*offsets)[c];
    if (!bl.kept) continue;
    if (!amb.kept) {  // the offset alone: its own fit
      bl.value = only.beta(column[c] - 1);
      bl.sigma = CoefficientSigma(only, column[c] - 1);
      bl.heldout_residual_on =
          BlackFrameResidual(ctx, column, static_cast<int>(c), 0.0, &only.beta, 1);
    }
    bl.reason =
        Fmt("the black frame sits %.2f DN above what ambient light on the print explains, "
            "on every reflectance: held-out residual %.2f -> %.2f DN",
            bl.value, bl.heldout_residual_off, bl.heldout_residual_on);
  }
}

// --- black-level offsets, one per camera: B = o_c + E FS ambient albedo G, fitted jointly with
// ambient (`amb`, FitAmbient's; judged again when an offset is kept) ---
std::vector<PhysicsLayer> FitBlackLevels(const FitContext& ctx, PhysicsLayer* amb) {
  int cols = 1;
  const std::vector<int> column = BlackLevelColumns(ctx, &cols);
  std::vector<PhysicsLayer> offsets;
  if (cols == 1) {
    for (const CameraData& cam : ctx.cameras) offsets.push_back(UnobservableBlackLevel(cam.camera));
    return offsets;
  }
  const LinearFit both = FitBlackFrame(ctx, column, cols, true);
  const LinearFit only = FitBlackFrame(ctx, column, cols, false);
  if (!both.ok || !only.ok) return offsets;
  bool any_kept = false;
  for (size_t c = 0; c < ctx.cameras.size(); ++c) {
    offsets.push_back(FitBlackLevel(ctx, column, c, both, *amb));
    any_kept = any_kept || offsets.back().kept;
  }
  if (any_kept) RejudgeAmbientWithOffsets(ctx, column, both, only, amb, &offsets);
  for (PhysicsLayer& bl : offsets) {
    if (bl.observable && !bl.kept)
      bl.reason = Fmt("no offset beyond noise (%.2f +- %.2f DN)", bl.value, bl.sigma);
  }
  return offsets;
}

// --- ambient and black level: B = o_c + E FS ambient albedo G ---
void FitAmbientAndBlackLevels(FitContext& ctx) {
  SetTwinAlbedos(ctx);
  const std::string no_black_frame =
      ctx.has_white_black ? ""
                          : " (no black frame: the black level is the darker of each inverse pair, "
                            "which projector blur raises near stripe edges: an upper bound)";
  PhysicsLayer amb = FitAmbient(ctx);
  std::vector<PhysicsLayer> offsets = FitBlackLevels(ctx, &amb);
  amb.reason += no_black_frame;
  ctx.fit.layers.push_back(amb);
  for (PhysicsLayer& bl : offsets) {
    if (bl.observable) bl.reason += no_black_frame;
    ctx.fit.layers.push_back(bl);
  }
}

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
      gamma.value = GammaOfPhaseMean(Median(fit_mean.all));
      gamma.sigma = fit_mean.Sigma(
          50, [](const std::vector<double>& b) { return GammaOfPhaseMean(Median(b)); });
      gamma.samples = static_cast<int64_t>(fit_mean.all.size());
      std::vector<double> off, on;
      const double on_level = PhaseMeanOfGamma(gamma.value);
      for (double m : held_mean) off.push_back(m - 0.5), on.push_back(m - on_level);
      gamma.heldout_residual_off = Rms(off);
      gamma.heldout_residual_on = Rms(on);
      const bool significant = Significant(gamma.value - 1, gamma.sigma, ctx.options.gamma_floor);
      gamma.kept = significant && HeldoutDrops(gamma, ctx.options.min_heldout_drop);
      gamma.reason =
          gamma.kept
              ? Fmt("phase frames average %.3f of white, not 0.5: held-out residual %.4f -> %.4f",
                    on_level, gamma.heldout_residual_off, gamma.heldout_residual_on)
              : Fmt("a linear response fits within noise (gamma %.3f, held-out residual %.4f vs "
                    "%.4f)",
                    gamma.value, gamma.heldout_residual_off, gamma.heldout_residual_on);
    }
  }
  ctx.fit.layers.push_back(gamma);
}

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
      const double r = Median(per);  // a pixel near one bit's edge is outvoted by the others
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
      gl.value = 1 - Median(fit_r.all);
      gl.sigma = fit_r.Sigma(20, [](const std::vector<double>& b) { return 1 - Median(b); });
      gl.samples = static_cast<int64_t>(fit_r.all.size());
      std::vector<double> off, on;
      for (double r : held_r) off.push_back(r - 1), on.push_back(r - (1 - gl.value));
      gl.heldout_residual_off = Rms(off);
      gl.heldout_residual_on = Rms(on);
      gl.extra["pairs"] = coarse.size();
      const bool significant =
          gl.value > 0 && Significant(gl.value, gl.sigma, options.global_light_floor);
      gl.kept = significant && HeldoutDrops(gl, options.min_heldout_drop);
      gl.reason =
          gl.kept ? Fmt("coarse stripes reach %.1f %% of white - black: %.1f %% of the light is "
                        "scattered from the lit "
                        "projector image; held-out residual %.3f -> %.3f",
                        100 * (1 - gl.value), 100 * gl.value, gl.heldout_residual_off,
                        gl.heldout_residual_on)
                  : Fmt("coarse stripes reach %.1f %% of white - black: direct light explains them",
                        100 * (1 - gl.value));
    }
  }
  ctx.fit.layers.push_back(gl);
}

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
    centre->push_back(Median(s));
    var->push_back(RobustVariance(r));
  }
}

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
      const bool significant = k > 0 && Significant(k, sigma_k, 0);
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
      noise.reason = noise.kept ? Fmt("inverse pairs vary by %.2f DN^2 (quantisation alone: "
                                      "%.2f), growing with signal: shot noise",
                                      mean_var, quant)
                                : Fmt("inverse-pair variance %.2f DN^2 is what quantisation "
                                      "(%.2f) explains, or does not grow with signal",
                                      mean_var, quant);
    }
  }
  ctx.fit.layers.push_back(noise);
}

}  // namespace

PhysicsFit FitPhysics(const PatternSpec& spec, const Scene& twin,
                      const std::vector<CameraData>& cameras, const PhysicsFitOptions& options) {
  options.Check();
  SLSHADOW_THROW_IF(cameras.empty(), "physics fit: no camera");
  FitContext ctx(spec, twin, cameras, options);  // white / black levels, the lit part pixels
  FitExposure(ctx);
  FitIlluminationFields(ctx);
  FitObjectAlbedos(ctx);
  FitDarkSquares(ctx);
  FitAmbientAndBlackLevels(ctx);
  FitGamma(ctx);
  FitGlobalLight(ctx);
  FitNoise(ctx);
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
  const double rho = Median(r.all);
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
  const bool significant = loss > 0 && Significant(loss, sigma_rho, options.defocus_min_loss);
  d.kept = significant && HeldoutDrops(d, options.min_heldout_drop);
  d.reason =
      d.kept
          ? Fmt("fringes reach %.1f %% of the focused twin's modulation: held-out residual %.4f -> "
                "%.4f",
                100 * rho, d.heldout_residual_off, d.heldout_residual_on)
          : Fmt("fringe modulation %.1f %% of the focused twin's: focus explains it within noise",
                100 * rho);
  fit->layers.push_back(d);
}

}  // namespace slshadow::shadow
