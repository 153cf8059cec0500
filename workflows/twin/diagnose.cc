#include "workflows/twin/diagnose.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numeric>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "compare/neighbour_grid.h"
#include "core/error.h"
#include "core/kdtree.h"
#include "core/statistics.h"
#include "core/string_printf.h"
#include "workflows/twin/internal/diagnose_part.h"

namespace slshadow::twin {
namespace {

float PixelValue(const cv::Mat& m, int y, int x) {
  return m.depth() == CV_8U ? static_cast<float>(m.at<uint8_t>(y, x))
                            : static_cast<float>(m.at<uint16_t>(y, x));
}

Eigen::Matrix<double, 6, 1> Basis(double x, double y, int w, int h) {
  const double u = (x - w / 2.0) / (w / 2.0), v = (y - h / 2.0) / (h / 2.0);
  Eigen::Matrix<double, 6, 1> b;
  b << 1, u, v, u * u, u * v, v * v;
  return b;
}

// Projector pattern value through the response, bilinear between texels.
double PatternIntensity(const cv::Mat& pattern, const std::vector<float>& response, double x,
                        double y) {
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const double fx = x - x0, fy = y - y0;
  double v = 0;
  for (int dy = 0; dy < 2; ++dy) {
    for (int dx = 0; dx < 2; ++dx) {
      const int xi = std::clamp(x0 + dx, 0, pattern.cols - 1),
                yi = std::clamp(y0 + dy, 0, pattern.rows - 1);
      const double w = (dx ? fx : 1 - fx) * (dy ? fy : 1 - fy);
      v += w * response[pattern.at<uint8_t>(yi, xi)];
    }
  }
  return v;
}

// a - mean(a), scaled to unit norm (left zero when constant).
void Standardise(std::vector<float>* a) {
  double m = 0, ss = 0;
  for (float x : *a) m += x;
  m /= static_cast<double>(a->size());
  for (float x : *a) ss += (x - m) * (x - m);
  const double scale = ss > 0 ? 1 / std::sqrt(ss) : 0.0;
  for (float& x : *a) x = static_cast<float>((x - m) * scale);
}

// Correlation of two standardised vectors.
double Dot(const std::vector<float>& a, const std::vector<float>& b) {
  // Eight partial sums: vectorised, and float error stays far below the thresholds (~0.05).
  float s[8] = {0, 0, 0, 0, 0, 0, 0, 0};
  const size_t n = a.size(), m = n - n % 8;
  for (size_t i = 0; i < m; i += 8) {
    for (size_t j = 0; j < 8; ++j) s[j] += a[i + j] * b[i + j];
  }
  double sum = 0;
  for (float x : s) sum += x;
  for (size_t i = m; i < n; ++i) sum += static_cast<double>(a[i]) * b[i];
  return sum;
}

double StdDev(const std::vector<float>& a) {
  double m = 0, s = 0;
  for (float x : a) m += x;
  m /= static_cast<double>(a.size());
  for (float x : a) s += (x - m) * (x - m);
  return std::sqrt(s / static_cast<double>(a.size()));
}

}  // namespace

void DiagnoseOptions::Check() const {
  SLSHADOW_THROW_IF(!(calibration_field_px > 0), "diagnose: calibration_field_px must be > 0 (got ",
                    calibration_field_px, ")");
  SLSHADOW_THROW_IF(!(multipath_ratio > 0 && multipath_ratio < 1),
                    "diagnose: multipath_ratio must be in (0, 1) (got ", multipath_ratio, ")");
  SLSHADOW_THROW_IF(!(pose_residual_px > 0) || !std::isfinite(pose_residual_px),
                    "diagnose: pose_residual_px must be a finite number > 0 (got ",
                    pose_residual_px, ")");
  SLSHADOW_THROW_IF(!(pose_max_share > 0 && pose_max_share < 1),
                    "diagnose: pose_max_share must be in (0, 1) (got ", pose_max_share, ")");
  SLSHADOW_THROW_IF(smoothing_neighbors < 1, "diagnose: smoothing_neighbors must be >= 1 (got ",
                    smoothing_neighbors, ")");
  SLSHADOW_THROW_IF(!(part_pose_sigmas >= 0) || !std::isfinite(part_pose_sigmas),
                    "diagnose: part_pose_sigmas must be a finite number >= 0 (got ",
                    part_pose_sigmas, ")");
}

namespace {

// The fitted quadratic of SmoothField, evaluated where it is read (At gives the values
// SmoothField's image holds, bit for bit): the diagnosis reads it at a sample of pixels, so the
// whole image is not drawn (6 images of 2.3 M pixels on the demo rig).
struct QuadraticField {
  bool valid = false;
  Eigen::Matrix<double, 6, 1> coef = Eigen::Matrix<double, 6, 1>::Zero();
  int w = 0, h = 0;
  float At(int x, int y) const { return static_cast<float>(coef.dot(Basis(x, y, w, h))); }
};

QuadraticField FitSmoothField(const cv::Mat& residual, const cv::Mat& mask, double* rms_px,
                              double* mean_px) {
  QuadraticField out;
  const int w = residual.cols, h = residual.rows;
  out.w = w;
  out.h = h;
  std::vector<Eigen::Matrix<double, 6, 1>> basis;
  std::vector<double> values;
  const int stride = std::max(1, std::min(w, h) / 200);
  for (int y = 0; y < h; y += stride) {
    for (int x = 0; x < w; x += stride) {
      const float r = residual.at<float>(y, x);
      if (!std::isfinite(r) || !mask.at<uint8_t>(y, x)) continue;
      basis.push_back(Basis(x, y, w, h));
      values.push_back(r);
    }
  }
  if (values.size() < 50) return out;
  const double med = Median(std::vector<double>(values));
  std::vector<bool> inlier(values.size());
  for (size_t i = 0; i < values.size(); ++i) inlier[i] = std::abs(values[i] - med) < 5.0;
  Eigen::Matrix<double, 6, 1> coef = Eigen::Matrix<double, 6, 1>::Zero();
  for (int iter = 0; iter < 4; ++iter) {
    Eigen::Matrix<double, 6, 6> ata = Eigen::Matrix<double, 6, 6>::Zero();
    Eigen::Matrix<double, 6, 1> atb = Eigen::Matrix<double, 6, 1>::Zero();
    for (size_t i = 0; i < values.size(); ++i) {
      if (!inlier[i]) continue;
      ata += basis[i] * basis[i].transpose();
      atb += basis[i] * values[i];
    }
    coef = ata.ldlt().solve(atb);
    std::vector<double> res;
    for (size_t i = 0; i < values.size(); ++i) res.push_back(values[i] - coef.dot(basis[i]));
    const double sigma = internal::Mad(res, 0.0);
    for (size_t i = 0; i < values.size(); ++i)
      inlier[i] = std::abs(res[i]) < std::max(3 * sigma, 0.5);
  }
  double ss = 0, sum = 0;
  int64_t n = 0;
  for (size_t i = 0; i < values.size(); ++i) {
    if (!inlier[i]) continue;
    const double f = coef.dot(basis[i]);
    ss += f * f, sum += f, ++n;
  }
  if (rms_px) *rms_px = n ? std::sqrt(ss / static_cast<double>(n)) : 0.0;
  if (mean_px) *mean_px = n ? sum / static_cast<double>(n) : 0.0;
  out.coef = coef;
  out.valid = true;
  return out;
}

}  // namespace

cv::Mat SmoothField(const cv::Mat& residual, const cv::Mat& mask, double* rms_px, double* mean_px) {
  const QuadraticField q = FitSmoothField(residual, mask, rms_px, mean_px);
  if (!q.valid) return cv::Mat();
  cv::Mat field(q.h, q.w, CV_32FC1);
  cv::parallel_for_(cv::Range(0, q.h), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      float* f = field.ptr<float>(y);
      for (int x = 0; x < q.w; ++x) f[x] = q.At(x, y);
    }
  });
  return field;
}

