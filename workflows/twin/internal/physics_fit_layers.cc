// The layers of FitPhysics (workflows/twin/physics_fit.h), one function each, over a shared
// FitContext.
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

// The white - black contrast a pixel needs to count as well lit: 0.3 x the median over the samples.
double WellLitContrast(const std::vector<Sample>& samples) {
  std::vector<double> contrast;
  contrast.reserve(samples.size());
  for (const Sample& s : samples) contrast.push_back(s.white - s.black);
  return 0.3 * Median(std::move(contrast));
}

namespace {

std::string TermName(const std::pair<int, int>& t) {
  const auto power = [](const char* v, int k) {
    return k == 0   ? std::string()
           : k == 1 ? std::string(v)
                    : v + std::string("^") + std::to_string(k);
  };
  const std::string a = power("u", t.first), b = power("v", t.second);
  return a.empty() ? b : b.empty() ? a : a + " " + b;
}

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

}  // namespace

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

namespace {

// `value` of the fitting (not held-out) samples that `select` picks, all and per band.
template <typename Select, typename Value>
BandedValues FittingValues(const std::vector<Sample>& samples, Select&& select, Value&& value) {
  BandedValues v;
  for (const Sample& s : samples) {
    if (!s.heldout && select(s)) v.Add(s.band, value(s));
  }
  return v;
}

}  // namespace

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
  exposure.value = Median(std::vector<double>(v.all));
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

namespace {

// The illumination field's basis on one camera's image: 1 and the monomials of `terms` at a pixel.
struct FieldBasis {
  const std::vector<std::pair<int, int>>& terms;
  int degree = 0, width = 0, height = 0;
  int Size() const { return 1 + static_cast<int>(terms.size()); }
  void Row(const Sample& s, double* out) const {
    MonomialRow(terms, degree, NormalisedCoordinate(s.x, width), NormalisedCoordinate(s.y, height),
                out);
  }
};

// The basis rows (row-major, basis.Size() columns) of up to ~20000 of camera c's lit part pixels.
std::vector<double> LitPartRows(const std::vector<Sample>& samples, size_t c,
                                const FieldBasis& basis) {
  const int p = basis.Size();
  std::vector<double> lit_rows;
  int64_t count = 0;
  for (const Sample& s : samples) count += s.camera == static_cast<int>(c);
  const int64_t step = std::max<int64_t>(1, count / 20000);
  int64_t i = 0;
  for (const Sample& s : samples) {
    if (s.camera != static_cast<int>(c) || i++ % step) continue;
    lit_rows.resize(lit_rows.size() + static_cast<size_t>(p));
    basis.Row(s, &lit_rows[lit_rows.size() - static_cast<size_t>(p)]);
  }
  return lit_rows;
}

// The field layer's extra: its terms, coefficients and their sigmas, the image size it was fitted
// on and its range [lo, hi] over the lit part.
nlohmann::json IlluminationExtra(const FieldBasis& basis, const LinearFit& lf, double lo,
                                 double hi) {
  nlohmann::json names = nlohmann::json::array(), coeffs = nlohmann::json::array(),
                 sigmas = nlohmann::json::array();
  for (int k = 0; k < basis.Size(); ++k) {
    names.push_back(k == 0 ? std::string("1") : TermName(basis.terms[static_cast<size_t>(k - 1)]));
    coeffs.push_back(lf.beta(k));
    sigmas.push_back(CoefficientSigma(lf, k));
  }
  return {{"degree", basis.degree},
          {"terms", names},
          {"coefficients", coeffs},
          {"coefficient_sigmas", sigmas},
          {"width", basis.width},
          {"height", basis.height},
          {"min", lo},
          {"max", hi},
          {"coordinates",
           "u = (x - width/2) / (width/2), v = (y - height/2) / (height/2), x, y pixel centres"}};
}

// The illumination field of camera c: on the reference pixels (W - B) / (FS factor range) =
// E G(u, v). When kept, the samples of camera c get the field as their gain.
PhysicsLayer FitIlluminationField(FitContext& ctx, size_t c,
                                  const std::vector<std::pair<int, int>>& terms) {
  std::vector<Sample>& samples = ctx.samples;
  const PhysicsFitOptions& options = ctx.options;
  const double fs = ctx.fs, range = ctx.range, e = ctx.e;
  const GeometryBuffer& g = *ctx.cameras[c].geometry;
  const FieldBasis basis{terms, options.illumination_degree, g.width, g.height};
  const int p = basis.Size();
  PhysicsLayer il;
  il.name = "illumination_" + ctx.cameras[c].camera;
  il.unit = "RMS of G - 1";
  il.residual_unit = "DN RMS of white - black, reference pixels";
  const auto row = [&](const Sample& s, double* out) { basis.Row(s, out); };
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
  const std::vector<double> lit_rows = LitPartRows(samples, c, basis);
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
  il.extra = IlluminationExtra(basis, lf, lo, hi);
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
      il.value > 0 && pipeline::Significant(il.value, il.sigma, options.illumination_floor);
  il.kept = significant && HeldoutDrops(il, options.min_heldout_drop);
  il.reason =
      il.kept ? StringPrintf(
                    "the lit part is %.3f..%.3f of its mean brightness, smoothly: held-out "
                    "residual %.2f -> %.2f DN",
                    lo, hi, il.heldout_residual_off, il.heldout_residual_on)
              : StringPrintf(
                    "uniform within noise (field %.3f..%.3f, held-out residual %.2f vs %.2f DN)",
                    lo, hi, il.heldout_residual_off, il.heldout_residual_on);
  if (il.kept) {
    for (Sample& s : samples) {
      if (s.camera == static_cast<int>(c)) s.gain = static_cast<float>(field(lf.beta, s));
    }
  }
  return il;
}

}  // namespace

