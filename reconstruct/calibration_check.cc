#include "reconstruct/calibration_check.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include <Eigen/Dense>

namespace slshadow {

namespace {

constexpr int kTerms = 8;
constexpr int kGroupEnd[CalibrationCheck::kNumGroups] = {1, 3, 6, 8};  // nested groups of terms
constexpr size_t kMaxSamples = 50000;
constexpr int kMinCount = 100;

using Terms = Eigen::Matrix<double, kTerms, 1>;

Terms Basis(double x, double y) {
  const double r2 = x * x + y * y;
  Terms t;
  t << 1, x, y, x * x, x * y, y * y, x * r2, y * r2;
  return t;
}

// 1.4826 x the median absolute value: the standard deviation of Gaussian noise.
double RobustScale(std::vector<double> r) {
  for (double& v : r) v = std::abs(v);
  const auto mid = r.begin() + static_cast<std::ptrdiff_t>(r.size() / 2);
  std::nth_element(r.begin(), mid, r.end());
  return 1.4826 * *mid;
}

double Median(std::vector<double> v) {
  const auto mid = v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2);
  std::nth_element(v.begin(), mid, v.end());
  return *mid;
}

// The weighted normal equations of the full basis; a nested group's are their top-left block.
struct Normal {
  Eigen::Matrix<double, kTerms, kTerms> ata = Eigen::Matrix<double, kTerms, kTerms>::Zero();
  Terms atb = Terms::Zero();
};

Normal Accumulate(const std::vector<Terms>& basis, const std::vector<double>& e,
                  const std::vector<double>& w) {
  Normal n;
  for (size_t i = 0; i < e.size(); ++i) {
    n.ata.noalias() += (w[i] * basis[i]) * basis[i].transpose();
    n.atb += (w[i] * e[i]) * basis[i];
  }
  return n;
}

// Weighted least squares over the first `terms` basis functions.
Terms Solve(const Normal& n, int terms) {
  Eigen::MatrixXd ata = n.ata.topLeftCorner(terms, terms);
  // Tiny ridge: a scene covering a thin strip leaves some terms undetermined; they stay ~0.
  ata.diagonal().array() += 1e-9 * std::max(ata.diagonal().maxCoeff(), 1e-300);
  Terms c = Terms::Zero();
  c.head(terms) = ata.ldlt().solve(n.atb.head(terms));
  return c;
}

std::string Fixed(double v, const char* format = "%.3g") {
  char buf[32];
  std::snprintf(buf, sizeof(buf), format, v);
  return buf;
}

const char* Cause(int group, bool stereo) {
  switch (group) {
    case 0:
      return stereo ? "a principal point of either camera or a rotation between the cameras"
                    : "a principal point (camera or projector) or a rotation of the pose";
    case 1:
      return "a focal length or a rotation of the pose";
    case 2:
      return "the pose (rotation or baseline)";
    case 3:
      return "the lens distortion";
  }
  return "";
}

}  // namespace

std::string ToString(CalibrationResidual residual) {
  return residual == CalibrationResidual::kEpipolarError ? "epipolar error" : "projector error";
}

const char* ResidualKey(CalibrationResidual residual) {
  return residual == CalibrationResidual::kEpipolarError ? "epipolar_error_px"
                                                         : "projector_error_px";
}

std::string CalibrationCheck::GroupName(int group) {
  static const char* const kNames[kNumGroups] = {"offset", "linear", "quadratic", "radial"};
  return group >= 0 && group < kNumGroups ? kNames[group] : "unknown";
}

CalibrationCheck UnavailableCalibrationCheck(const std::string& pair, const std::string& reason) {
  CalibrationCheck c;
  c.pair = pair;
  c.unavailable_reason = reason;
  return c;
}

