#include "calib/calibration.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <map>
#include <cmath>
#include <cstdio>
#include <memory>
#include <numeric>
#include <sstream>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "core/error.h"
#include "core/threads.h"

namespace slshadow {
namespace {

using Pose6 = std::array<double, 6>;  // angle-axis (rad), translation (mm)
using Intr9 = std::array<double, CameraModel::kNumParams>;

Pose6 ToPose6(const Rigid3d& t) {
  const Eigen::AngleAxisd aa(t.rotation);
  const Eigen::Vector3d r = aa.angle() * aa.axis();
  return {r.x(), r.y(), r.z(), t.translation.x(), t.translation.y(), t.translation.z()};
}

Rigid3d FromPose6(const Pose6& p) {
  const Eigen::Vector3d r(p[0], p[1], p[2]);
  const double angle = r.norm();
  const Eigen::Quaterniond q =
      angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, r / angle)) : Eigen::Quaterniond::Identity();
  return Rigid3d(q, Eigen::Vector3d(p[3], p[4], p[5]));
}

// r = weight * (ImgFromCam(intrinsics, dev_from_rig * rig_from_board * W(X)) - u). With aspect > 0 the
// model's fy is aspect * fx (the fy entry of the block is held constant and ignored). W adds the
// board warp z += w_x (1 - s^2) + w_y (1 - t^2), (s, t) the point's position across the board
// extent scaled to [-1, 1] (mrcal's board deformation).
struct ReprojectionFunctor {
  ReprojectionFunctor(const Eigen::Vector3d& point_in_board, const Eigen::Vector2d& pixel, double aspect,
                      const Eigen::Vector4d& extent)
      : x(point_in_board), u(pixel), aspect_ratio(aspect) {
    const double sx = extent[1] > extent[0] ? 2 * (x.x() - extent[0]) / (extent[1] - extent[0]) - 1 : 0;
    const double sy = extent[3] > extent[2] ? 2 * (x.y() - extent[2]) / (extent[3] - extent[2]) - 1 : 0;
    warp_x = 1 - sx * sx;
    warp_y = 1 - sy * sy;
  }

  template <typename T>
  bool operator()(const T* intrinsics, const T* dev_from_rig, const T* rig_from_board, const T* warp, T* residual) const {
    const T point_in_board[3] = {T(x.x()), T(x.y()), T(x.z()) + warp[0] * T(warp_x) + warp[1] * T(warp_y)};
    T point_in_rig[3], point_in_dev[3];
    ceres::AngleAxisRotatePoint(rig_from_board, point_in_board, point_in_rig);
    for (int i = 0; i < 3; ++i) point_in_rig[i] += rig_from_board[3 + i];
    ceres::AngleAxisRotatePoint(dev_from_rig, point_in_rig, point_in_dev);
    for (int i = 0; i < 3; ++i) point_in_dev[i] += dev_from_rig[3 + i];
    T params[CameraModel::kNumParams];
    for (int i = 0; i < CameraModel::kNumParams; ++i) params[i] = intrinsics[i];
    if (aspect_ratio > 0) params[CameraModel::kFy] = intrinsics[CameraModel::kFx] * T(aspect_ratio);
    T pixel[2];
    CameraModel::ImgFromCam(params, point_in_dev, pixel);
    residual[0] = (pixel[0] - T(u.x())) * T(weight);
    residual[1] = (pixel[1] - T(u.y())) * T(weight);
    return true;
  }

  Eigen::Vector3d x;
  Eigen::Vector2d u;
  double aspect_ratio;
  double warp_x = 0, warp_y = 0;
  double weight = 1;  // 1 / noise sigma when whitening
};

// One carried point and its source point (BoardView::source_device), whitened together:
// W (r_source; r_carried), W = L^-1 for their 4x4 noise covariance C = L L^T.
struct CarriedPairFunctor {
  template <typename T>
  bool operator()(const T* source_intrinsics, const T* source_from_rig, const T* intrinsics, const T* dev_from_rig,
                  const T* rig_from_board, const T* warp, T* residual) const {
    T r[4];
    source(source_intrinsics, source_from_rig, rig_from_board, warp, r);
    carried(intrinsics, dev_from_rig, rig_from_board, warp, r + 2);
    for (int i = 0; i < 4; ++i) {
      residual[i] = T(0);
      for (int j = 0; j <= i; ++j) residual[i] += T(whiten(i, j)) * r[j];
    }
    return true;
  }

  ReprojectionFunctor source, carried;
  Eigen::Matrix4d whiten;  // lower triangular
};

// Weights of the joint noise model (CalibrationOptions::correlated_carried_noise).
struct NoiseModel {
  std::vector<double> sigma_px;  // per device, per coordinate
  double carry_scale = 1;        // k on carry_covariances_px2
};

// Error field of one device's corners within a view (view-correlated noise model): sigma per
// coordinate, and the correlation of two corners delta grid squares apart, share *
// exp(-delta^2 / (2 length^2)) (1 at delta 0).
struct ViewNoiseKernel {
  double sigma_px = 0;
  double share = 0;
  double length_squares = 1;
};

// Whitening of a carried point and its source: C = [[s^2 I, s^2 J^T], [s^2 J, s^2 J J^T + carry]];
// std::nullopt when C is not positive definite.
std::optional<Eigen::Matrix4d> PairWhitening(double sigma, const Eigen::Matrix2d& jacobian, const Eigen::Matrix2d& carry) {
  const double s2 = sigma * sigma;
  Eigen::Matrix4d c;
  c.topLeftCorner<2, 2>() = s2 * Eigen::Matrix2d::Identity();
  c.topRightCorner<2, 2>() = s2 * jacobian.transpose();
  c.bottomLeftCorner<2, 2>() = s2 * jacobian;
  c.bottomRightCorner<2, 2>() = s2 * jacobian * jacobian.transpose() + carry;
  const Eigen::LLT<Eigen::Matrix4d> llt(c);
  if (llt.info() != Eigen::Success) return std::nullopt;
  const Eigen::Matrix4d w = llt.matrixL().solve(Eigen::Matrix4d::Identity());
  if (!w.allFinite()) return std::nullopt;
  return w;
}

// Index of `device`'s view of `pose` in input.views, -1 when there is none.
int FindView(const CalibrationInput& input, int device, int pose) {
  for (size_t i = 0; i < input.views.size(); ++i) {
    if (input.views[i].device == device && input.views[i].pose == pose) return static_cast<int>(i);
  }
  return -1;
}

ceres::LossFunction* MakeLoss(const CalibrationOptions& options, double scale) {
  if (options.loss == LossType::kHuber) return new ceres::HuberLoss(scale);
  if (options.loss == LossType::kCauchy) return new ceres::CauchyLoss(scale);
  return nullptr;
}

// All unknowns of one problem.
struct State {
  std::vector<Intr9> intrinsics;
  std::vector<double> aspect;  // per device: fixed fy/fx, or 0 when free
  std::vector<Pose6> dev_from_rig;
  std::vector<Pose6> rig_from_board;
  std::vector<bool> pose_known;
  // Per device: principal-point coordinates pinned to their bound by the last solve (Solve).
  std::vector<std::vector<int>> pinned;
  std::array<double, 2> warp{0, 0};            // board warp, mm
  Eigen::Vector4d extent = Eigen::Vector4d::Zero();  // board xmin xmax ymin ymax, mm
};

Eigen::Vector4d BoardExtent(const CalibrationInput& input) {
  Eigen::Vector4d e(1e300, -1e300, 1e300, -1e300);
  for (const auto& v : input.views) {
    for (const auto& p : v.points_in_board_mm) {
      e[0] = std::min(e[0], p.x());
      e[1] = std::max(e[1], p.x());
      e[2] = std::min(e[2], p.y());
      e[3] = std::max(e[3], p.y());
    }
  }
  return e;
}

Intr9 EffectiveParams(const State& s, int d) {
  Intr9 p = s.intrinsics[d];
  if (s.aspect[d] > 0) p[CameraModel::kFy] = p[CameraModel::kFx] * s.aspect[d];
  return p;
}

Eigen::Vector2d ProjectView(const State& s, const BoardView& v, size_t i) {
  const ReprojectionFunctor f(v.points_in_board_mm[i], Eigen::Vector2d::Zero(), s.aspect[v.device], s.extent);
  Eigen::Vector2d pixel;
  f(s.intrinsics[v.device].data(), s.dev_from_rig[v.device].data(), s.rig_from_board[v.pose].data(), s.warp.data(),
    pixel.data());
  return pixel;
}

std::vector<int> HeldIntrinsics(const CalibrationOptions& o, const CalibrationDevice& device, double aspect) {
  std::vector<int> held;
  for (int i : device.held_params) {
    if (i != CameraModel::kFy || aspect <= 0) held.push_back(i);
  }
  if (aspect > 0) held.push_back(CameraModel::kFy);
  if (o.fix_principal_point) {
    held.push_back(CameraModel::kCx);
    held.push_back(CameraModel::kCy);
  }
  if (o.zero_tangential) {
    held.push_back(CameraModel::kP1);
    held.push_back(CameraModel::kP2);
  }
  if (o.fix_k3) held.push_back(CameraModel::kK3);
  std::sort(held.begin(), held.end());
  held.erase(std::unique(held.begin(), held.end()), held.end());
  return held;
}