// --- illumination field per camera ---
void FitIlluminationFields(FitContext& ctx) {
  const std::vector<std::pair<int, int>> terms = IlluminationTerms(ctx.options.illumination_degree);
  for (size_t c = 0; c < ctx.cameras.size() && !terms.empty(); ++c)
    ctx.fit.layers.push_back(FitIlluminationField(ctx, c, terms));
}

namespace {

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
  a.value = Median(std::vector<double>(v.all));
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
  const bool significant = pipeline::Significant(a.value - a.off_value, a.sigma, 0.01);
  a.kept = significant && HeldoutDrops(a, ctx.options.min_heldout_drop);
  a.reason = a.kept ? StringPrintf(
                          "reflects %.3f, not %.3f, relative to the reference object: held-out "
                          "residual %.2f -> %.2f DN",
                          a.value, a.off_value, a.heldout_residual_off, a.heldout_residual_on)
                    : StringPrintf("the file's albedo %.3f fits within noise (fitted %.3f)",
                                   a.off_value, a.value);
  return a;
}

}  // namespace

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
    dark.value = Median(std::vector<double>(d.all));
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
    const bool significant = pipeline::Significant(dark.value - dark.off_value, dark.sigma, 0.005);
    dark.kept = significant && HeldoutDrops(dark, ctx.options.min_heldout_drop);
    dark.reason = dark.kept ? StringPrintf(
                                  "dark squares reflect %.3f of the light ones' exposure, not "
                                  "%.3f: held-out residual %.2f -> %.2f DN",
                                  dark.value / board->light, board->dark / board->light,
                                  dark.heldout_residual_off, dark.heldout_residual_on)
                            : "the part's dark reflectance already fits within noise";
  }
  ctx.fit.layers.push_back(dark);
}