CalibrationCheck FitCalibrationCheck(const std::vector<float>& x, const std::vector<float>& y,
                                     const std::vector<float>& error_px,
                                     const CalibrationCheckSetup& setup) {
  const size_t n_all = std::min({x.size(), y.size(), error_px.size()});
  auto finite = [&](size_t i) {
    return std::isfinite(x[i]) && std::isfinite(y[i]) && std::isfinite(error_px[i]);
  };
  size_t count = 0;
  for (size_t i = 0; i < n_all; ++i) count += finite(i) ? 1 : 0;
  if (count < static_cast<size_t>(kMinCount)) {
    return UnavailableCalibrationCheck(
        setup.pair, "only " + std::to_string(count) + " correspondences have " +
                        (setup.residual == CalibrationResidual::kEpipolarError ? "an " : "a ") +
                        ToString(setup.residual) + " (at least " + std::to_string(kMinCount) +
                        " are needed)");
  }
  CalibrationCheck c;
  c.available = true;
  c.pair = setup.pair;
  c.residual = setup.residual;
  c.count = static_cast<int64_t>(count);
  c.working_distance_mm = setup.working_distance_mm;
  // An even subsample keeps the fit's cost bounded: 5e4 samples fit a field of 8 terms to ~1.3 %
  // of the noise (sigma sqrt(8 / n)), and give the median to ~0.6 % of it.
  const size_t stride = (count + kMaxSamples - 1) / kMaxSamples;
  std::vector<Terms> basis;
  std::vector<double> e;
  basis.reserve(count / stride + 1);
  e.reserve(count / stride + 1);
  for (size_t i = 0, k = 0; i < n_all; ++i) {
    if (!finite(i)) continue;
    if (k++ % stride != 0) continue;
    basis.push_back(Basis(x[i], y[i]));
    e.push_back(error_px[i]);
  }
  c.median_px = Median(e);
  const size_t n = e.size();

  // Huber IRLS from the median: bounded influence of decoding blunders, convex, so it converges
  // from any start (a rig file hundreds of pixels off included).
  Terms coef = Terms::Zero();
  coef(0) = c.median_px;
  std::vector<double> r(n), w(n, 1.0);
  double scale = 0;
  for (int iter = 0; iter < 30; ++iter) {
    for (size_t i = 0; i < n; ++i) r[i] = e[i] - coef.dot(basis[i]);
    scale = std::max(RobustScale(r), 1e-9);
    const double k = 1.345 * scale;
    for (size_t i = 0; i < n; ++i) w[i] = std::abs(r[i]) <= k ? 1.0 : k / std::abs(r[i]);
    const Terms next = Solve(Accumulate(basis, e, w), kTerms);
    const double step = (next - coef).cwiseAbs().maxCoeff();
    coef = next;
    if (step < 1e-4 * scale) break;
  }
  for (size_t i = 0; i < n; ++i) r[i] = e[i] - coef.dot(basis[i]);
  c.noise_px = RobustScale(r);

  // The field's RMS, and what each nested group adds (same weights: orthogonal increments).
  const Normal normal = Accumulate(basis, e, w);
  std::vector<double> previous(n, 0.0);
  double field2 = 0;
  for (size_t i = 0; i < n; ++i) field2 += std::pow(coef.dot(basis[i]), 2);
  c.systematic_px = std::sqrt(field2 / static_cast<double>(n));
  for (int g = 0; g < CalibrationCheck::kNumGroups; ++g) {
    const Terms cg = g == CalibrationCheck::kNumGroups - 1 ? coef : Solve(normal, kGroupEnd[g]);
    double sum2 = 0;
    for (size_t i = 0; i < n; ++i) {
      const double f = cg.dot(basis[i]);
      sum2 += std::pow(f - previous[i], 2);
      previous[i] = f;
    }
    c.group_rms_px[static_cast<size_t>(g)] = std::sqrt(sum2 / static_cast<double>(n));
  }

  if (setup.warning_px > 0) {
    c.threshold_source = "user";
    c.threshold_px = setup.warning_px;
  } else {
    c.threshold_px =
        c.noise_px * std::max(setup.noise_factor, 5.0 * std::sqrt(kTerms / static_cast<double>(n)));
    c.threshold_source = "noise";
    if (!(c.threshold_px >= setup.min_warning_px)) {
      c.threshold_px = setup.min_warning_px;
      c.threshold_source = "floor";
    }
  }
  c.threshold_mm =
      std::isfinite(c.threshold_px) && setup.mm_per_px > 0 ? c.threshold_px * setup.mm_per_px : 0;
  c.warn = std::isfinite(c.threshold_px) && c.systematic_px > c.threshold_px;
  if (c.warn) {
    if (c.systematic_px > 1.0)
      c.likely_causes.push_back("a bumped rig, swapped camera names or a wrong rig file");
    const double top = *std::max_element(c.group_rms_px.begin(), c.group_rms_px.end());
    for (int g = 0; g < CalibrationCheck::kNumGroups; ++g) {
      if (c.group_rms_px[static_cast<size_t>(g)] >= 0.3 * top)
        c.likely_causes.push_back(Cause(g, setup.stereo));
    }
    if (setup.residual == CalibrationResidual::kProjectorError) {
      c.likely_causes.push_back(
          "the projector's own calibration (the third view checked; the stereo cloud does not use "
          "it)");
    }
  }
  return c;
}