nlohmann::json Diagnosis::ToJson() const {
  nlohmann::json j;
  j["verdict"] = verdict;
  j["causes"] = causes;
  j["findings"] = nlohmann::json::array();
  for (const auto& f : findings) {
    j["findings"].push_back({{"cause", f.cause},
                             {"evaluated", f.evaluated},
                             {"detected", f.detected},
                             {"message", f.message},
                             {"evidence", f.evidence}});
  }
  return j;
}

std::string Diagnosis::Summary() const {
  std::string out = "verdict: " + verdict + "\n";
  for (const auto& f : findings) {
    out += "  " + std::string(f.detected ? "[FOUND] " : (f.evaluated ? "[  ok ] " : "[ n/a ] ")) +
           f.cause + ": " + f.message + "\n";
  }
  return out;
}

namespace {

// The calibration field of one camera: the robust quadratic of each projector-coordinate
// residual (the calibration cause reads it, and the frame test and the response's ripple too).
struct Field {
  QuadraticField x, y;
  double rms_x = 0, rms_y = 0, mean_x = 0, mean_y = 0;
};

std::vector<Field> FitCalibrationFields(const std::vector<CameraEvidence>& cameras) {
  std::vector<Field> fields(cameras.size());
  for (size_t c = 0; c < cameras.size(); ++c) {
    const CameraEvidence& cam = cameras[c];
    // NaN propagates; an axis the spec does not code has empty maps.
    if (!cam.real_x.empty() && !cam.gt_x.empty()) {
      fields[c].x =
          FitSmoothField(cam.real_x - cam.gt_x, cam.mask, &fields[c].rms_x, &fields[c].mean_x);
    }
    if (!cam.real_y.empty() && !cam.gt_y.empty()) {
      fields[c].y =
          FitSmoothField(cam.real_y - cam.gt_y, cam.mask, &fields[c].rms_y, &fields[c].mean_y);
    }
  }
  return fields;
}

// A cause not evaluated because a wrong frame corrupts the decoding.
Finding NotEvaluated(const std::string& cause) {
  Finding f;
  f.cause = cause;
  f.evaluated = false;
  f.message = "not evaluated: a wrong frame corrupts the decoding";
  return f;
}

// wrong_frame: each real frame correlated with the predicted frame of every pattern.
Finding WrongFrame(const std::vector<FrameInfo>& frames,
                   const std::vector<cv::Mat>& projector_images, const std::vector<float>& response,
                   const std::vector<CameraEvidence>& cameras, const std::vector<Field>& fields,
                   const DiagnoseOptions& options) {
  Finding wrong;
  wrong.cause = "wrong_frame";
  wrong.evidence["frames"] = nlohmann::json::array();
  for (size_t c = 0; c < cameras.size(); ++c) {
    const CameraEvidence& cam = cameras[c];
    if (!cam.real || cam.white.empty() || cam.black.empty()) continue;
    const auto& real = *cam.real;
    // Sample pixels (<= ~40 k) where the twin's coordinate is known.
    std::vector<cv::Point> px;
    std::vector<double> cx, cy;
    int64_t inside = cv::countNonZero(cam.mask);
    const int stride =
        std::max(1, static_cast<int>(std::sqrt(static_cast<double>(inside) / 40000.0)));
    for (int y = 0; y < cam.height; y += stride) {
      for (int x = 0; x < cam.width; x += stride) {
        if (!cam.mask.at<uint8_t>(y, x)) continue;
        double u = cam.gt_x.empty() ? 0 : cam.gt_x.at<float>(y, x),
               v = cam.gt_y.empty() ? 0 : cam.gt_y.at<float>(y, x);
        if (!std::isfinite(u) || !std::isfinite(v)) continue;
        if (fields[c].x.valid) u += fields[c].x.At(x, y);
        if (fields[c].y.valid) v += fields[c].y.At(x, y);
        px.emplace_back(x, y);
        cx.push_back(u);
        cy.push_back(v);
      }
    }
    if (px.size() < 100) continue;
    const size_t nf = real.size();
    std::vector<std::vector<float>> r(nf), p(nf);
    for (size_t k = 0; k < nf; ++k) {
      r[k].resize(px.size());
      p[k].resize(px.size());
    }
    for (size_t i = 0; i < px.size(); ++i) {
      const float w = cam.white.at<float>(px[i].y, px[i].x);
      const float b = cam.black.at<float>(px[i].y, px[i].x);
      for (size_t k = 0; k < nf; ++k) {
        r[k][i] = PixelValue(real[k], px[i].y, px[i].x);
        p[k][i] = static_cast<float>(
            b + (w - b) * PatternIntensity(projector_images[k], response, cx[i], cy[i]));
      }
    }
    std::vector<double> rstd(nf), pstd(nf);
    for (size_t k = 0; k < nf; ++k) rstd[k] = StdDev(r[k]), pstd[k] = StdDev(p[k]);
    // Each frame centred and scaled to unit norm once: a correlation is then one dot product.
    for (size_t k = 0; k < nf; ++k) Standardise(&r[k]), Standardise(&p[k]);
    for (size_t k = 0; k < nf; ++k) {
      if (rstd[k] < 2 || pstd[k] < 2) continue;
      const double own = Dot(r[k], p[k]);
      double best = -2;
      size_t best_j = k;
      for (size_t j = 0; j < nf; ++j) {
        if (j == k || pstd[j] < 2) continue;
        const double cj = Dot(r[k], p[j]);
        if (cj > best) best = cj, best_j = j;
      }
      if (best >= options.wrong_frame_min_corr && own < best - options.wrong_frame_margin) {
        wrong.detected = true;
        wrong.evidence["frames"].push_back({{"camera", cam.camera},
                                            {"frame", k},
                                            {"frame_name", frames[k].Name()},
                                            {"matches_pattern", best_j},
                                            {"matches_pattern_name", frames[best_j].Name()},
                                            {"correlation_own", own},
                                            {"correlation_best", best}});
      }
    }
  }
  if (wrong.detected) {
    std::string list;
    for (const auto& f : wrong.evidence["frames"]) {
      list += (list.empty() ? "" : ", ") + f["camera"].get<std::string>() + " frame " +
              std::to_string(f["frame"].get<int>()) + " (" + f["frame_name"].get<std::string>() +
              ") shows pattern " + std::to_string(f["matches_pattern"].get<int>()) + " (" +
              f["matches_pattern_name"].get<std::string>() + ")";
    }
    wrong.message = "wrong or late frame: " + list + "; check the projector-camera synchronisation";
  } else {
    wrong.message = "every frame matches its own pattern best";
  }
  return wrong;
}

// calibration: the smooth field of each camera against the threshold and the rig's uncertainty.
Finding Calibration(const std::vector<CameraEvidence>& cameras, const std::vector<Field>& fields,
                    const DiagnoseOptions& options) {
  Finding cal;
  cal.cause = "calibration";
  double worst = 0, worst_threshold = options.calibration_field_px;
  bool above = false;
  cal.evidence["cameras"] = nlohmann::json::array();
  for (size_t c = 0; c < cameras.size(); ++c) {
    const Field& f = fields[c];
    const CameraEvidence& cam = cameras[c];
    const double rms = std::hypot(f.rms_x, f.rms_y);
    const double rot_y_deg = std::atan(f.mean_x / cam.projector_fx) * 180 / M_PI;
    const double rot_x_deg = std::atan(f.mean_y / cam.projector_fy) * 180 / M_PI;
    // Focal-length equivalent: a projector focal error df moves a coordinate by
    // (df / f) (u - cx), so the field's slope against u - cx (least squares, with an offset)
    // times f is the focal error that explains its linear part.
    const auto focal_error = [&](const QuadraticField& field, const cv::Mat& truth,
                                 double principal, double focal) {
      if (!field.valid || truth.empty()) return std::nan("");
      double n = 0, sx = 0, sy = 0, sxx = 0, sxy = 0;
      const int stride = std::max(1, std::min(cam.width, cam.height) / 200);
      for (int y = 0; y < cam.height; y += stride) {
        for (int x = 0; x < cam.width; x += stride) {
          if (!cam.mask.at<uint8_t>(y, x)) continue;
          const double u = truth.at<float>(y, x) - principal, d = field.At(x, y);
          if (!std::isfinite(u) || !std::isfinite(d)) continue;
          n += 1, sx += u, sy += d, sxx += u * u, sxy += u * d;
        }
      }
      const double den = n * sxx - sx * sx;
      return n > 50 && den > 0 ? focal * (n * sxy - sx * sy) / den : std::nan("");
    };
    const double dfx = focal_error(f.x, cam.gt_x, cam.projector_cx, cam.projector_fx);
    const double dfy = focal_error(f.y, cam.gt_y, cam.projector_cy, cam.projector_fy);
    nlohmann::json ev = {{"camera", cam.camera},
                         {"field_rms_px", rms},
                         {"field_rms_x_px", f.rms_x},
                         {"field_rms_y_px", f.rms_y},
                         {"field_mean_x_px", f.mean_x},
                         {"field_mean_y_px", f.mean_y},
                         {"equivalent_projector_rotation_about_y_deg", rot_y_deg},
                         {"equivalent_projector_rotation_about_x_deg", rot_x_deg}};
    // The rig's own uncertainty, where its file says, raises the bar.
    const double threshold = std::isfinite(cam.rig_uncertainty_px)
                                 ? std::max(options.calibration_field_px, cam.rig_uncertainty_px)
                                 : options.calibration_field_px;
    ev["rig_uncertainty_px"] = std::isfinite(cam.rig_uncertainty_px)
                                   ? nlohmann::json(cam.rig_uncertainty_px)
                                   : nlohmann::json();
    ev["threshold_px"] = threshold;
    above = above || rms > threshold;
    if (std::isfinite(dfx)) ev["equivalent_projector_focal_error_x_px"] = dfx;
    if (std::isfinite(dfy)) ev["equivalent_projector_focal_error_y_px"] = dfy;
    cal.evidence["cameras"].push_back(ev);
    if (rms > worst) {
      worst = rms;
      worst_threshold = threshold;
      cal.message =
          StringPrintf("smooth projector-coordinate field of %.3f px RMS (mean %.3f, %.3f px): ",
                       rms, f.mean_x, f.mean_y) +
          StringPrintf("equivalent projector rotation %.4f deg about y, %.4f deg about x",
                       rot_y_deg, rot_x_deg);
      if (std::isfinite(dfx))
        cal.message += StringPrintf(", or a projector focal length off by %.2f px (fx %.1f)", dfx,
                                    cam.projector_fx);
      if (std::isfinite(dfy)) cal.message += StringPrintf(" / %.2f px (fy)", dfy);
    }
  }
  cal.evidence["threshold_px"] = options.calibration_field_px;
  cal.detected = above;
  if (cal.detected) {
    cal.message = "calibration error: " + cal.message + "; run `slshadow calibrate refine`";
  } else if (worst > options.calibration_field_px) {
    cal.message = StringPrintf(
        "a smooth field of %.3f px RMS, within what the rig's calibration "
        "uncertainty explains (%.3f px)",
        worst, worst_threshold);
  } else {
    cal.message = StringPrintf("no smooth field above %.2f px (largest %.3f px RMS)",
                               options.calibration_field_px, worst);
  }
  return cal;
}

// projector_response: the physics fit's gamma; the ripple at the fringe harmonics as evidence
// (phase codecs, unless a wrong frame was found).
Finding ProjectorResponse(const PatternSpec& spec, const PhysicsFit& physics,
                          const std::vector<CameraEvidence>& cameras,
                          const std::vector<Field>& fields, bool wrong_frame) {
  Finding resp;
  resp.cause = "projector_response";
  const PhysicsLayer* g = physics.Find("gamma");
  resp.evaluated = g && g->observable;
  resp.detected = g && g->kept;
  if (g) resp.evidence["gamma"] = g->ToJson();
  // Ripple of the residual at 1..4 x the fringe frequency (phase codecs).
  if (spec.kind != PatternKind::kGrayCode && !wrong_frame) {
    const double period = spec.PeriodsPx().front();
    const CameraEvidence& cam = cameras[0];
    Eigen::MatrixXd ata = Eigen::MatrixXd::Zero(9, 9);
    Eigen::VectorXd atb = Eigen::VectorXd::Zero(9);
    double ss = 0;
    int64_t n = 0;
    for (int y = 0; y < cam.height; y += 2) {
      for (int x = 0; x < cam.width; x += 2) {
        if (!cam.mask.at<uint8_t>(y, x)) continue;
        const float gx = cam.gt_x.at<float>(y, x);
        double r = cam.real_x.at<float>(y, x) - gx;
        if (!std::isfinite(r)) continue;
        if (fields[0].x.valid) r -= fields[0].x.At(x, y);
        if (std::abs(r) > 2) continue;
        Eigen::VectorXd b(9);
        const double phi = 2 * M_PI * gx / period;
        b(0) = 1;
        for (int m = 1; m <= 4; ++m) b(2 * m - 1) = std::cos(m * phi), b(2 * m) = std::sin(m * phi);
        ata += b * b.transpose();
        atb += b * r;
        ss += r * r;
        ++n;
      }
    }
    if (n > 100) {
      const Eigen::VectorXd coef = ata.ldlt().solve(atb);
      const double var = std::max(0.0, (ss - coef.dot(atb)) / static_cast<double>(n - 9));
      nlohmann::json amps = nlohmann::json::array();
      double largest = 0;
      for (int m = 1; m <= 4; ++m) {
        const double a = std::hypot(coef(2 * m - 1), coef(2 * m));
        largest = std::max(largest, a);
        amps.push_back({{"harmonic", m},
                        {"amplitude_px", a},
                        {"standard_error_px", std::sqrt(2 * var / static_cast<double>(n))}});
      }
      resp.evidence["ripple"] = amps;
      resp.evidence["ripple_largest_px"] = largest;
    }
  }
  if (resp.detected) {
    resp.message = StringPrintf(
        "projector response is not linear: gamma %.3f +- %.3f fitted from the phase frames",
        g->value, g->sigma);
    if (resp.evidence.contains("ripple_largest_px"))
      resp.message += StringPrintf(" (coordinate ripple at the fringe harmonics up to %.4f px)",
                                   resp.evidence["ripple_largest_px"].get<double>());
  } else {
    resp.message = g ? g->reason : "no response fit";
  }
  return resp;
}

// defocus: the physics fit's projector blur.
Finding Defocus(const PhysicsFit& physics) {
  Finding d;
  d.cause = "defocus";
  const PhysicsLayer* l = physics.Find("defocus");
  d.evaluated = l && l->observable;
  d.detected = l && l->kept;
  if (l) d.evidence["defocus"] = l->ToJson();
  d.message = d.detected ? StringPrintf(
                               "projector defocus: Gaussian blur sigma %.2f +- %.2f projector px "
                               "(fringe modulation %.1f %% of focused)",
                               l->value, l->sigma, 100 * l->extra.value("modulation_ratio", 1.0))
                         : (l ? l->reason : "no defocus fit");
  return d;
}

// multipath: local blobs of lost fringe modulation.
Finding Multipath(const std::vector<CameraEvidence>& cameras, const DiagnoseOptions& options) {
  Finding mp;
  mp.cause = "multipath";
  int largest = 0;
  std::string where;
  for (const CameraEvidence& cam : cameras) {
    if (cam.modulation_ratio.empty()) continue;
    // Well-lit pixels only (real white - black at least 30 % of its median over the part):
    // dark print or shadowed parts have little modulation to lose and say nothing of multipath.
    cv::Mat usable = cam.mask.clone();
    if (!cam.white.empty() && !cam.black.empty()) {
      std::vector<double> range;
      for (int y = 0; y < cam.height; y += 2) {
        for (int x = 0; x < cam.width; x += 2) {
          if (cam.mask.at<uint8_t>(y, x))
            range.push_back(cam.white.at<float>(y, x) - cam.black.at<float>(y, x));
        }
      }
      const double min_range = 0.3 * Median(std::vector<double>(range));
      for (int y = 0; y < cam.height; ++y) {
        for (int x = 0; x < cam.width; ++x) {
          if (cam.white.at<float>(y, x) - cam.black.at<float>(y, x) < min_range)
            usable.at<uint8_t>(y, x) = 0;
        }
      }
    }
    // Relative to a smooth background (a robust quadratic over the image): a depth-dependent
    // blur on a tilted part is a smooth trend, multipath a local loss.
    cv::Mat ratio = cam.modulation_ratio.clone();
    // Normalised where it is read: the usable pixels (the others keep the raw ratio, unread).
    const QuadraticField background =
        FitSmoothField(cam.modulation_ratio, usable, nullptr, nullptr);
    if (background.valid) {
      for (int y = 0; y < cam.height; ++y) {
        const uint8_t* use = usable.ptr<uint8_t>(y);
        for (int x = 0; x < cam.width; ++x) {
          if (!use[x]) continue;
          const float b = background.At(x, y);
          ratio.at<float>(y, x) = b > 0.05f ? ratio.at<float>(y, x) / b : std::nanf("");
        }
      }
    }
    std::vector<double> all;
    for (int y = 0; y < cam.height; y += 2) {
      for (int x = 0; x < cam.width; x += 2) {
        const float v = ratio.at<float>(y, x);
        if (usable.at<uint8_t>(y, x) && std::isfinite(v)) all.push_back(v);
      }
    }
    if (all.size() < 100) continue;
    const double med = Median(std::vector<double>(all));
    const int bw = cam.width / 8, bh = cam.height / 8;
    std::vector<uint8_t> flag(static_cast<size_t>(bw * bh), 0);
    for (int by = 0; by < bh; ++by) {
      for (int bx = 0; bx < bw; ++bx) {
        std::vector<double> v;
        bool full = true;
        for (int y = by * 8; y < by * 8 + 8 && full; ++y) {
          for (int x = bx * 8; x < bx * 8 + 8; ++x) {
            if (!usable.at<uint8_t>(y, x)) {
              full = false;
              break;
            }
            const float r = ratio.at<float>(y, x);
            if (std::isfinite(r)) v.push_back(r);
          }
        }
        if (full && v.size() >= 48 &&
            Median(std::vector<double>(v)) < options.multipath_ratio * med)
          flag[static_cast<size_t>(by * bw + bx)] = 1;
      }
    }
    // Connected blobs (4-neighbourhood).
    std::vector<int> stack;
    for (int i = 0; i < bw * bh; ++i) {
      if (flag[static_cast<size_t>(i)] != 1) continue;
      int size = 0;
      double sx = 0, sy = 0;
      stack.push_back(i);
      flag[static_cast<size_t>(i)] = 2;
      while (!stack.empty()) {
        const int k = stack.back();
        stack.pop_back();
        ++size;
        sx += (k % bw) * 8 + 4, sy += (k / bw) * 8 + 4;
        const int kx = k % bw, ky = k / bw;
        const int nb[4][2] = {{kx - 1, ky}, {kx + 1, ky}, {kx, ky - 1}, {kx, ky + 1}};
        for (const auto& q : nb) {
          if (q[0] < 0 || q[1] < 0 || q[0] >= bw || q[1] >= bh) continue;
          const size_t qi = static_cast<size_t>(q[1] * bw + q[0]);
          if (flag[qi] == 1) {
            flag[qi] = 2;
            stack.push_back(static_cast<int>(qi));
          }
        }
      }
      if (size > largest) {
        largest = size;
        where = cam.camera + StringPrintf(" around pixel (%.0f, %.0f)", sx / size, sy / size);
      }
    }
    mp.evidence["median_modulation_ratio_" + cam.camera] = med;
  }
  mp.evidence["largest_blob_blocks"] = largest;
  mp.evidence["block_px"] = 8;
  mp.detected = largest >= options.min_blob_blocks;
  mp.message = mp.detected ? "multipath / specular / subsurface: real fringe modulation below "
                             "the twin's in a blob of " +
                                 std::to_string(largest) + " 8x8 blocks, " + where
                           : "no local loss of fringe modulation (largest blob " +
                                 std::to_string(largest) + " blocks)";
  return mp;
}

// pose: the share of the pixels both decode whose real coordinate is far from the twin's truth
// once the calibration field is taken out.
Finding Pose(const std::vector<CameraEvidence>& cameras, const std::vector<Field>& fields,
             const PoseEvidence& pose, bool calibration_found, const DiagnoseOptions& options) {
  Finding f;
  f.cause = "pose";
  f.evidence["cameras"] = nlohmann::json::array();
  f.evidence["residual_gate_px"] = options.pose_residual_px;
  f.evidence["max_share"] = options.pose_max_share;
  double worst = 0;
  std::string worst_camera;
  const double gate2 = options.pose_residual_px * options.pose_residual_px;
  for (size_t c = 0; c < cameras.size(); ++c) {
    const CameraEvidence& cam = cameras[c];
    const bool has_x = !cam.real_x.empty() && !cam.gt_x.empty();
    const bool has_y = !cam.real_y.empty() && !cam.gt_y.empty();
    if (!has_x && !has_y) continue;
    int64_t compared = 0, beyond = 0;
    for (int y = 0; y < cam.height; ++y) {
      const uint8_t* m = cam.mask.ptr<uint8_t>(y);
      for (int x = 0; x < cam.width; ++x) {
        if (!m[x]) continue;
        double d2 = 0;
        bool ok = true;
        if (has_x) {
          const float r = cam.real_x.at<float>(y, x), t = cam.gt_x.at<float>(y, x);
          ok = std::isfinite(r) && std::isfinite(t);
          const double d = r - t - (fields[c].x.valid ? fields[c].x.At(x, y) : 0.0f);
          d2 += d * d;
        }
        if (has_y && ok) {
          const float r = cam.real_y.at<float>(y, x), t = cam.gt_y.at<float>(y, x);
          ok = std::isfinite(r) && std::isfinite(t);
          const double d = r - t - (fields[c].y.valid ? fields[c].y.At(x, y) : 0.0f);
          d2 += d * d;
        }
        if (!ok) continue;
        ++compared;
        beyond += d2 > gate2 ? 1 : 0;
      }
    }
    const double share =
        compared ? static_cast<double>(beyond) / static_cast<double>(compared) : 0.0;
    f.evidence["cameras"].push_back({{"camera", cam.camera},
                                     {"compared_pixels", compared},
                                     {"beyond_gate", beyond},
                                     {"share", share}});
    if (share > worst) worst = share, worst_camera = cam.camera;
  }
  f.evidence["worst_share"] = worst;
  if (pose.known) {
    f.evidence["pose"] = {{"source", pose.source},
                          {"fitness", pose.fitness},
                          {"inlier_rmse_mm", pose.inlier_rmse_mm},
                          {"candidate_fitness", pose.candidate_fitness},
                          {"alternative_fitness", pose.alternative_fitness},
                          {"alternative_rotation_deg", pose.alternative_rotation_deg},
                          {"alternative_translation_mm", pose.alternative_translation_mm}};
  }
  const bool beyond = worst > options.pose_max_share;
  f.detected = beyond && !calibration_found;
  if (f.detected) {
    f.message = StringPrintf(
        "the twin is not where the real part is: real decoded projector coordinates differ "
        "from the twin's by more than %.2f px on %.1f %% of the pixels camera '%s' decodes "
        "(at most %.1f %% expected)",
        options.pose_residual_px, 100 * worst, worst_camera.c_str(), 100 * options.pose_max_share);
    if (pose.known) {
      f.message += StringPrintf(
          ", though the cloud fits the part at the pose (%s: fitness %.3f, "
          "inlier RMSE %.3f mm)",
          pose.source.c_str(), pose.fitness, pose.inlier_rmse_mm);
      if (pose.alternative_fitness >= 0)
        f.message += StringPrintf(
            "; the registration's best other pose (%.1f deg, %.1f mm "
            "away) fitted %.3f against the chosen %.3f",
            pose.alternative_rotation_deg, pose.alternative_translation_mm,
            pose.alternative_fitness, pose.candidate_fitness);
    }
    f.message +=
        ": the pose is wrong (or the part file is not this part); give a pose with "
        "--pose";
  } else if (beyond) {
    f.message =
        "decoded differences beyond the calibration field: explained by the calibration "
        "error";
  } else {
    f.message = StringPrintf(
        "real and twin decoded coordinates agree: %.2f %% of the pixels "
        "beyond %.2f px",
        100 * worst, options.pose_residual_px);
  }
  return f;
}

}  // namespace