struct SolveOutput {
  ceres::Solver::Summary summary;
  std::vector<Matrix9d> covariance;  // per device, unscaled (J^T J)^-1 in the 9 parameters
  std::vector<Matrix9d> correlated_covariance;  // per device, px-scaled sandwich (with `kernels`)
  int num_free_parameters = 0;
  bool repeat = false;  // a principal-point coordinate was pinned to its bound: solve again
};

// Covariance (px^2, 2x2) of the errors of point ia of view va and point ib of view vb of the same
// pose under the view-correlated noise model (CalibrationResult::correlated_covariance): each
// point's error is M e(X) + h(X), e the error field of its source device (the device itself, or
// the device its pixels were carried from, M = J then, else I) and h the carried device's own
// field; each field is Gaussian-correlated across the board, independent between devices.
Eigen::Matrix2d PointPairCovariance(const std::vector<ViewNoiseKernel>& kernels, const BoardView& va, size_t ia,
                                    const BoardView& vb, size_t ib, double spacing_mm) {
  const double delta = (va.points_in_board_mm[ia] - vb.points_in_board_mm[ib]).norm() / spacing_mm;
  auto rho = [&](const ViewNoiseKernel& k) {
    const double r = delta < 1e-9 ? 1.0 : k.share * std::exp(-delta * delta / (2 * k.length_squares * k.length_squares));
    return k.sigma_px * k.sigma_px * r;
  };
  const int sa = va.IsCarried() ? va.source_device : va.device, sb = vb.IsCarried() ? vb.source_device : vb.device;
  const Eigen::Matrix2d ma = va.IsCarried() ? va.source_jacobians[ia] : Eigen::Matrix2d::Identity();
  const Eigen::Matrix2d mb = vb.IsCarried() ? vb.source_jacobians[ib] : Eigen::Matrix2d::Identity();
  Eigen::Matrix2d c = Eigen::Matrix2d::Zero();
  if (sa == sb) c += rho(kernels[static_cast<size_t>(sa)]) * ma * mb.transpose();
  if (va.IsCarried() && vb.IsCarried() && va.device == vb.device && va.source_device == vb.source_device) {
    c += rho(kernels[static_cast<size_t>(va.device)]) * Eigen::Matrix2d::Identity();
  }
  return c;
}

// Smallest distance between two board points of a view (the grid spacing), mm.
double GridSpacing(const BoardView& v) {
  double spacing = 1e300;
  for (size_t i = 0; i < v.points_in_board_mm.size(); ++i) {
    for (size_t j = i + 1; j < v.points_in_board_mm.size(); ++j) {
      spacing = std::min(spacing, (v.points_in_board_mm[i] - v.points_in_board_mm[j]).norm());
    }
  }
  return spacing > 0 && spacing < 1e300 ? spacing : 1.0;
}