std::string CalibrationCheck::Message() const {
  if (!available)
    return "calibration check: not available for " + pair + ", because " + unavailable_reason;
  const bool off = !std::isfinite(threshold_px);
  std::string m = "calibration check: " +
                  std::string(warn  ? ""
                              : off ? "reported only (--calibration-warning-px inf): "
                                    : "passed: ") +
                  "the " + ToString(residual) + " of " + std::to_string(count) + " dense " + pair +
                  " correspondences has a systematic part of " + Fixed(systematic_px) +
                  " projector px RMS (median " + Fixed(median_px, "%+.3g") + " px; decode noise " +
                  Fixed(noise_px) + " px)";
  if (off) return m;
  m += std::string(warn ? ", above" : ", within") + " the threshold " + Fixed(threshold_px) + " px";
  if (threshold_source == "user") {
    m += " (--calibration-warning-px";
  } else if (threshold_source == "floor") {
    m += " (the floor of the automatic threshold";
  } else {
    m += " (" + Fixed(threshold_px / noise_px, "%.2g") + " x the decode noise";
  }
  m += threshold_mm > 0
           ? ", = " + Fixed(threshold_mm) + " mm in depth at the " +
                 Fixed(working_distance_mm, "%.0f") + " mm working distance of this scan)"
           : "; no mm equivalent without a projector model)";
  if (!warn) return m;
  std::string shape = "(";
  for (int g = 0; g < kNumGroups; ++g) {
    shape += std::string(g ? ", " : "") + GroupName(g) + " " +
             Fixed(group_rms_px[static_cast<size_t>(g)], "%.2g");
  }
  shape += " px)";
  m += ": the rig file does not fit these captures; the field's shape " + shape + " points at ";
  for (size_t k = 0; k < likely_causes.size(); ++k) m += (k ? "; or " : "") + likely_causes[k];
  m += ". Recalibrate or run 'slshadow calibrate refine'";
  return m;
}

nlohmann::json CalibrationCheck::ToJson() const {
  if (!available)
    return {{"available", false},
            {"reason", unavailable_reason},
            {"warning", false},
            {"message", Message()}};
  auto num = [](double v) { return std::isfinite(v) ? nlohmann::json(v) : nlohmann::json("inf"); };
  nlohmann::json field = nlohmann::json::object();
  for (int g = 0; g < kNumGroups; ++g) field[GroupName(g)] = group_rms_px[static_cast<size_t>(g)];
  return {{"available", true},
          {"residual", ResidualKey(residual)},
          {"unit", "projector px"},
          {"count", count},
          {"median_px", median_px},
          {"noise_px", noise_px},
          {"systematic_px", systematic_px},
          {"threshold_px", num(threshold_px)},
          {"threshold_source", threshold_source},
          {"threshold_mm", threshold_mm},
          {"working_distance_mm", working_distance_mm},
          {"field_rms_px", field},
          {"likely_causes", likely_causes},
          {"warning", warn},
          {"message", Message()}};
}

}  // namespace slshadow