Diagnosis Diagnose(const PatternSpec& spec, const std::vector<cv::Mat>& projector_images,
                   const std::vector<float>& response, const PhysicsFit& physics,
                   const std::vector<CameraEvidence>& cameras,
                   const std::vector<ModeEvidence>& modes, const DiagnoseOptions& options,
                   const PoseEvidence& pose) {
  options.Check();
  SLSHADOW_THROW_IF(cameras.empty(), "diagnose: no camera evidence");
  SLSHADOW_THROW_IF(response.size() != 256, "diagnose: the response table needs 256 entries");
  Diagnosis diag;
  // Calibration fields per camera (used by the frame test too).
  const std::vector<Field> fields = FitCalibrationFields(cameras);

  // A wrong frame is evaluated first: it corrupts the decoding, so the coordinate and cloud
  // signatures are then not evaluated.
  const Finding wrong =
      WrongFrame(spec.Frames(), projector_images, response, cameras, fields, options);
  diag.findings.push_back(wrong);
  const bool decoded = !wrong.detected;
  diag.findings.push_back(decoded ? Calibration(cameras, fields, options)
                                  : NotEvaluated("calibration"));
  const bool calibration_found = decoded && diag.findings.back().detected;
  // A twin rendered where the part is not: the cloud signatures compare the wrong surfaces.
  Finding pose_finding;
  if (decoded) {
    pose_finding = Pose(cameras, fields, pose, calibration_found, options);
  } else {
    pose_finding = NotEvaluated("pose");
  }
  const bool pose_wrong = pose_finding.detected;
  diag.findings.push_back(std::move(pose_finding));
  diag.findings.push_back(ProjectorResponse(spec, physics, cameras, fields, wrong.detected));
  diag.findings.push_back(Defocus(physics));
  diag.findings.push_back(decoded ? Multipath(cameras, options) : NotEvaluated("multipath"));
  if (!decoded) {
    diag.findings.push_back(NotEvaluated("part"));
  } else if (pose_wrong) {
    Finding part;
    part.cause = "part";
    part.evaluated = false;
    part.message = "not evaluated: the twin is not at the real part's pose";
    diag.findings.push_back(std::move(part));
  } else {
    diag.findings.push_back(internal::Part(modes, options, calibration_found));
  }

  for (const auto& f : diag.findings) {
    if (f.detected) diag.causes.push_back(f.cause);
  }
  if (diag.causes.empty()) {
    diag.verdict = "consistent with the model";
  } else {
    diag.verdict = "differences found: ";
    for (size_t i = 0; i < diag.causes.size(); ++i)
      diag.verdict += (i ? ", " : "") + diag.causes[i];
  }
  return diag;
}

}  // namespace slshadow::twin