// The view-correlated covariance of all free parameters (the sandwich
// (J^T J)^-1 J^T Sigma J (J^T J)^-1, Sigma the errors' covariance pose by pose), for Solve. The
// rows of `crs` and `residuals` are the single-point blocks in `block_points` order (two each);
// `inv` is (J^T J)^-1. When the first guess in `kernels` shows correlation, each device's kernel is
// refitted to the residuals' moments first and written back (Solve's comment says how).
Eigen::MatrixXd ViewCorrelatedCovariance(const CalibrationInput& input, const std::vector<std::pair<int, int>>& block_points,
                                         const std::vector<double>& residuals, const ceres::CRSMatrix& crs,
                                         const Eigen::MatrixXd& inv, int cols, std::vector<ViewNoiseKernel>* kernels) {
  // Pose by pose (errors of different poses are independent): Jacobian rows, residuals,
  // the hat block H_pp = J_p (J^T J)^-1 J_p^T, and the moment units: per point its
  // residual, for a carried point its own part r - J r_source.
  struct Unit {
    int device = 0;
    std::vector<std::pair<Eigen::Index, Eigen::Matrix2d>> terms;  // sum of c * r(block)
  };
  struct PoseRows {
    std::vector<int> blocks;
    // The pose's Jacobian rows restricted to the columns any of them touches (`cols`: its devices'
    // intrinsics and rig poses, its board pose; the rest are zero), and the hat block.
    std::vector<Eigen::Index> cols;
    Eigen::MatrixXd j, h;
    Eigen::VectorXd r;
    double spacing = 1e300;
    std::vector<Unit> units;  // one per block, in block order
    std::vector<std::array<int, 3>> pairs;  // unit a, unit b, lag 0 (a = b), 1 or 2 (sqrt 2 squares)
    Eigen::MatrixXd th, tj;  // T H and T J, T the units' linear map (row pair u: sum of c * rows of block)
  };
  auto apply_units = [](const PoseRows& p, const Eigen::MatrixXd& m) {  // T m
    Eigen::MatrixXd out = Eigen::MatrixXd::Zero(2 * static_cast<Eigen::Index>(p.units.size()), m.cols());
    for (size_t u = 0; u < p.units.size(); ++u) {
      for (const auto& [k, c] : p.units[u].terms) out.middleRows(2 * static_cast<Eigen::Index>(u), 2).noalias() += c * m.middleRows(2 * k, 2);
    }
    return out;
  };
  std::vector<PoseRows> poses(static_cast<size_t>(input.num_poses));
  for (size_t k = 0; k < block_points.size(); ++k) {
    poses[static_cast<size_t>(input.views[static_cast<size_t>(block_points[k].first)].pose)].blocks.push_back(static_cast<int>(k));
  }
  std::erase_if(poses, [](const PoseRows& p) { return p.blocks.empty(); });
  std::vector<double> view_spacing(input.views.size(), -1);  // GridSpacing per view, computed once
  for (auto& p : poses) {
    const auto m = static_cast<Eigen::Index>(2 * p.blocks.size());
    std::vector<Eigen::Index> compact(static_cast<size_t>(cols), -1);  // column -> column of p.j
    for (int b : p.blocks) {
      for (int row = 2 * b; row < 2 * b + 2; ++row) {
        for (int e = crs.rows[row]; e < crs.rows[row + 1]; ++e) {
          if (compact[static_cast<size_t>(crs.cols[e])] < 0) compact[static_cast<size_t>(crs.cols[e])] = 0;
        }
      }
    }
    for (int c = 0; c < cols; ++c) {
      if (compact[static_cast<size_t>(c)] < 0) continue;
      compact[static_cast<size_t>(c)] = static_cast<Eigen::Index>(p.cols.size());
      p.cols.push_back(c);
    }
    p.j = Eigen::MatrixXd::Zero(m, static_cast<Eigen::Index>(p.cols.size()));
    p.r.resize(m);
    std::map<std::pair<int, int>, Eigen::Index> local;  // (view, point) -> block index in the pose
    for (size_t a = 0; a < p.blocks.size(); ++a) {
      const auto [va, ia] = block_points[static_cast<size_t>(p.blocks[a])];
      local[{va, ia}] = static_cast<Eigen::Index>(a);
      double& spacing = view_spacing[static_cast<size_t>(va)];
      if (spacing < 0) spacing = GridSpacing(input.views[static_cast<size_t>(va)]);
      p.spacing = std::min(p.spacing, spacing);
      for (int r = 0; r < 2; ++r) {
        const int row = 2 * p.blocks[a] + r;
        p.r(static_cast<Eigen::Index>(2 * a) + r) = residuals[static_cast<size_t>(row)];
        for (int e = crs.rows[row]; e < crs.rows[row + 1]; ++e) {
          p.j(static_cast<Eigen::Index>(2 * a) + r, compact[static_cast<size_t>(crs.cols[e])]) = crs.values[e];
        }
      }
    }
    p.h = p.j * inv(p.cols, p.cols) * p.j.transpose();
    std::map<int, std::vector<int>> view_units;  // view -> its units
    for (size_t a = 0; a < p.blocks.size(); ++a) {
      const auto [va, ia] = block_points[static_cast<size_t>(p.blocks[a])];
      const BoardView& v = input.views[static_cast<size_t>(va)];
      Unit u;
      u.device = v.device;
      u.terms.emplace_back(static_cast<Eigen::Index>(a), Eigen::Matrix2d::Identity());
      if (v.IsCarried()) {
        const auto it = local.find({FindView(input, v.source_device, v.pose), v.source_points[static_cast<size_t>(ia)]});
        if (it != local.end()) u.terms.emplace_back(it->second, -v.source_jacobians[static_cast<size_t>(ia)]);
      }
      view_units[va].push_back(static_cast<int>(p.units.size()));
      p.units.push_back(std::move(u));
    }
    for (const auto& [va, us] : view_units) {
      for (size_t a = 0; a < us.size(); ++a) {
        const auto ia = static_cast<size_t>(block_points[static_cast<size_t>(p.blocks[static_cast<size_t>(us[a])])].second);
        for (size_t b = a; b < us.size(); ++b) {
          const auto ib = static_cast<size_t>(block_points[static_cast<size_t>(p.blocks[static_cast<size_t>(us[b])])].second);
          const auto& x = input.views[static_cast<size_t>(va)].points_in_board_mm;
          const double delta = (x[ia] - x[ib]).norm() / p.spacing;
          const int lag = a == b ? 0 : std::abs(delta - 1) < 0.01 ? 1 : std::abs(delta - std::sqrt(2.0)) < 0.01 ? 2 : -1;
          if (lag >= 0) p.pairs.push_back({us[a], us[b], lag});
        }
      }
    }
    p.th = apply_units(p, p.h);
    p.tj = apply_units(p, p.j);
  }
  auto sigma_of = [&](const std::vector<ViewNoiseKernel>& k, const PoseRows& p) {
    const auto m = static_cast<Eigen::Index>(2 * p.blocks.size());
    Eigen::MatrixXd sigma = Eigen::MatrixXd::Zero(m, m);
    auto active = [&](const BoardView& v) {  // does any field of this view's points have noise?
      return k[static_cast<size_t>(v.IsCarried() ? v.source_device : v.device)].sigma_px > 0 ||
             (v.IsCarried() && k[static_cast<size_t>(v.device)].sigma_px > 0);
    };
    for (size_t a = 0; a < p.blocks.size(); ++a) {
      const auto [va, ia] = block_points[static_cast<size_t>(p.blocks[a])];
      const BoardView& v = input.views[static_cast<size_t>(va)];
      if (!active(v)) continue;
      for (size_t b = a; b < p.blocks.size(); ++b) {
        const auto [vb, ib] = block_points[static_cast<size_t>(p.blocks[b])];
        const BoardView& w = input.views[static_cast<size_t>(vb)];
        if (!active(w)) continue;
        const Eigen::Matrix2d c = PointPairCovariance(k, v, static_cast<size_t>(ia), w, static_cast<size_t>(ib), p.spacing);
        const auto ra = static_cast<Eigen::Index>(2 * a), rb = static_cast<Eigen::Index>(2 * b);
        sigma.block<2, 2>(ra, rb) = c;
        sigma.block<2, 2>(rb, ra) = c.transpose();
      }
    }
    return sigma;
  };
  auto meat_of = [&](const std::vector<Eigen::MatrixXd>& sigmas) {
    Eigen::MatrixXd meat = Eigen::MatrixXd::Zero(cols, cols);
    for (size_t i = 0; i < poses.size(); ++i) meat(poses[i].cols, poses[i].cols) += poses[i].j.transpose() * sigmas[i] * poses[i].j;
    return meat;
  };
  // Sum over each device's unit pairs of u_a . u_b by lag, for a covariance C of the
  // residuals (entry(a, b): the 2x2 block of C between blocks a and b).
  const size_t nd = input.devices.size();
  auto pair_sums = [&](const PoseRows& p, const auto& entry, std::vector<double>* sums) {
    for (const auto& [ua, ub, lag] : p.pairs) {
      double v = 0;
      for (const auto& [ka, ca] : p.units[static_cast<size_t>(ua)].terms) {
        for (const auto& [kb, cb] : p.units[static_cast<size_t>(ub)].terms) v += (ca * entry(ka, kb) * cb.transpose()).trace();
      }
      (*sums)[3 * static_cast<size_t>(p.units[static_cast<size_t>(ua)].device) + static_cast<size_t>(lag)] += v;
    }
  };
  // Expected sums when the errors have covariance `k`: residuals r = (I - H) e, so
  // E[r r^T]_pp = S_p - H_pp S_p - S_p H_pp + J_p (J^T J)^-1 (sum_q J_q^T S_q J_q) (J^T J)^-1 J_p^T.
  // A unit pair's sum is trace(T_a E T_b^T), T the units' map: with S, H and K symmetric,
  // trace((T S T^T)_ab) - <(T H)_a, (T S)_b> - <(T S)_a, (T H)_b> + <(T J K)_a, (T J)_b>, <,> the
  // sum of the element-wise product of two row pairs (T H and T J are fixed: computed once).
  auto expected = [&](const std::vector<ViewNoiseKernel>& k) {
    std::vector<double> sums(3 * nd, 0);
    std::vector<Eigen::MatrixXd> sigmas;
    for (const auto& p : poses) sigmas.push_back(sigma_of(k, p));
    const Eigen::MatrixXd kk = inv * meat_of(sigmas) * inv;
    for (size_t i = 0; i < poses.size(); ++i) {
      const PoseRows& p = poses[i];
      const Eigen::MatrixXd ts = apply_units(p, sigmas[i]);
      const Eigen::MatrixXd tjk = p.tj * kk(p.cols, p.cols);
      for (const auto& [ua, ub, lag] : p.pairs) {
        const Eigen::Index a = 2 * ua, b = 2 * ub;
        double v = 0;
        for (const auto& [kb, cb] : p.units[static_cast<size_t>(ub)].terms) v += (ts.block<2, 2>(a, 2 * kb) * cb.transpose()).trace();
        v -= p.th.middleRows(a, 2).cwiseProduct(ts.middleRows(b, 2)).sum();
        v -= ts.middleRows(a, 2).cwiseProduct(p.th.middleRows(b, 2)).sum();
        v += tjk.middleRows(a, 2).cwiseProduct(p.tj.middleRows(b, 2)).sum();
        sums[3 * static_cast<size_t>(p.units[static_cast<size_t>(ua)].device) + static_cast<size_t>(lag)] += v;
      }
    }
    return sums;
  };
  std::vector<double> observed(3 * nd, 0);
  for (const auto& p : poses) {
    pair_sums(p, [&](Eigen::Index a, Eigen::Index b) {
      return Eigen::Matrix2d(p.r.segment<2>(2 * a) * p.r.segment<2>(2 * b).transpose());
    }, &observed);
  }
  // Moment matching: each device's field contributes sigma^2 (nugget) and sigma^2 share
  // (correlated part) linearly; its length is searched on a grid, device by device.
  auto structure = [&](size_t f, double share, double length) {
    std::vector<ViewNoiseKernel> k(nd);
    k[f] = {1.0, share, length};
    return expected(k);
  };
  bool seen = false;  // any correlation in the residuals? (else the residual-based estimate stands)
  for (const auto& k : *kernels) seen = seen || k.share > 0;
  std::vector<std::vector<double>> nugget(nd);
  for (size_t f = 0; seen && f < nd; ++f) nugget[f] = structure(f, 0, 1);
  const std::vector<double> grid = {0.4, 0.6, 0.85, 1.2, 1.7, 2.4, 3.4};
  std::vector<double> length(nd);
  std::map<std::pair<size_t, size_t>, std::vector<double>> correlated;  // (field, grid index)
  auto correlated_of = [&](size_t f, size_t g) -> const std::vector<double>& {
    auto it = correlated.find({f, g});
    if (it == correlated.end()) {
      std::vector<double> c = structure(f, 1, grid[g]);
      for (size_t i = 0; i < c.size(); ++i) c[i] -= nugget[f][i];
      it = correlated.emplace(std::make_pair(f, g), std::move(c)).first;
    }
    return it->second;
  };
  std::vector<size_t> at(nd, 0);
  for (size_t f = 0; f < nd; ++f) {  // start from the residual-based estimate
    for (size_t g = 0; g < grid.size(); ++g) {
      if (std::abs(grid[g] - (*kernels)[f].length_squares) < std::abs(grid[at[f]] - (*kernels)[f].length_squares)) at[f] = g;
    }
  }
  auto fit = [&](const std::vector<size_t>& g, Eigen::VectorXd* x) {
    Eigen::MatrixXd a(3 * nd, 2 * nd);
    Eigen::VectorXd b(3 * nd);
    for (size_t i = 0; i < 3 * nd; ++i) {
      const double w = observed[3 * (i / 3)] > 0 ? 1 / observed[3 * (i / 3)] : 0;  // per device, by its energy
      b(static_cast<Eigen::Index>(i)) = w * observed[i];
      for (size_t f = 0; f < nd; ++f) {
        a(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(2 * f)) = w * nugget[f][i];
        a(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(2 * f + 1)) = w * correlated_of(f, g[f])[i];
      }
    }
    *x = a.colPivHouseholderQr().solve(b);
    return (a * *x - b).squaredNorm();
  };
  Eigen::VectorXd x;
  for (int pass = 0; seen && pass < (nd > 1 ? 2 : 1); ++pass) {
    for (size_t f = 0; f < nd; ++f) {
      size_t best = at[f];
      double best_err = 1e300;
      for (size_t g = 0; g < grid.size(); ++g) {
        std::vector<size_t> trial = at;
        trial[f] = g;
        const double err = fit(trial, &x);
        if (err < best_err) {
          best_err = err;
          best = g;
        }
      }
      at[f] = best;
    }
  }
  if (seen) fit(at, &x);
  for (size_t f = 0; seen && f < nd; ++f) {
    const double var = x(static_cast<Eigen::Index>(2 * f)), cov = x(static_cast<Eigen::Index>(2 * f + 1));
    if (!(var > 0) || observed[3 * f] <= 0) continue;  // keep the residual-based estimate
    (*kernels)[f] = {std::sqrt(var), std::clamp(cov / var, 0.0, 1.0), grid[at[f]]};
  }
  std::vector<Eigen::MatrixXd> sigmas;
  for (const auto& p : poses) sigmas.push_back(sigma_of(*kernels, p));
  return inv * meat_of(sigmas) * inv;
}

