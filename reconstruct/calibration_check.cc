#include "reconstruct/calibration_check.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>

#include <Eigen/Dense>

#include "core/statistics.h"

namespace slshadow {

namespace {

constexpr int kTerms = 8;
constexpr int kGroupEnd[CalibrationCheck::kNumGroups] = {1, 3, 6, 8};  // nested groups of terms
constexpr size_t kMaxSamples = 50000;
constexpr int kMinCount = 100;
// Sizes of the systematic part that rank the likely causes, projector px (FitCalibrationCheck).
constexpr double kBumpPx = 1.0;
constexpr double kGrossPx = 20.0;
constexpr int kMinBlockCount = 30;  // samples a block of the local field needs

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
  return 1.4826 * Median(r);  // core/statistics.h: nearest rank
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
  switch (residual) {
    case CalibrationResidual::kEpipolarError:
      return "epipolar error";
    case CalibrationResidual::kProjectorError:
      return "projector error";
    case CalibrationResidual::kFittedProjectorError:
      return "fitted projector error";
  }
  return "unknown";
}

const char* ResidualKey(CalibrationResidual residual) {
  switch (residual) {
    case CalibrationResidual::kEpipolarError:
      return "epipolar_error_px";
    case CalibrationResidual::kProjectorError:
      return "projector_error_px";
    case CalibrationResidual::kFittedProjectorError:
      return "fitted_projector_error_px";
  }
  return "unknown";
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
  c.median_px = Median(std::vector<double>(e));  // a copy: e stays aligned with basis
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
  double field_terms = kTerms;
  if (setup.local_blocks > 0) {
    // The local field: the smooth field plus a robust (Huber) mean of what is left in each block
    // of a grid over the image (blocks of fewer than kMinBlockCount samples add nothing).
    double x0 = 1e300, x1 = -1e300, y0 = 1e300, y1 = -1e300;
    for (const Terms& b : basis) {
      x0 = std::min(x0, b(1));
      x1 = std::max(x1, b(1));
      y0 = std::min(y0, b(2));
      y1 = std::max(y1, b(2));
    }
    const int bx = setup.local_blocks;
    const double cell = std::max((x1 - x0) / bx, 1e-12);
    const int by = std::max(1, static_cast<int>(std::ceil((y1 - y0) / cell)));
    const size_t blocks = static_cast<size_t>(bx) * static_cast<size_t>(by);
    std::vector<size_t> block(n);
    std::vector<int> count_in(blocks, 0);
    for (size_t i = 0; i < n; ++i) {
      const int ix = std::clamp(static_cast<int>((basis[i](1) - x0) / cell), 0, bx - 1);
      const int iy = std::clamp(static_cast<int>((basis[i](2) - y0) / cell), 0, by - 1);
      block[i] = static_cast<size_t>(iy) * static_cast<size_t>(bx) + static_cast<size_t>(ix);
      ++count_in[block[i]];
    }
    std::vector<double> mean(blocks, 0.0), sw(blocks), swr(blocks);
    const double k = std::max(1.345 * c.noise_px, 1e-12);
    for (int iter = 0; iter < 10; ++iter) {
      std::fill(sw.begin(), sw.end(), 0.0);
      std::fill(swr.begin(), swr.end(), 0.0);
      for (size_t i = 0; i < n; ++i) {
        const double d = std::abs(r[i] - mean[block[i]]);
        const double wi = d <= k ? 1.0 : k / d;
        sw[block[i]] += wi;
        swr[block[i]] += wi * r[i];
      }
      for (size_t b = 0; b < blocks; ++b) mean[b] = sw[b] > 0 ? swr[b] / sw[b] : 0.0;
    }
    int used = 0;
    for (size_t b = 0; b < blocks; ++b) {
      if (count_in[b] < kMinBlockCount) {
        mean[b] = 0;
      } else {
        ++used;
      }
    }
    double local2 = 0;
    std::vector<double> about(n);
    for (size_t i = 0; i < n; ++i) {
      const double f = coef.dot(basis[i]) + mean[block[i]];
      local2 += f * f;
      about[i] = e[i] - f;
    }
    c.systematic_px = std::sqrt(local2 / static_cast<double>(n));
    c.noise_px = RobustScale(about);
    c.local_blocks = used;
    field_terms += used;
  }

  if (setup.warning_px > 0) {
    c.threshold_source = "user";
    c.threshold_px = setup.warning_px;
  } else {
    c.threshold_px = c.noise_px * std::max(setup.noise_factor,
                                           5.0 * std::sqrt(field_terms / static_cast<double>(n)));
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
    // Ranked by size, then shape. A calibrated rig drifts by fractions of a pixel (a focal length,
    // a principal point); a device knocked out of place by pixels; tens of pixels are more than a
    // bump of a rig that still yields points: a rig file of another rig, or swapped names.
    const char* const kWrongFile = "a wrong rig file or swapped camera names";
    const char* const kBumped = "a device bumped since calibration (a rotation of its pose)";
    std::vector<int> groups;  // the dominant groups, largest share first
    const double top = *std::max_element(c.group_rms_px.begin(), c.group_rms_px.end());
    for (int g = 0; g < CalibrationCheck::kNumGroups; ++g) {
      if (c.group_rms_px[static_cast<size_t>(g)] >= 0.3 * top) groups.push_back(g);
    }
    std::stable_sort(groups.begin(), groups.end(), [&](int a, int b) {
      return c.group_rms_px[static_cast<size_t>(a)] > c.group_rms_px[static_cast<size_t>(b)];
    });
    if (c.systematic_px > kGrossPx) {
      c.likely_causes.push_back(kWrongFile);
      c.likely_causes.push_back(kBumped);
    } else {
      if (c.systematic_px > kBumpPx) c.likely_causes.push_back(kBumped);
      for (int g : groups) c.likely_causes.push_back(Cause(g, setup.stereo));
      if (c.systematic_px > kBumpPx) c.likely_causes.push_back(kWrongFile);
    }
    if (setup.residual == CalibrationResidual::kFittedProjectorError) {
      // The fit absorbs most of any error: what is left is a cloud no projector explains.
      c.likely_causes.insert(c.likely_causes.begin(),
                             "a camera turned about the baseline or a principal point off across "
                             "it (rows out of register), a camera's lens distortion, or swapped "
                             "camera names (a stereo cloud that no projector explains)");
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
                  " correspondences has a " +
                  (local_blocks > 0 ? "local systematic part (a smooth field plus the means of " +
                                          std::to_string(local_blocks) + " image blocks) of "
                                    : std::string("systematic part of ")) +
                  Fixed(systematic_px) + " projector px RMS (median " + Fixed(median_px, "%+.3g") +
                  " px; decode noise " + Fixed(noise_px) + " px)";
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
  nlohmann::json j = {{"available", true},
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
                      {"local_blocks", local_blocks},
                      {"likely_causes", likely_causes},
                      {"warning", warn},
                      {"message", Message()}};
  if (!fitted_projector.empty()) j["fitted_projector"] = fitted_projector;
  return j;
}

// ---- The 1-D projector fit (FitOneAxisProjector) ----

namespace {

constexpr int kProjParams = 10;  // rotation increment (3), translation (3), fx, cx, k1, k2
using ProjVector = Eigen::Matrix<double, kProjParams, 1>;

struct ProjState {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // proj_from_rig
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  double fx = 1, cx = 0, k1 = 0, k2 = 0;

  // The column of p; NaN behind the projector.
  double Column(const Eigen::Vector3d& p) const {
    const Eigen::Vector3d q = rotation * p + translation;
    if (!(q.z() > 0)) return std::numeric_limits<double>::quiet_NaN();
    const double x = q.x() / q.z(), y = q.y() / q.z(), r2 = x * x + y * y;
    return fx * x * (1 + r2 * (k1 + k2 * r2)) + cx;
  }
  // The state moved by `delta` (rotation increment on the left).
  ProjState Moved(const ProjVector& delta) const {
    ProjState s = *this;
    const Eigen::Vector3d w = delta.head<3>();
    if (w.norm() > 0) s.rotation = Eigen::AngleAxisd(w.norm(), w.normalized()) * rotation;
    s.translation += delta.segment<3>(3);
    s.fx += delta(6);
    s.cx += delta(7);
    s.k1 += delta(8);
    s.k2 += delta(9);
    return s;
  }
};

double Huber(double r, double k) {
  const double a = std::abs(r);
  return a <= k ? 0.5 * r * r : k * a - 0.5 * k * k;
}

// The row pair's DLT on normalised data, decomposed into a projector pose, fx and cx; the gauge
// (the translation along the projector's y axis) puts the data's centroid on the row y = 0.
std::optional<ProjState> InitialProjector(const std::vector<Eigen::Vector3d>& p,
                                          const std::vector<double>& u) {
  const size_t n = p.size();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  double mean_u = 0;
  for (size_t i = 0; i < n; ++i) {
    mean += p[i];
    mean_u += u[i];
  }
  mean /= static_cast<double>(n);
  mean_u /= static_cast<double>(n);
  double spread2 = 0, spread_u2 = 0;
  for (size_t i = 0; i < n; ++i) {
    spread2 += (p[i] - mean).squaredNorm();
    spread_u2 += std::pow(u[i] - mean_u, 2);
  }
  const double s = std::sqrt(spread2 / (3.0 * static_cast<double>(n)));
  const double su = std::sqrt(spread_u2 / static_cast<double>(n));
  if (!(s > 0) || !(su > 0)) return std::nullopt;
  Eigen::Matrix<double, 8, 8> m = Eigen::Matrix<double, 8, 8>::Zero();
  for (size_t i = 0; i < n; ++i) {
    Eigen::Vector4d x;
    x << (p[i] - mean) / s, 1.0;
    const double un = (u[i] - mean_u) / su;
    Eigen::Matrix<double, 8, 1> a;
    a << x, -un * x;
    m.noalias() += a * a.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 8, 8>> eig(m);
  const Eigen::Matrix<double, 8, 1> v = eig.eigenvectors().col(0);
  // Back to rig coordinates: x_normalised = T x, u = su u_n + mean_u.
  Eigen::Matrix4d t = Eigen::Matrix4d::Identity() / s;
  t(3, 3) = 1;
  t.topRightCorner<3, 1>() = -mean / s;
  Eigen::Vector4d r1 = t.transpose() * (su * v.head<4>() + mean_u * v.tail<4>());
  Eigen::Vector4d r3 = t.transpose() * v.tail<4>();
  int in_front = 0;
  for (size_t i = 0; i < n; ++i) in_front += r3.head<3>().dot(p[i]) + r3(3) > 0 ? 1 : -1;
  if (in_front < 0) {
    r1 = -r1;
    r3 = -r3;
  }
  const double lambda = r3.head<3>().norm();
  if (!(lambda > 0)) return std::nullopt;
  r1 /= lambda;
  r3 /= lambda;
  ProjState st;
  const Eigen::Vector3d z = r3.head<3>();
  st.cx = r1.head<3>().dot(z);
  const Eigen::Vector3d a = r1.head<3>() - st.cx * z;
  st.fx = a.norm();
  if (!(st.fx > 0)) return std::nullopt;
  const Eigen::Vector3d x = a / st.fx, y = z.cross(x);
  st.rotation.row(0) = x;
  st.rotation.row(1) = y;
  st.rotation.row(2) = z;
  st.translation = Eigen::Vector3d((r1(3) - st.cx * r3(3)) / st.fx, -y.dot(mean), r3(3));
  return st;
}

struct LmResult {
  ProjState state;
  double cost = 0;   // Huber cost at the final scale
  double scale = 0;  // robust scale of the residuals, px
  double rms = 0;    // Huber-weighted RMS residual, px
  int behind = 0;    // points behind the projector
};

// Robust Levenberg-Marquardt over the parameters `active`: IRLS weights (Huber, k = 1.345 x the
// robust scale of the current residuals), steps accepted on the Huber cost.
LmResult RefineProjector(const std::vector<Eigen::Vector3d>& p, const std::vector<double>& u,
                         ProjState state, const std::vector<int>& active) {
  const size_t n = p.size();
  const int m = static_cast<int>(active.size());
  static constexpr double kStep[kProjParams] = {1e-6, 1e-6, 1e-6, 1e-4, 1e-4,
                                                1e-4, 1e-4, 1e-4, 1e-7, 1e-7};
  std::vector<double> r(n);
  auto residuals = [&](const ProjState& s, std::vector<double>* out) {
    int behind = 0;
    for (size_t i = 0; i < n; ++i) {
      (*out)[i] = u[i] - s.Column(p[i]);
      behind += std::isfinite((*out)[i]) ? 0 : 1;
    }
    return behind;
  };
  auto scale_of = [&](const std::vector<double>& res) {
    std::vector<double> finite;
    finite.reserve(n);
    for (double v : res)
      if (std::isfinite(v)) finite.push_back(v);
    return finite.empty() ? 0.0 : std::max(RobustScale(finite), 1e-9);
  };
  auto cost_of = [&](const std::vector<double>& res, double k) {
    double c = 0;
    for (double v : res) c += std::isfinite(v) ? Huber(v, k) : 0.5 * k * k * 100;
    return c;
  };
  residuals(state, &r);
  double scale = scale_of(r);
  double lambda = 1e-3;
  std::vector<double> trial(n);
  for (int iter = 0; iter < 60; ++iter) {
    const double k = 1.345 * scale;
    const double cost = cost_of(r, k);
    Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(m, m);
    Eigen::VectorXd jtr = Eigen::VectorXd::Zero(m);
    Eigen::VectorXd row(m);
    // Central differences: the states moved by +-h along each active parameter.
    std::vector<ProjState> plus, minus;
    for (int j = 0; j < m; ++j) {
      ProjVector d = ProjVector::Zero();
      d(active[static_cast<size_t>(j)]) = kStep[active[static_cast<size_t>(j)]];
      plus.push_back(state.Moved(d));
      minus.push_back(state.Moved(-d));
    }
    for (size_t i = 0; i < n; ++i) {
      if (!std::isfinite(r[i])) continue;
      const double w = std::abs(r[i]) <= k ? 1.0 : k / std::abs(r[i]);
      bool finite = true;
      for (int j = 0; j < m; ++j) {
        const size_t js = static_cast<size_t>(j);
        row(j) = (plus[js].Column(p[i]) - minus[js].Column(p[i])) / (2 * kStep[active[js]]);
        finite = finite && std::isfinite(row(j));
      }
      if (!finite) continue;
      jtj.noalias() += w * row * row.transpose();
      jtr += (w * r[i]) * row;
    }
    bool improved = false, converged = false;
    for (int attempt = 0; attempt < 10 && !improved; ++attempt) {
      Eigen::MatrixXd a = jtj;
      a.diagonal() += lambda * jtj.diagonal().cwiseMax(1e-12);
      const Eigen::VectorXd step = a.ldlt().solve(jtr);
      ProjVector delta = ProjVector::Zero();
      for (int j = 0; j < m; ++j) delta(active[static_cast<size_t>(j)]) = step(j);
      const ProjState next = state.Moved(delta);
      residuals(next, &trial);
      if (cost_of(trial, k) < cost) {
        improved = true;
        const double gain = (cost - cost_of(trial, k)) / std::max(cost, 1e-300);
        state = next;
        r.swap(trial);
        lambda = std::max(lambda * 0.1, 1e-12);
        scale = scale_of(r);
        converged = gain < 1e-10;
      } else {
        lambda *= 10;
      }
    }
    if (!improved || converged) break;
  }
  LmResult out;
  out.state = state;
  out.behind = residuals(state, &r);
  out.scale = scale_of(r);
  const double k = 1.345 * out.scale;
  out.cost = cost_of(r, k);
  double sw = 0, swr2 = 0;
  for (double v : r) {
    if (!std::isfinite(v)) continue;
    const double w = std::abs(v) <= k ? 1.0 : k / std::abs(v);
    sw += w;
    swr2 += w * v * v;
  }
  out.rms = sw > 0 ? std::sqrt(swr2 / sw) : 0;
  return out;
}

}  // namespace

double OneAxisProjectorFit::BaselineMm(const Eigen::Vector3d& center_in_rig) const {
  const Eigen::Vector3d c = proj_from_rig.TargetOriginInSource();
  const Eigen::Vector3d axis = proj_from_rig.rotation.conjugate() * Eigen::Vector3d::UnitY();
  const Eigen::Vector3d d = center_in_rig - c;
  return (d - d.dot(axis) * axis).norm();
}

double OneAxisProjectorFit::Column(const Eigen::Vector3d& point_in_rig) const {
  ProjState s;
  s.rotation = proj_from_rig.rotation.toRotationMatrix();
  s.translation = proj_from_rig.translation;
  s.fx = fx;
  s.cx = cx;
  s.k1 = k1;
  s.k2 = k2;
  return s.Column(point_in_rig);
}

std::string OneAxisProjectorFit::Describe() const {
  if (!ok) return "no projector fitted: " + reason;
  std::string m =
      std::string(radial ? "radial (k1 " + Fixed(k1, "%+.3g") + ", k2 " + Fixed(k2, "%+.3g") + ")"
                         : "pinhole") +
      " 1-D projector, fx " + Fixed(fx, "%.1f") + " px, cx " + Fixed(cx, "%.1f") +
      " px, fitted to " + std::to_string(count) + " points with " + Fixed(rms_px) + " px RMS";
  if (radial) m += " (pinhole: " + Fixed(pinhole_rms_px) + " px)";
  return m;
}

OneAxisProjectorFit FitOneAxisProjector(const std::vector<Eigen::Vector3d>& points_in_rig,
                                        const std::vector<double>& column_px, size_t max_points) {
  OneAxisProjectorFit fit;
  const size_t n_all = std::min(points_in_rig.size(), column_px.size());
  auto finite = [&](size_t i) {
    return points_in_rig[i].allFinite() && std::isfinite(column_px[i]);
  };
  size_t count = 0;
  for (size_t i = 0; i < n_all; ++i) count += finite(i) ? 1 : 0;
  if (count < static_cast<size_t>(kMinCount)) {
    fit.reason = "only " + std::to_string(count) + " points with a decoded column (at least " +
                 std::to_string(kMinCount) + " are needed)";
    return fit;
  }
  const size_t stride =
      (count + std::max<size_t>(max_points, 1) - 1) / std::max<size_t>(max_points, 1);
  std::vector<Eigen::Vector3d> p;
  std::vector<double> u;
  for (size_t i = 0, k = 0; i < n_all; ++i) {
    if (!finite(i) || k++ % stride != 0) continue;
    p.push_back(points_in_rig[i]);
    u.push_back(column_px[i]);
  }
  fit.count = static_cast<int64_t>(p.size());
  const std::optional<ProjState> start = InitialProjector(p, u);
  if (!start) {
    fit.reason = "the points or their columns do not spread (a degenerate fit)";
    return fit;
  }
  const LmResult pinhole = RefineProjector(p, u, *start, {0, 1, 2, 3, 5, 6, 7});
  const LmResult radial = RefineProjector(p, u, pinhole.state, {0, 1, 2, 3, 4, 5, 6, 7, 8, 9});
  // The radial terms (and the row they make observable): 3 more parameters, kept when they lower
  // the (Huber) sum of squares by more than 25 noise variances each.
  const bool use_radial =
      std::isfinite(radial.cost) &&
      2 * (pinhole.cost - radial.cost) > 25.0 * 3.0 * radial.scale * radial.scale;
  const LmResult& best = use_radial ? radial : pinhole;
  if (2 * best.behind > static_cast<int>(p.size()) || !std::isfinite(best.cost)) {
    fit.reason = "most points lie behind every projector that fits their columns";
    return fit;
  }
  fit.ok = true;
  fit.radial = use_radial;
  fit.proj_from_rig = Rigid3d(Eigen::Quaterniond(best.state.rotation), best.state.translation);
  fit.fx = best.state.fx;
  fit.cx = best.state.cx;
  fit.k1 = best.state.k1;
  fit.k2 = best.state.k2;
  fit.rms_px = best.rms;
  fit.pinhole_rms_px = pinhole.rms;
  return fit;
}

}  // namespace slshadow