namespace {

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
  const bool significant = amb.value > 0 && pipeline::Significant(amb.value, amb.sigma, 0.002);
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
  amb.value = Median(std::vector<double>(v.all));
  amb.sigma = v.MedianSigma();
  amb.samples = static_cast<int64_t>(v.all.size());
  std::vector<double> off, on;
  double off_sum = 0;
  for (const Sample& s : samples) {
    if (!s.heldout) continue;
    off.push_back(s.black);
    off_sum += s.black;
    on.push_back(s.black - amb.value * AmbientRegressor(ctx, s));
  }
  amb.heldout_residual_off = Rms(off);
  amb.heldout_residual_on = Rms(on);
  amb.kept = KeepAmbient(amb, options);
  const double off_mean = off.empty() ? 0.0 : off_sum / static_cast<double>(off.size());
  amb.reason =
      amb.kept
          ? StringPrintf("the black frame is lit: %.2f DN mean; held-out residual %.2f -> %.2f DN",
                         off_mean, amb.heldout_residual_off, amb.heldout_residual_on)
          : StringPrintf("the black frame is dark within noise (held-out RMS %.2f DN)",
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
// *camera_inliers: the fit's inlier rows per camera.
LinearFit FitBlackFrame(const FitContext& ctx, const std::vector<int>& column, int cols,
                        bool with_ambient, std::vector<int64_t>* camera_inliers) {
  const int shift = with_ambient ? 0 : 1;
  std::vector<double> x, y;
  std::vector<int> bands, cameras;
  for (const Sample& s : ctx.samples) {
    if (s.heldout || column[static_cast<size_t>(s.camera)] < 0) continue;
    const size_t at = x.size();
    x.resize(at + static_cast<size_t>(cols - shift), 0.0);
    if (with_ambient) x[at] = AmbientRegressor(ctx, s);
    x[at + static_cast<size_t>(column[static_cast<size_t>(s.camera)] - shift)] = 1;
    y.push_back(s.black);
    bands.push_back(s.band);
    cameras.push_back(s.camera);
  }
  LinearFit fit = FitLinear(x, y, bands, cols - shift);
  camera_inliers->assign(ctx.cameras.size(), 0);
  for (size_t i = 0; i < fit.inlier.size(); ++i)
    (*camera_inliers)[static_cast<size_t>(cameras[i])] += fit.inlier[i];
  return fit;
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
  bl.residual_unit = "DN RMS of the black frame";
  bl.observable = false;
  bl.reason =
      "one reflectance in view: a black-level offset and ambient light look alike in the "
      "black frame; ambient stands for both";
  return bl;
}

// The offset of camera c from the joint fit `both` (`inliers`: camera c's inlier rows in it),
// judged against ambient alone (`amb`).
PhysicsLayer FitBlackLevel(const FitContext& ctx, const std::vector<int>& column, size_t c,
                           const LinearFit& both, int64_t inliers, const PhysicsLayer& amb) {
  const PhysicsFitOptions& options = ctx.options;
  if (column[c] < 0) return UnobservableBlackLevel(ctx.cameras[c].camera);
  PhysicsLayer bl;
  bl.name = "black_level_" + ctx.cameras[c].camera;
  bl.unit = "DN";
  bl.residual_unit = "DN RMS of the black frame";
  const int k = column[c];
  bl.value = both.beta(k);
  bl.sigma = CoefficientSigma(both, k);
  bl.samples = inliers;
  bl.heldout_residual_off =
      BlackFrameResidual(ctx, column, static_cast<int>(c), amb.kept ? amb.value : 0.0, nullptr, 0);
  bl.heldout_residual_on =
      BlackFrameResidual(ctx, column, static_cast<int>(c), both.beta(0), &both.beta, 0);
  const bool significant =
      pipeline::Significant(bl.value, bl.sigma, options.black_level_floor * ctx.fs);
  bl.kept = significant && HeldoutDrops(bl, options.min_heldout_drop);
  return bl;
}

// With an offset kept: ambient judged again with the offsets in (offsets + ambient against offsets
// alone); when ambient is then left off, the kept offsets take their values (and samples: the
// camera's inlier rows, `only_inliers`) from `only`.
void RejudgeAmbientWithOffsets(const FitContext& ctx, const std::vector<int>& column,
                               const LinearFit& both, const LinearFit& only,
                               const std::vector<int64_t>& only_inliers, PhysicsLayer* amb_layer,
                               std::vector<PhysicsLayer>* offsets) {
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
      amb.kept ? StringPrintf(
                     "the black frame scales with reflectance beyond the offset: %.4f of white; "
                     "held-out residual %.2f -> %.2f DN",
                     amb.value, amb.heldout_residual_off, amb.heldout_residual_on)
               : StringPrintf(
                     "with the black-level offset in, the black frame does not scale with "
                     "reflectance (%.4f +- %.4f); held-out residual %.2f vs %.2f DN",
                     amb.value, amb.sigma, amb.heldout_residual_off, amb.heldout_residual_on);
  for (size_t c = 0; c < offsets->size(); ++c) {
    PhysicsLayer& bl = (*offsets)[c];
    if (!bl.kept) continue;
    if (!amb.kept) {  // the offset alone: its own fit
      bl.value = only.beta(column[c] - 1);
      bl.sigma = CoefficientSigma(only, column[c] - 1);
      bl.samples = only_inliers[c];
      bl.heldout_residual_on =
          BlackFrameResidual(ctx, column, static_cast<int>(c), 0.0, &only.beta, 1);
    }
    bl.reason = StringPrintf(
        "the black frame sits %.2f DN above what ambient light on the print explains, "
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
  std::vector<int64_t> both_inliers, only_inliers;
  const LinearFit both = FitBlackFrame(ctx, column, cols, true, &both_inliers);
  const LinearFit only = FitBlackFrame(ctx, column, cols, false, &only_inliers);
  if (!both.ok || !only.ok) {  // too few rows, or too few bands for the jackknife
    for (size_t c = 0; c < ctx.cameras.size(); ++c) {
      offsets.push_back(UnobservableBlackLevel(ctx.cameras[c].camera));
      if (column[c] >= 0)
        offsets.back().reason =
            "too few lit pixels spread over the image (at least 3 of its 8 bands) for the "
            "black-level fit";
    }
    return offsets;
  }
  bool any_kept = false;
  for (size_t c = 0; c < ctx.cameras.size(); ++c) {
    offsets.push_back(FitBlackLevel(ctx, column, c, both, both_inliers[c], *amb));
    any_kept = any_kept || offsets.back().kept;
  }
  if (any_kept) RejudgeAmbientWithOffsets(ctx, column, both, only, only_inliers, amb, &offsets);
  for (PhysicsLayer& bl : offsets) {
    if (bl.observable && !bl.kept)
      bl.reason = StringPrintf("no offset beyond noise (%.2f +- %.2f DN)", bl.value, bl.sigma);
  }
  return offsets;
}

}  // namespace

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

}  // namespace slshadow::twin::internal