// One Levenberg-Marquardt solve over `input`, starting from and updating `s`. With `noise`, carried
// points are whitened jointly with their source points and every other point is weighted by
// 1 / its device's sigma; without, all points are independent and equally weighted.
//
// With `kernels` (and no `noise`) the covariance is also computed under the view-correlated noise
// model: (J^T J)^-1 J^T Sigma J (J^T J)^-1, Sigma the errors' covariance within each pose. When
// the first guess in `kernels` shows correlation, each device's kernel is first refitted (and
// written back): the moments of the residuals (per device: sum of |r|^2, of r_i . r_j one and
// sqrt(2) squares apart) are matched to their expectation E[r r^T] = (I - H) Sigma (I - H)^T,
// H = J (J^T J)^-1 J^T, linear in sigma^2 and sigma^2 share for each length on a grid.
//
// `pinned` (per device, CameraModel indices): principal-point coordinates held at their bound
// (CalibrationOptions::principal_point_inside); with that option, a free cx or cy that ends outside
// its image is clamped to the bound and added to `pinned`, and the solve returns `repeat` (before
// the covariance) for Solve to solve again with it held: an active-set method, which converges
// where Ceres' projected steps on parameter bounds stalled (kamino: 433 iterations, not converged).
SolveOutput SolveOnce(const CalibrationInput& input, const CalibrationOptions& options, State* s, bool want_covariance,
                      const NoiseModel* noise, std::vector<ViewNoiseKernel>* kernels, std::vector<std::vector<int>>* pinned) {
  auto held_of = [&](size_t d) {
    std::vector<int> held = HeldIntrinsics(options, input.devices[d], s->aspect[d]);
    held.insert(held.end(), (*pinned)[d].begin(), (*pinned)[d].end());
    std::sort(held.begin(), held.end());
    held.erase(std::unique(held.begin(), held.end()), held.end());
    return held;
  };
  ceres::Problem problem;
  std::vector<bool> device_used(input.devices.size(), false), pose_used(static_cast<size_t>(input.num_poses), false);
  // Points in a joint pair, per view (not added again alone).
  std::vector<std::vector<bool>> paired(input.views.size());
  // Single-point residual blocks in order, and their (view, point).
  std::vector<ceres::ResidualBlockId> block_ids;
  std::vector<std::pair<int, int>> block_points;
  for (size_t vi = 0; noise && vi < input.views.size(); ++vi) {
    const BoardView& v = input.views[vi];
    if (!v.IsCarried() || !s->pose_known[v.pose]) continue;
    const auto si = static_cast<size_t>(FindView(input, v.source_device, v.pose));  // exists (input.Check())
    const BoardView& src = input.views[si];
    paired[vi].resize(v.pixels_px.size(), false);
    paired[si].resize(src.pixels_px.size(), false);
    const double sigma = noise->sigma_px[src.device];
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const auto j = static_cast<size_t>(v.source_points[i]);
      if (paired[si][j]) continue;  // a source point pairs once
      const auto w = PairWhitening(sigma, v.source_jacobians[i], noise->carry_scale * v.carry_covariances_px2[i]);
      if (!w) continue;
      auto* cost = new ceres::AutoDiffCostFunction<CarriedPairFunctor, 4, CameraModel::kNumParams, 6,
                                                   CameraModel::kNumParams, 6, 6, 2>(new CarriedPairFunctor{
          ReprojectionFunctor(src.points_in_board_mm[j], src.pixels_px[j], s->aspect[src.device], s->extent),
          ReprojectionFunctor(v.points_in_board_mm[i], v.pixels_px[i], s->aspect[v.device], s->extent), *w});
      problem.AddResidualBlock(cost, MakeLoss(options, options.loss_scale_px / sigma), s->intrinsics[src.device].data(),
                               s->dev_from_rig[src.device].data(), s->intrinsics[v.device].data(),
                               s->dev_from_rig[v.device].data(), s->rig_from_board[v.pose].data(), s->warp.data());
      paired[vi][i] = paired[si][j] = true;
    }
  }
  for (size_t vi = 0; vi < input.views.size(); ++vi) {
    const BoardView& v = input.views[vi];
    if (!s->pose_known[v.pose]) continue;
    const double weight = noise ? 1 / noise->sigma_px[v.device] : 1.0;
    for (size_t i = 0; i < v.points_in_board_mm.size(); ++i) {
      if (!paired[vi].empty() && paired[vi][i]) continue;
      auto* f = new ReprojectionFunctor(v.points_in_board_mm[i], v.pixels_px[i], s->aspect[v.device], s->extent);
      f->weight = weight;
      auto* cost = new ceres::AutoDiffCostFunction<ReprojectionFunctor, 2, CameraModel::kNumParams, 6, 6, 2>(f);
      // The loss is owned by the problem, one per residual.
      block_points.emplace_back(static_cast<int>(vi), static_cast<int>(i));
      block_ids.push_back(problem.AddResidualBlock(cost, MakeLoss(options, options.loss_scale_px * weight), s->intrinsics[v.device].data(),
                               s->dev_from_rig[v.device].data(), s->rig_from_board[v.pose].data(), s->warp.data()));
    }
    device_used[v.device] = true;
    pose_used[v.pose] = true;
  }
  SolveOutput out;
  for (size_t d = 0; d < input.devices.size(); ++d) {
    if (!device_used[d]) continue;
    double* intr = s->intrinsics[d].data();
    const auto held = held_of(d);
    if (options.fix_intrinsics || input.devices[d].hold_intrinsics) {
      problem.SetParameterBlockConstant(intr);
    } else {
      if (!held.empty()) problem.SetManifold(intr, new ceres::SubsetManifold(CameraModel::kNumParams, held));
      out.num_free_parameters += CameraModel::kNumParams - static_cast<int>(held.size());
    }
    if (d == 0) {
      problem.SetParameterBlockConstant(s->dev_from_rig[d].data());
    } else {
      out.num_free_parameters += 6;
    }
  }
  for (int p = 0; p < input.num_poses; ++p) {
    if (pose_used[p]) out.num_free_parameters += 6;
  }
  const bool estimate_warp = options.estimate_board_warp && problem.HasParameterBlock(s->warp.data());
  if (problem.HasParameterBlock(s->warp.data())) {
    if (estimate_warp) {
      out.num_free_parameters += 2;
    } else {
      problem.SetParameterBlockConstant(s->warp.data());
    }
  }
  ceres::Solver::Options so;
  so.linear_solver_type = ceres::DENSE_SCHUR;
  so.max_num_iterations = options.max_iterations;
  so.function_tolerance = 1e-12;
  so.gradient_tolerance = 1e-14;
  so.parameter_tolerance = 1e-12;
  so.num_threads = ThreadBudget();
  so.logging_type = ceres::SILENT;
  ceres::Solve(so, &problem, &out.summary);
  for (size_t d = 0; options.principal_point_inside && d < input.devices.size(); ++d) {
    if (!device_used[d] || options.fix_intrinsics || input.devices[d].hold_intrinsics) continue;
    const auto held = held_of(d);
    for (int i : {CameraModel::kCx, CameraModel::kCy}) {
      if (std::find(held.begin(), held.end(), i) != held.end()) continue;
      const double upper = (i == CameraModel::kCx ? input.devices[d].width : input.devices[d].height) - 0.5;
      double& v = s->intrinsics[d][static_cast<size_t>(i)];
      if (v >= -0.5 && v <= upper) continue;
      v = std::clamp(v, -0.5, upper);
      (*pinned)[d].push_back(i);
      out.repeat = true;
    }
  }
  if (out.repeat) return out;

  if (want_covariance && !options.fix_intrinsics) {
    // Covariance (J^T J)^-1 of all free parameters, from the Jacobian at the solution (tangent
    // space of each block's manifold), with Jacobi column scaling: intrinsics (fx ~ 1e3, k3 ~ 1e-2
    // sensitivities) and poses span ~10 orders of magnitude, which puts ceres::Covariance's
    // unscaled dense SVD below its rank threshold on well-posed problems.
    std::vector<double*> blocks;
    std::vector<int> intr_column(input.devices.size(), -1);
    int cols = 0;
    for (size_t d = 0; d < input.devices.size(); ++d) {
      if (!device_used[d] || input.devices[d].hold_intrinsics) continue;
      blocks.push_back(s->intrinsics[d].data());
      intr_column[d] = cols;
      cols += problem.ParameterBlockTangentSize(s->intrinsics[d].data());
    }
    for (size_t d = 1; d < input.devices.size(); ++d) {
      if (!device_used[d]) continue;
      blocks.push_back(s->dev_from_rig[d].data());
      cols += 6;
    }
    for (int p = 0; p < input.num_poses; ++p) {
      if (!pose_used[p]) continue;
      blocks.push_back(s->rig_from_board[p].data());
      cols += 6;
    }
    if (estimate_warp) {
      blocks.push_back(s->warp.data());
      cols += 2;
    }
    ceres::Problem::EvaluateOptions eo;
    eo.parameter_blocks = blocks;
    eo.num_threads = ThreadBudget();
    ceres::CRSMatrix crs;
    double cost = 0;
    const bool sandwich = kernels != nullptr && noise == nullptr;
    if (sandwich) eo.residual_blocks = block_ids;  // rows 2k, 2k + 1 are block k's
    std::vector<double> residuals;
    if (cols > 0 && problem.Evaluate(eo, &cost, &residuals, nullptr, &crs)) {
      Eigen::MatrixXd jtj = Eigen::MatrixXd::Zero(cols, cols);
      for (int r = 0; r < crs.num_rows; ++r) {
        for (int a = crs.rows[r]; a < crs.rows[r + 1]; ++a) {
          for (int b = crs.rows[r]; b < crs.rows[r + 1]; ++b) jtj(crs.cols[a], crs.cols[b]) += crs.values[a] * crs.values[b];
        }
      }
      const Eigen::VectorXd scale = jtj.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
      const Eigen::MatrixXd scaled = scale.asDiagonal() * jtj * scale.asDiagonal();
      const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(scaled);
      const double max_ev = es.eigenvalues().maxCoeff();
      if (es.info() == Eigen::Success && es.eigenvalues().minCoeff() > 1e-12 * max_ev) {
        const Eigen::MatrixXd inv = scale.asDiagonal() *
                                    (es.eigenvectors() * es.eigenvalues().cwiseInverse().asDiagonal() *
                                     es.eigenvectors().transpose()) *
                                    scale.asDiagonal();
        // Per device: lift from the tangent space (free coordinates in order) to the 9 parameters.
        auto lift = [&](const Eigen::MatrixXd& full, size_t d) {
          Matrix9d c = Matrix9d::Zero();
          if (intr_column[d] < 0) return c;
          const auto held = held_of(d);
          std::vector<int> free;
          for (int i = 0; i < CameraModel::kNumParams; ++i) {
            if (std::find(held.begin(), held.end(), i) == held.end()) free.push_back(i);
          }
          for (size_t a = 0; a < free.size(); ++a) {
            for (size_t b = 0; b < free.size(); ++b) {
              c(free[a], free[b]) = full(intr_column[d] + static_cast<int>(a), intr_column[d] + static_cast<int>(b));
            }
          }
          if (s->aspect[d] > 0) {  // fy = aspect * fx
            Matrix9d j = Matrix9d::Identity();
            j(CameraModel::kFy, CameraModel::kFy) = 0;
            j(CameraModel::kFy, CameraModel::kFx) = s->aspect[d];
            c = j * c * j.transpose();
          }
          return c;
        };
        for (size_t d = 0; d < input.devices.size(); ++d) out.covariance.push_back(lift(inv, d));
        if (sandwich) {
          const Eigen::MatrixXd sandwich_cov =
              ViewCorrelatedCovariance(input, block_points, residuals, crs, inv, cols, kernels);
          for (size_t d = 0; d < input.devices.size(); ++d) out.correlated_covariance.push_back(lift(sandwich_cov, d));
        }
      }
    }
  }
  return out;
}

// SolveOnce until no principal-point coordinate leaves its image (at most once per coordinate).
SolveOutput Solve(const CalibrationInput& input, const CalibrationOptions& options, State* s, bool want_covariance,
                  const NoiseModel* noise = nullptr, std::vector<ViewNoiseKernel>* kernels = nullptr) {
  // A solve with iterations finds its own active set; an evaluation (max_iterations 0, the
  // covariance at a solution) keeps the one the solution was found with.
  std::vector<std::vector<int>> pinned(input.devices.size());
  if (options.max_iterations == 0 && s->pinned.size() == input.devices.size()) pinned = s->pinned;
  double initial_cost = -1;  // of the first pass (a pinned pass starts from the clamped point)
  for (;;) {
    SolveOutput out = SolveOnce(input, options, s, want_covariance, noise, kernels, &pinned);
    if (initial_cost < 0) initial_cost = out.summary.initial_cost;
    if (out.repeat) continue;
    s->pinned = pinned;
    out.summary.initial_cost = initial_cost;
    return out;
  }
}

std::vector<cv::Point3f> ToCv(const std::vector<Eigen::Vector3d>& v) {
  std::vector<cv::Point3f> out;
  for (const auto& p : v) out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
  return out;
}
std::vector<cv::Point2f> ToCv(const std::vector<Eigen::Vector2d>& v) {
  std::vector<cv::Point2f> out;
  for (const auto& p : v) out.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
  return out;
}

// Pose of the board in the device frame from one view, by PnP with the current intrinsics.
std::optional<Pose6> PoseByPnP(const Intr9& params, const BoardView& v) {
  using M = CameraModel;
  cv::Mat k = (cv::Mat_<double>(3, 3) << params[M::kFx], 0, params[M::kCx], 0, params[M::kFy], params[M::kCy], 0, 0, 1);
  cv::Mat dist = (cv::Mat_<double>(1, 5) << params[M::kK1], params[M::kK2], params[M::kP1], params[M::kP2], params[M::kK3]);
  cv::Mat rvec, tvec;
  std::vector<cv::Point3d> obj;
  std::vector<cv::Point2d> img;
  for (size_t i = 0; i < v.pixels_px.size(); ++i) {
    obj.emplace_back(v.points_in_board_mm[i].x(), v.points_in_board_mm[i].y(), v.points_in_board_mm[i].z());
    img.emplace_back(v.pixels_px[i].x(), v.pixels_px[i].y());
  }
  if (!cv::solvePnP(obj, img, k, dist, rvec, tvec, false, cv::SOLVEPNP_ITERATIVE)) return std::nullopt;
  Pose6 p{rvec.at<double>(0), rvec.at<double>(1), rvec.at<double>(2),
          tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)};
  for (double x : p) {
    if (!std::isfinite(x)) return std::nullopt;
  }
  if (p[5] <= 0) return std::nullopt;
  return p;
}

// Single-device input made of the views of device d (device index remapped to 0).
CalibrationInput DeviceInput(const CalibrationInput& input, int d) {
  CalibrationInput sub;
  sub.devices = {input.devices[d]};
  sub.num_poses = input.num_poses;
  for (const auto& v : input.views) {
    if (v.device != d) continue;
    sub.views.push_back(v);
    sub.views.back().device = 0;
    sub.views.back().DropCarry();
  }
  return sub;
}

// First guess of the view-correlated noise model's kernels from the residuals at `s`: per device,
// the residuals of its points, or for a carried view their own part d = r - J r_source; sigma is
// their RMS per coordinate, and their correlation at 1 and sqrt(2) squares (rho1, rho2) fixes the
// Gaussian: length^2 = 1 / (2 ln(rho1 / rho2)), share = rho1 exp(1 / (2 length^2)), at most 1;
// rho1 <= 0.1 counts as independent errors (share 0). The fit absorbs the smooth part of the
// errors, so residuals are smaller and shorter-correlated than the errors (measured: share 0.66
// over 0.77 squares for a true 0.6 over 1.0); Solve() then fits the kernel to the residual
// moments through the residual-maker matrix I - J (J^T J)^-1 J^T.
std::vector<ViewNoiseKernel> EstimateViewKernels(const CalibrationInput& input, const State& s) {
  const double kSecondLag = std::sqrt(2.0);  // diagonal neighbours
  const size_t nd = input.devices.size();
  std::vector<double> energy(nd, 0), points(nd, 0), p1(nd, 0), n1(nd, 0), p2(nd, 0), n2(nd, 0);
  for (const auto& v : input.views) {
    if (!s.pose_known[v.pose]) continue;
    const BoardView* src = v.IsCarried() ? &input.views[static_cast<size_t>(FindView(input, v.source_device, v.pose))] : nullptr;
    std::vector<Eigen::Vector2d> r;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      r.push_back(ProjectView(s, v, i) - v.pixels_px[i]);
      if (src) {
        const auto j = static_cast<size_t>(v.source_points[i]);
        r.back() -= v.source_jacobians[i] * (ProjectView(s, *src, j) - src->pixels_px[j]);
      }
    }
    const double spacing = GridSpacing(v);
    const auto d = static_cast<size_t>(v.device);
    for (size_t i = 0; i < r.size(); ++i) {
      energy[d] += r[i].squaredNorm();
      points[d] += 1;
      for (size_t j = i + 1; j < r.size(); ++j) {
        const double delta = (v.points_in_board_mm[i] - v.points_in_board_mm[j]).norm() / spacing;
        if (std::abs(delta - 1) < 0.01) {
          p1[d] += r[i].dot(r[j]);
          n1[d] += 1;
        } else if (std::abs(delta - kSecondLag) < 0.01) {
          p2[d] += r[i].dot(r[j]);
          n2[d] += 1;
        }
      }
    }
  }
  std::vector<ViewNoiseKernel> kernels(nd);
  for (size_t d = 0; d < nd; ++d) {
    if (points[d] == 0) continue;
    const double mean_sq = energy[d] / points[d];
    kernels[d].sigma_px = std::sqrt(mean_sq / 2);
    const double rho1 = n1[d] > 0 && mean_sq > 0 ? p1[d] / n1[d] / mean_sq : 0;
    const double rho2 = n2[d] > 0 && mean_sq > 0 ? p2[d] / n2[d] / mean_sq : 0;
    if (!(rho1 > 0.1)) continue;  // treated as independent errors (they give about -0.03)
    const double ratio = std::max(rho1 / std::max(rho2, 0.02 * rho1), 1.05);
    kernels[d].length_squares = std::sqrt((kSecondLag * kSecondLag - 1) / (2 * std::log(ratio)));
    kernels[d].share = std::min(1.0, rho1 * std::exp(1 / (2 * kernels[d].length_squares * kernels[d].length_squares)));
  }
  return kernels;
}

// The joint noise model's weights from the residuals at `s`: each device's corner noise (RMS per
// coordinate of its points) and k, the scale of the carry covariances: for a carried point i and
// its source point, d = r_i - J_i r_source has covariance k C_i alone (the source's error
// cancels), so k = mean(d^T C_i^-1 d) / 2 (medians with a robust loss, below).
double Median(std::vector<double> v);

NoiseModel EstimateNoise(const CalibrationInput& input, const State& s, bool robust) {
  // Per-coordinate variance samples |r|^2 / 2 per device, and d^T C^-1 d / 2 for k: their mean,
  // or with a robust loss their median / ln 2 (exponentially distributed for Gaussian errors), so
  // that outliers do not inflate the weights' scale.
  std::vector<std::vector<double>> var(input.devices.size());
  std::vector<double> k;
  for (const auto& v : input.views) {
    if (!s.pose_known[v.pose]) continue;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) var[v.device].push_back((ProjectView(s, v, i) - v.pixels_px[i]).squaredNorm() / 2);
    if (!v.IsCarried()) continue;
    const BoardView& src = input.views[static_cast<size_t>(FindView(input, v.source_device, v.pose))];
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const auto j = static_cast<size_t>(v.source_points[i]);
      const Eigen::Vector2d d = (ProjectView(s, v, i) - v.pixels_px[i]) -
                                v.source_jacobians[i] * (ProjectView(s, src, j) - src.pixels_px[j]);
      k.push_back(d.dot(v.carry_covariances_px2[i].ldlt().solve(d)) / 2);
    }
  }
  auto scale = [&](const std::vector<double>& x) {
    if (x.empty()) return 1.0;
    return robust ? Median(x) / std::log(2.0) : std::accumulate(x.begin(), x.end(), 0.0) / static_cast<double>(x.size());
  };
  NoiseModel noise;
  for (const auto& x : var) noise.sigma_px.push_back(std::max(std::sqrt(scale(x)), 1e-6));
  noise.carry_scale = std::max(scale(k), 1e-6);
  return noise;
}

// Intrinsics and per-pose dev_from_board of one device alone.
State InitDevice(const CalibrationInput& sub, const CalibrationOptions& options) {
  const CalibrationDevice& dev = sub.devices[0];
  State s;
  s.extent = BoardExtent(sub);
  s.dev_from_rig = {Pose6{0, 0, 0, 0, 0, 0}};
  s.rig_from_board.assign(static_cast<size_t>(sub.num_poses), Pose6{0, 0, 0, 0, 0, 1000});
  s.pose_known.assign(static_cast<size_t>(sub.num_poses), false);
  Intr9 params{};
  if (dev.initial) {
    params = dev.initial->params;
  } else {
    std::vector<std::vector<cv::Point3f>> obj;
    std::vector<std::vector<cv::Point2f>> img;
    for (const auto& v : sub.views) {
      obj.push_back(ToCv(v.points_in_board_mm));
      img.push_back(ToCv(v.pixels_px));
    }
    // OpenCV's aspectRatio is fx / fy; 0 estimates both.
    const double cv_aspect = options.fix_aspect_ratio ? 1.0 / options.aspect_ratio : 0.0;
    cv::Mat k;
    try {
      k = cv::initCameraMatrix2D(obj, img, cv::Size(dev.width, dev.height), cv_aspect);
    } catch (const cv::Exception& e) {
      SLSHADOW_THROW("device '", dev.name, "': cannot initialise the intrinsics from the board homographies (",
                     e.what(), ")");
    }
    params = {k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2), k.at<double>(1, 2), 0, 0, 0, 0, 0};
    SLSHADOW_THROW_IF(!(params[CameraModel::kFx] > 0 && params[CameraModel::kFy] > 0 && std::isfinite(params[CameraModel::kFx]) &&
                        std::isfinite(params[CameraModel::kFy])),
                      "device '", dev.name, "': the board homographies give no valid focal length (fx ", params[CameraModel::kFx],
                      ", fy ", params[CameraModel::kFy], "): the views are degenerate (all parallel to the image plane, or ",
                      "too few); capture the board tilted by 20-40 degrees in several directions");
  }
  if (options.fix_principal_point && !dev.initial) {
    params[CameraModel::kCx] = (dev.width - 1) / 2.0;
    params[CameraModel::kCy] = (dev.height - 1) / 2.0;
  }
  s.intrinsics = {params};
  s.aspect = {options.fix_aspect_ratio ? params[CameraModel::kFy] / params[CameraModel::kFx] : 0.0};
  int posed = 0;
  for (const auto& v : sub.views) {
    const auto pose = PoseByPnP(params, v);
    if (!pose) continue;
    s.rig_from_board[v.pose] = *pose;
    s.pose_known[v.pose] = true;
    ++posed;
  }
  SLSHADOW_THROW_IF(posed == 0, "device '", dev.name, "': no view could be posed (solvePnP failed on all views)");
  return s;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The candidate transform closest (in translation, then rotation) to all others: robust average.
Rigid3d Medoid(const std::vector<Rigid3d>& candidates) {
  SLSHADOW_CHECK(!candidates.empty());
  size_t best = 0;
  double best_cost = 1e300;
  for (size_t i = 0; i < candidates.size(); ++i) {
    double cost = 0;
    for (const auto& c : candidates) {
      cost += (c.translation - candidates[i].translation).norm() +
              1000 * c.rotation.angularDistance(candidates[i].rotation);
    }
    if (cost < best_cost) {
      best_cost = cost;
      best = i;
    }
  }
  return candidates[best];
}

}  // namespace

std::string ToString(LossType loss) {
  switch (loss) {
    case LossType::kNone: return "none";
    case LossType::kHuber: return "huber";
    case LossType::kCauchy: return "cauchy";
  }
  return "?";
}

LossType LossTypeFromString(const std::string& name) {
  if (name == "none") return LossType::kNone;
  if (name == "huber") return LossType::kHuber;
  if (name == "cauchy") return LossType::kCauchy;
  SLSHADOW_THROW("loss: unknown robust loss (got '", name, "'; use none, huber or cauchy)");
}

void CalibrationOptions::Check() const {
  SLSHADOW_THROW_IF(!(aspect_ratio > 0 && std::isfinite(aspect_ratio)), "calibration options: aspect_ratio: must be positive (got ",
                    aspect_ratio, ")");
  SLSHADOW_THROW_IF(!(loss_scale_px > 0), "calibration options: loss_scale_px: must be positive (got ", loss_scale_px, ")");
  SLSHADOW_THROW_IF(max_iterations < 1, "calibration options: max_iterations: must be at least 1 (got ", max_iterations, ")");
  SLSHADOW_THROW_IF(!(outlier_view_factor > 1), "calibration options: outlier_view_factor: must be > 1 (got ",
                    outlier_view_factor, ")");
}

void CalibrationInput::Check() const {
  SLSHADOW_THROW_IF(devices.empty(), "calibration: no devices");
  SLSHADOW_THROW_IF(num_poses < 1, "calibration: no board poses (got num_poses ", num_poses, ")");
  for (const auto& d : devices) {
    SLSHADOW_THROW_IF(d.width <= 0 || d.height <= 0, "calibration: device '", d.name, "': image size must be positive (got ",
                      d.width, "x", d.height, ")");
    if (d.initial) d.initial->Check("calibration: device '" + d.name + "': initial model");
    SLSHADOW_THROW_IF(d.hold_intrinsics && !d.initial, "calibration: device '", d.name,
                      "': hold_intrinsics needs initial intrinsics");
    for (int i : d.held_params) {
      SLSHADOW_THROW_IF(i < 0 || i >= CameraModel::kNumParams, "calibration: device '", d.name,
                        "': held_params: parameter index must be in 0..", CameraModel::kNumParams - 1, " (got ", i, ")");
    }
    SLSHADOW_THROW_IF(d.initial && (d.initial->width != d.width || d.initial->height != d.height), "calibration: device '",
                      d.name, "': initial model is ", d.initial->width, "x", d.initial->height, " but the device is ", d.width,
                      "x", d.height, " (mismatched image sizes)");
  }
  std::vector<int> views_per_device(devices.size(), 0);
  for (const auto& v : views) {
    const std::string what = "calibration: view '" + v.label + "'";
    SLSHADOW_THROW_IF(v.device < 0 || v.device >= static_cast<int>(devices.size()), what, ": device index out of range (got ",
                      v.device, ")");
    SLSHADOW_THROW_IF(v.pose < 0 || v.pose >= num_poses, what, ": pose index out of range (got ", v.pose, ")");
    SLSHADOW_THROW_IF(v.points_in_board_mm.size() != v.pixels_px.size(), what, ": ", v.points_in_board_mm.size(),
                      " board points but ", v.pixels_px.size(), " pixels");
    SLSHADOW_THROW_IF(v.pixels_px.size() < 4, what, ": needs at least 4 points (got ", v.pixels_px.size(), ")");
    const auto& dev = devices[static_cast<size_t>(v.device)];
    for (const auto& px : v.pixels_px) {
      // 2 px of slack: noisy detections at the border.
      SLSHADOW_THROW_IF(!px.allFinite() || px.x() < -2.5 || px.y() < -2.5 || px.x() > dev.width + 1.5 ||
                            px.y() > dev.height + 1.5,
                        what, ": pixel (", px.x(), ", ", px.y(), ") outside the ", dev.width, "x", dev.height,
                        " image of device '", dev.name, "' (mismatched image sizes?)");
    }
    if (v.IsCarried()) {
      SLSHADOW_THROW_IF(v.source_device >= static_cast<int>(devices.size()) || v.source_device == v.device, what,
                        ": source_device must be another device of the input (got ", v.source_device, ")");
      const size_t n = v.pixels_px.size();
      SLSHADOW_THROW_IF(v.source_points.size() != n || v.source_jacobians.size() != n || v.carry_covariances_px2.size() != n,
                        what, ": a carried view needs one source point, Jacobian and carry covariance per point (", n,
                        " points, ", v.source_points.size(), " source points, ", v.source_jacobians.size(), " Jacobians, ",
                        v.carry_covariances_px2.size(), " covariances)");
      const int si = FindView(*this, v.source_device, v.pose);
      SLSHADOW_THROW_IF(si < 0, what, ": carried from device '", devices[static_cast<size_t>(v.source_device)].name,
                        "', which has no view of pose ", v.pose);
      const BoardView& src = views[static_cast<size_t>(si)];
      for (size_t i = 0; i < n; ++i) {
        const int j = v.source_points[i];
        SLSHADOW_THROW_IF(j < 0 || j >= static_cast<int>(src.pixels_px.size()) ||
                              (src.points_in_board_mm[static_cast<size_t>(j)] - v.points_in_board_mm[i]).norm() > 1e-9,
                          what, ": point ", i, ": source point ", j, " is not the same board point in view '", src.label, "'");
        const Eigen::Matrix2d& c = v.carry_covariances_px2[i];
        SLSHADOW_THROW_IF(!v.source_jacobians[i].allFinite() || !c.allFinite() || std::abs(c(0, 1) - c(1, 0)) > 1e-9 * c.norm() ||
                              Eigen::LLT<Eigen::Matrix2d>(c).info() != Eigen::Success,
                          what, ": point ", i, ": the source Jacobian must be finite and the carry covariance symmetric "
                          "positive definite");
      }
    }
    // Collinear (or coincident) board points give no pose.
    Eigen::MatrixXd centred(3, static_cast<Eigen::Index>(v.points_in_board_mm.size()));
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : v.points_in_board_mm) mean += p;
    mean /= static_cast<double>(v.points_in_board_mm.size());
    for (size_t i = 0; i < v.points_in_board_mm.size(); ++i) centred.col(static_cast<Eigen::Index>(i)) = v.points_in_board_mm[i] - mean;
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(centred);
    const auto sv = svd.singularValues();
    SLSHADOW_THROW_IF(!(sv(1) > 1e-6 * sv(0)) || !(sv(0) > 0), what,
                      ": the board points are collinear; a view needs points spanning the board in 2D");
    ++views_per_device[static_cast<size_t>(v.device)];
  }
  for (size_t d = 0; d < devices.size(); ++d) {
    if (devices[d].initial) {
      SLSHADOW_THROW_IF(views_per_device[d] < 1, "calibration: device '", devices[d].name, "': no views");
    } else {
      SLSHADOW_THROW_IF(views_per_device[d] < 2, "calibration: device '", devices[d].name, "': ", views_per_device[d],
                        " view(s); calibrating intrinsics needs at least 2 (better 10-20) views of the board in "
                        "different orientations");
    }
  }
}

CalibrationResult Calibrate(const CalibrationInput& input, const CalibrationOptions& options) {
  options.Check();
  input.Check();
  const auto t0 = std::chrono::steady_clock::now();
  const int num_devices = static_cast<int>(input.devices.size());
  int iterations = 0;

  // Per device: intrinsics and dev_from_board per pose.
  std::vector<State> per_device;
  for (int d = 0; d < num_devices; ++d) {
    const CalibrationInput sub = DeviceInput(input, d);
    // Two starts, the lower final cost kept: the full model straight from the homography
    // initialisation (OpenCV's way), and pinhole first (distortion held at its start, zero unless
    // given) then the full model. With few poses either can fall into a far minimum: measured,
    // the kamino projector with one pose held out went to k1 -1.5, cy 256 px from the first
    // start, and the ChArUco tutorial camera to fx +36 % from the second.
    State s = InitDevice(sub, options);
    SolveOutput direct = Solve(sub, options, &s, false);
    iterations += static_cast<int>(direct.summary.iterations.size());
    State t = InitDevice(sub, options);
    CalibrationInput pinhole = sub;
    for (int i : {CameraModel::kK1, CameraModel::kK2, CameraModel::kP1, CameraModel::kP2, CameraModel::kK3}) {
      pinhole.devices[0].held_params.push_back(i);
    }
    iterations += static_cast<int>(Solve(pinhole, options, &t, false).summary.iterations.size());
    const SolveOutput staged = Solve(sub, options, &t, false);
    iterations += static_cast<int>(staged.summary.iterations.size());
    if (staged.summary.final_cost < direct.summary.final_cost) s = std::move(t);
    per_device.push_back(std::move(s));
  }

  // Chain devices to device 0 through shared poses.
  State s;
  s.intrinsics.resize(static_cast<size_t>(num_devices));
  s.aspect.resize(static_cast<size_t>(num_devices));
  s.dev_from_rig.assign(static_cast<size_t>(num_devices), Pose6{0, 0, 0, 0, 0, 0});
  s.rig_from_board.assign(static_cast<size_t>(input.num_poses), Pose6{0, 0, 0, 0, 0, 1000});
  s.pose_known.assign(static_cast<size_t>(input.num_poses), false);
  s.extent = BoardExtent(input);
  s.warp = per_device[0].warp;
  for (int d = 0; d < num_devices; ++d) {
    s.intrinsics[d] = per_device[d].intrinsics[0];
    s.aspect[d] = per_device[d].aspect[0];
  }
  std::vector<bool> placed(static_cast<size_t>(num_devices), false);
  placed[0] = true;
  s.rig_from_board = per_device[0].rig_from_board;
  s.pose_known = per_device[0].pose_known;
  for (bool progress = true; progress;) {
    progress = false;
    for (int d = 1; d < num_devices; ++d) {
      if (placed[d]) continue;
      std::vector<Rigid3d> candidates;
      for (int p = 0; p < input.num_poses; ++p) {
        if (s.pose_known[p] && per_device[d].pose_known[p]) {
          candidates.push_back(FromPose6(per_device[d].rig_from_board[p]) * FromPose6(s.rig_from_board[p]).Inverse());
        }
      }
      if (candidates.empty()) continue;
      const Rigid3d dev_from_rig = Medoid(candidates);
      s.dev_from_rig[d] = ToPose6(dev_from_rig);
      for (int p = 0; p < input.num_poses; ++p) {
        if (!s.pose_known[p] && per_device[d].pose_known[p]) {
          s.rig_from_board[p] = ToPose6(dev_from_rig.Inverse() * FromPose6(per_device[d].rig_from_board[p]));
          s.pose_known[p] = true;
        }
      }
      placed[d] = true;
      progress = true;
    }
  }
  for (int d = 1; d < num_devices; ++d) {
    SLSHADOW_THROW_IF(!placed[d], "calibration: device '", input.devices[d].name, "' shares no board pose with device '",
                      input.devices[0].name, "' (directly or through other devices): its pose in the rig is unknown; "
                      "capture poses where both see the board");
  }

  // Final joint solve. With carried views and correlated_carried_noise: solve with independent
  // weights, estimate the noise model from its residuals, solve whitened, re-estimate once, and
  // solve whitened again (with the covariance).
  bool joint = false;
  for (const auto& v : input.views) joint = joint || (options.correlated_carried_noise && v.IsCarried());
  SolveOutput final_solve = Solve(input, options, &s, options.compute_covariance && !joint);
  iterations += static_cast<int>(final_solve.summary.iterations.size());
  NoiseModel noise;
  for (int round = 0; joint && round < 2; ++round) {
    noise = EstimateNoise(input, s, options.loss != LossType::kNone);
    final_solve = Solve(input, options, &s, options.compute_covariance && round == 1, &noise);
    iterations += static_cast<int>(final_solve.summary.iterations.size());
  }
  // The view-correlated covariance at the solution (no iterations).
  std::vector<ViewNoiseKernel> kernels;
  std::vector<Matrix9d> correlated_covariance;
  if (options.compute_covariance && !joint && !options.fix_intrinsics) {
    kernels = EstimateViewKernels(input, s);
    CalibrationOptions evaluate_only = options;
    evaluate_only.max_iterations = 0;
    correlated_covariance = Solve(input, evaluate_only, &s, true, nullptr, &kernels).correlated_covariance;
  }

  CalibrationResult result;
  result.board_warp_mm = Eigen::Vector2d(s.warp[0], s.warp[1]);
  result.board_extent_mm = s.extent;
  for (int d = 0; d < num_devices; ++d) {
    RigDevice dev;
    dev.name = input.devices[d].name;
    dev.model.width = input.devices[d].width;
    dev.model.height = input.devices[d].height;
    dev.model.params = EffectiveParams(s, d);
    dev.cam_from_rig = FromPose6(s.dev_from_rig[d]);
    result.devices.push_back(dev);
  }
  for (int p = 0; p < input.num_poses; ++p) {
    if (s.pose_known[p]) {
      result.rig_from_board.emplace_back(FromPose6(s.rig_from_board[p]));
    } else {
      result.rig_from_board.emplace_back(std::nullopt);
    }
  }

  // Statistics.
  CalibrationSummary& sum = result.summary;
  sum.initial_cost = final_solve.summary.initial_cost;
  sum.final_cost = final_solve.summary.final_cost;
  sum.iterations = iterations;
  sum.converged = final_solve.summary.termination_type == ceres::CONVERGENCE;
  sum.termination = ceres::TerminationTypeToString(final_solve.summary.termination_type) + std::string(": ") +
                    final_solve.summary.message;
  sum.num_free_parameters = final_solve.num_free_parameters;
  sum.devices.resize(static_cast<size_t>(num_devices));
  std::vector<double> dev_sq(static_cast<size_t>(num_devices), 0);
  double total_sq = 0;
  for (int d = 0; d < num_devices; ++d) sum.devices[d].name = input.devices[d].name;
  for (const auto& v : input.views) {
    ViewStats vs;
    vs.device = v.device;
    vs.pose = v.pose;
    vs.label = v.label;
    if (!s.pose_known[v.pose]) {
      vs.rms_px = std::nan("");
      vs.max_px = std::nan("");
      sum.views.push_back(vs);
      continue;
    }
    double sq = 0;
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const double e = (ProjectView(s, v, i) - v.pixels_px[i]).norm();
      sq += e * e;
      vs.max_px = std::max(vs.max_px, e);
    }
    vs.num_points = static_cast<int>(v.pixels_px.size());
    vs.rms_px = std::sqrt(sq / vs.num_points);
    auto& ds = sum.devices[v.device];
    ds.num_views++;
    ds.num_points += vs.num_points;
    ds.max_px = std::max(ds.max_px, vs.max_px);
    dev_sq[v.device] += sq;
    total_sq += sq;
    sum.num_points += vs.num_points;
    sum.max_px = std::max(sum.max_px, vs.max_px);
    sum.views.push_back(vs);
  }
  for (int d = 0; d < num_devices; ++d) {
    auto& ds = sum.devices[d];
    ds.rms_px = ds.num_points ? std::sqrt(dev_sq[d] / ds.num_points) : 0;
    std::vector<double> rms;
    for (const auto& vs : sum.views) {
      if (vs.device == d && vs.num_points) rms.push_back(vs.rms_px);
    }
    const double median = Median(rms);
    for (auto& vs : sum.views) {
      if (vs.device == d && vs.num_points && vs.rms_px > options.outlier_view_factor * median) {
        vs.outlier = true;
        ++sum.num_outlier_views;
      }
    }
  }
  sum.rms_px = sum.num_points ? std::sqrt(total_sq / sum.num_points) : 0;
  const int dof = 2 * sum.num_points - sum.num_free_parameters;
  sum.residual_sigma_px = dof > 0 ? std::sqrt(total_sq / dof) : std::nan("");
  if (joint) {
    sum.joint_noise = true;
    sum.noise_sigma_px = noise.sigma_px;
    sum.carry_scale = noise.carry_scale;
    sum.variance_factor = dof > 0 ? 2 * final_solve.summary.final_cost / dof : std::nan("");
  }
  for (const auto& k : kernels) sum.view_noise.push_back({k.sigma_px, k.share, k.length_squares});
  for (int d = 0; options.principal_point_inside && d < num_devices; ++d) {
    const CalibrationDevice& dev = input.devices[static_cast<size_t>(d)];
    for (int i : {CameraModel::kCx, CameraModel::kCy}) {
      const double v = s.intrinsics[d][i], upper = (i == CameraModel::kCx ? dev.width : dev.height) - 0.5;
      if (std::abs(v - upper) > 1e-6 && std::abs(v + 0.5) > 1e-6) continue;
      char line[160];
      std::snprintf(line, sizeof(line), "%s %s = %.1f (%s bound)", dev.name.c_str(), i == CameraModel::kCx ? "cx" : "cy", v,
                    v > 0 ? "upper" : "lower");
      sum.bounds_active.push_back(line);
    }
  }
  result.intrinsics_covariance_view_correlated = correlated_covariance;
  if (!final_solve.covariance.empty() && dof > 0) {
    const double var = joint ? sum.variance_factor : sum.residual_sigma_px * sum.residual_sigma_px;
    for (const auto& c : final_solve.covariance) result.intrinsics_covariance.push_back(c * var);
  }
  sum.solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

void BoardView::DropCarry() {
  source_device = -1;
  source_points.clear();
  source_jacobians.clear();
  carry_covariances_px2.clear();
}

std::vector<Eigen::Vector2d> Reproject(const CalibrationResult& result, const BoardView& view) {
  SLSHADOW_THROW_IF(view.device < 0 || view.device >= static_cast<int>(result.devices.size()) || view.pose < 0 ||
                        view.pose >= static_cast<int>(result.rig_from_board.size()) || !result.rig_from_board[view.pose],
                    "Reproject: view '", view.label, "' has no device or estimated pose in this result");
  const RigDevice& dev = result.devices[view.device];
  const Pose6 dev_from_rig = ToPose6(dev.cam_from_rig);
  const Pose6 rig_from_board = ToPose6(*result.rig_from_board[view.pose]);
  const double warp[2] = {result.board_warp_mm.x(), result.board_warp_mm.y()};
  std::vector<Eigen::Vector2d> out;
  for (const auto& x : view.points_in_board_mm) {
    const ReprojectionFunctor f(x, Eigen::Vector2d::Zero(), 0.0, result.board_extent_mm);
    Eigen::Vector2d px;
    f(dev.model.params.data(), dev_from_rig.data(), rig_from_board.data(), warp, px.data());
    out.push_back(px);
  }
  return out;
}

std::string CalibrationSummary::BriefReport() const {
  std::ostringstream out;
  out.precision(4);
  out << "calibration: " << devices.size() << " device(s), " << views.size() << " views, " << num_points
      << " points: RMS " << rms_px << " px (worst " << max_px << " px), " << num_outlier_views
      << " outlier view(s); cost " << initial_cost << " -> " << final_cost << ", " << iterations << " iterations, "
      << (converged ? "converged" : "NOT converged") << ", " << solve_time_s << " s";
  return out.str();
}

std::string CalibrationSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n";
  char line[512];
  std::snprintf(line, sizeof(line), "termination: %s\nfree parameters: %d, residual sigma %.4f px per coordinate\n",
                termination.c_str(), num_free_parameters, residual_sigma_px);
  out << line;
  if (joint_noise) {
    out << "noise model: carried points whitened with their source points; corner noise per device (px):";
    for (size_t d = 0; d < noise_sigma_px.size(); ++d) {
      std::snprintf(line, sizeof(line), " %s %.4f", devices[d].name.c_str(), noise_sigma_px[d]);
      out << line;
    }
    std::snprintf(line, sizeof(line), "; carry scale %.4g; chi2/dof %.4f\n", carry_scale, variance_factor);
    out << line;
  }
  if (!view_noise.empty()) {
    out << "corner errors within a view (sigma px, correlated share, length in squares):";
    for (size_t d = 0; d < view_noise.size() && d < devices.size(); ++d) {
      std::snprintf(line, sizeof(line), " %s %.4f %.2f %.2f", devices[d].name.c_str(), view_noise[d].sigma_px,
                    view_noise[d].share, view_noise[d].length_squares);
      out << line;
    }
    out << "\n";
  }
  for (const auto& b : bounds_active) out << "principal point on its bound (the data pull it outside the image): " << b << "\n";
  out << "device           views  points  RMS px   worst px\n";
  for (const auto& d : devices) {
    std::snprintf(line, sizeof(line), "%-16s %5d %7d %8.4f %9.4f\n", d.name.c_str(), d.num_views, d.num_points,
                  d.rms_px, d.max_px);
    out << line;
  }
  out << "view                             device pose points  RMS px   worst px\n";
  for (const auto& v : views) {
    std::snprintf(line, sizeof(line), "%-32s %6d %4d %6d %8.4f %9.4f%s\n", v.label.c_str(), v.device, v.pose,
                  v.num_points, v.rms_px, v.max_px, v.outlier ? "  OUTLIER" : (v.num_points ? "" : "  (not posed)"));
    out << line;
  }
  return out.str();
}

}  // namespace slshadow
