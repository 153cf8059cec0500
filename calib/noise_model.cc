#include "calib/internal/noise_model.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "calib/internal/initialization.h"
#include "core/error.h"
#include "core/statistics.h"
#include "core/threads.h"

namespace slshadow::calib::internal {

// Covariance (px^2, 2x2) of the errors of point ia of view va and point ib of view vb of the same
// pose under the view-correlated noise model (CalibrationResult::correlated_covariance): each
// point's error is M e(X) + h(X), e the error field of its source device (the device itself, or
// the device its pixels were carried from, M = J then, else I) and h the carried device's own
// field; each field is Gaussian-correlated across the board, independent between devices.
Eigen::Matrix2d PointPairCovariance(const std::vector<ViewNoiseKernel>& kernels,
                                    const BoardView& va, size_t ia, const BoardView& vb, size_t ib,
                                    double spacing_mm) {
  const double delta = (va.points_in_board_mm[ia] - vb.points_in_board_mm[ib]).norm() / spacing_mm;
  auto rho = [&](const ViewNoiseKernel& k) {
    const double r =
        delta < 1e-9
            ? 1.0
            : k.share * std::exp(-delta * delta / (2 * k.length_squares * k.length_squares));
    return k.sigma_px * k.sigma_px * r;
  };
  const int sa = va.IsCarried() ? va.source_device : va.device,
            sb = vb.IsCarried() ? vb.source_device : vb.device;
  const Eigen::Matrix2d ma = va.IsCarried() ? va.source_jacobians[ia] : Eigen::Matrix2d::Identity();
  const Eigen::Matrix2d mb = vb.IsCarried() ? vb.source_jacobians[ib] : Eigen::Matrix2d::Identity();
  Eigen::Matrix2d c = Eigen::Matrix2d::Zero();
  if (sa == sb) c += rho(kernels[static_cast<size_t>(sa)]) * ma * mb.transpose();
  if (va.IsCarried() && vb.IsCarried() && va.device == vb.device &&
      va.source_device == vb.source_device) {
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
Eigen::MatrixXd ViewCorrelatedCovariance(const CalibrationInput& input,
                                         const std::vector<std::pair<int, int>>& block_points,
                                         const std::vector<double>& residuals,
                                         const ceres::CRSMatrix& crs, const Eigen::MatrixXd& inv,
                                         int cols, std::vector<ViewNoiseKernel>* kernels) {
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
    std::vector<std::array<int, 3>>
        pairs;  // unit a, unit b, lag 0 (a = b), 1 or 2 (sqrt 2 squares)
    Eigen::MatrixXd th,
        tj;  // T H and T J, T the units' linear map (row pair u: sum of c * rows of block)
  };
  auto apply_units = [](const PoseRows& p, const Eigen::MatrixXd& m) {  // T m
    Eigen::MatrixXd out =
        Eigen::MatrixXd::Zero(2 * static_cast<Eigen::Index>(p.units.size()), m.cols());
    for (size_t u = 0; u < p.units.size(); ++u) {
      for (const auto& [k, c] : p.units[u].terms)
        out.middleRows(2 * static_cast<Eigen::Index>(u), 2).noalias() += c * m.middleRows(2 * k, 2);
    }
    return out;
  };
  std::vector<PoseRows> poses(static_cast<size_t>(input.num_poses));
  for (size_t k = 0; k < block_points.size(); ++k) {
    poses[static_cast<size_t>(input.views[static_cast<size_t>(block_points[k].first)].pose)]
        .blocks.push_back(static_cast<int>(k));
  }
  std::erase_if(poses, [](const PoseRows& p) { return p.blocks.empty(); });
  std::vector<double> view_spacing(input.views.size(), -1);  // GridSpacing per view, computed once
  for (auto& p : poses) {
    const auto m = static_cast<Eigen::Index>(2 * p.blocks.size());
    std::vector<Eigen::Index> compact(static_cast<size_t>(cols), -1);  // column -> column of p.j
    for (int b : p.blocks) {
      for (int row = 2 * b; row < 2 * b + 2; ++row) {
        for (int e = crs.rows[row]; e < crs.rows[row + 1]; ++e) {
          if (compact[static_cast<size_t>(crs.cols[e])] < 0)
            compact[static_cast<size_t>(crs.cols[e])] = 0;
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
          p.j(static_cast<Eigen::Index>(2 * a) + r, compact[static_cast<size_t>(crs.cols[e])]) =
              crs.values[e];
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
        const auto it = local.find(
            {FindView(input, v.source_device, v.pose), v.source_points[static_cast<size_t>(ia)]});
        if (it != local.end())
          u.terms.emplace_back(it->second, -v.source_jacobians[static_cast<size_t>(ia)]);
      }
      view_units[va].push_back(static_cast<int>(p.units.size()));
      p.units.push_back(std::move(u));
    }
    for (const auto& [va, us] : view_units) {
      for (size_t a = 0; a < us.size(); ++a) {
        const auto ia = static_cast<size_t>(
            block_points[static_cast<size_t>(p.blocks[static_cast<size_t>(us[a])])].second);
        for (size_t b = a; b < us.size(); ++b) {
          const auto ib = static_cast<size_t>(
              block_points[static_cast<size_t>(p.blocks[static_cast<size_t>(us[b])])].second);
          const auto& x = input.views[static_cast<size_t>(va)].points_in_board_mm;
          const double delta = (x[ia] - x[ib]).norm() / p.spacing;
          const int lag = a == b                                    ? 0
                          : std::abs(delta - 1) < 0.01              ? 1
                          : std::abs(delta - std::sqrt(2.0)) < 0.01 ? 2
                                                                    : -1;
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
        const Eigen::Matrix2d c = PointPairCovariance(k, v, static_cast<size_t>(ia), w,
                                                      static_cast<size_t>(ib), p.spacing);
        const auto ra = static_cast<Eigen::Index>(2 * a), rb = static_cast<Eigen::Index>(2 * b);
        sigma.block<2, 2>(ra, rb) = c;
        sigma.block<2, 2>(rb, ra) = c.transpose();
      }
    }
    return sigma;
  };
  auto meat_of = [&](const std::vector<Eigen::MatrixXd>& sigmas) {
    Eigen::MatrixXd meat = Eigen::MatrixXd::Zero(cols, cols);
    for (size_t i = 0; i < poses.size(); ++i)
      meat(poses[i].cols, poses[i].cols) += poses[i].j.transpose() * sigmas[i] * poses[i].j;
    return meat;
  };
  // Sum over each device's unit pairs of u_a . u_b by lag, for a covariance C of the
  // residuals (entry(a, b): the 2x2 block of C between blocks a and b).
  const size_t nd = input.devices.size();
  auto pair_sums = [&](const PoseRows& p, const auto& entry, std::vector<double>* sums) {
    for (const auto& [ua, ub, lag] : p.pairs) {
      double v = 0;
      for (const auto& [ka, ca] : p.units[static_cast<size_t>(ua)].terms) {
        for (const auto& [kb, cb] : p.units[static_cast<size_t>(ub)].terms)
          v += (ca * entry(ka, kb) * cb.transpose()).trace();
      }
      (*sums)[3 * static_cast<size_t>(p.units[static_cast<size_t>(ua)].device) +
              static_cast<size_t>(lag)] += v;
    }
  };
  // Expected sums when the errors have covariance `k`: residuals r = (I - H) e, so
  // E[r r^T]_pp = S_p - H_pp S_p - S_p H_pp + J_p (J^T J)^-1 (sum_q J_q^T S_q J_q) (J^T J)^-1
  // J_p^T. A unit pair's sum is trace(T_a E T_b^T), T the units' map: with S, H and K symmetric,
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
        for (const auto& [kb, cb] : p.units[static_cast<size_t>(ub)].terms)
          v += (ts.block<2, 2>(a, 2 * kb) * cb.transpose()).trace();
        v -= p.th.middleRows(a, 2).cwiseProduct(ts.middleRows(b, 2)).sum();
        v -= ts.middleRows(a, 2).cwiseProduct(p.th.middleRows(b, 2)).sum();
        v += tjk.middleRows(a, 2).cwiseProduct(p.tj.middleRows(b, 2)).sum();
        sums[3 * static_cast<size_t>(p.units[static_cast<size_t>(ua)].device) +
             static_cast<size_t>(lag)] += v;
      }
    }
    return sums;
  };
  std::vector<double> observed(3 * nd, 0);
  for (const auto& p : poses) {
    pair_sums(
        p,
        [&](Eigen::Index a, Eigen::Index b) {
          return Eigen::Matrix2d(p.r.segment<2>(2 * a) * p.r.segment<2>(2 * b).transpose());
        },
        &observed);
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
      if (std::abs(grid[g] - (*kernels)[f].length_squares) <
          std::abs(grid[at[f]] - (*kernels)[f].length_squares))
        at[f] = g;
    }
  }
  auto fit = [&](const std::vector<size_t>& g, Eigen::VectorXd* x) {
    Eigen::MatrixXd a(3 * nd, 2 * nd);
    Eigen::VectorXd b(3 * nd);
    for (size_t i = 0; i < 3 * nd; ++i) {
      const double w =
          observed[3 * (i / 3)] > 0 ? 1 / observed[3 * (i / 3)] : 0;  // per device, by its energy
      b(static_cast<Eigen::Index>(i)) = w * observed[i];
      for (size_t f = 0; f < nd; ++f) {
        a(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(2 * f)) = w * nugget[f][i];
        a(static_cast<Eigen::Index>(i), static_cast<Eigen::Index>(2 * f + 1)) =
            w * correlated_of(f, g[f])[i];
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
    const double var = x(static_cast<Eigen::Index>(2 * f)),
                 cov = x(static_cast<Eigen::Index>(2 * f + 1));
    if (!(var > 0) || observed[3 * f] <= 0) continue;  // keep the residual-based estimate
    (*kernels)[f] = {std::sqrt(var), std::clamp(cov / var, 0.0, 1.0), grid[at[f]]};
  }
  std::vector<Eigen::MatrixXd> sigmas;
  for (const auto& p : poses) sigmas.push_back(sigma_of(*kernels, p));
  return inv * meat_of(sigmas) * inv;
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
    const BoardView* src =
        v.IsCarried() ? &input.views[static_cast<size_t>(FindView(input, v.source_device, v.pose))]
                      : nullptr;
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
    kernels[d].share = std::min(
        1.0, rho1 * std::exp(1 / (2 * kernels[d].length_squares * kernels[d].length_squares)));
  }
  return kernels;
}

NoiseModel EstimateNoise(const CalibrationInput& input, const State& s, bool robust) {
  // Per-coordinate variance samples |r|^2 / 2 per device, and d^T C^-1 d / 2 for k: their mean,
  // or with a robust loss their median / ln 2 (exponentially distributed for Gaussian errors), so
  // that outliers do not inflate the weights' scale.
  std::vector<std::vector<double>> var(input.devices.size());
  std::vector<double> k;
  for (const auto& v : input.views) {
    if (!s.pose_known[v.pose]) continue;
    for (size_t i = 0; i < v.pixels_px.size(); ++i)
      var[v.device].push_back((ProjectView(s, v, i) - v.pixels_px[i]).squaredNorm() / 2);
    if (!v.IsCarried()) continue;
    const BoardView& src =
        input.views[static_cast<size_t>(FindView(input, v.source_device, v.pose))];
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const auto j = static_cast<size_t>(v.source_points[i]);
      const Eigen::Vector2d d = (ProjectView(s, v, i) - v.pixels_px[i]) -
                                v.source_jacobians[i] * (ProjectView(s, src, j) - src.pixels_px[j]);
      k.push_back(d.dot(v.carry_covariances_px2[i].ldlt().solve(d)) / 2);
    }
  }
  auto scale = [&](const std::vector<double>& x) {
    if (x.empty()) return 1.0;
    return robust ? Median(std::vector<double>(x)) / std::log(2.0)
                  : std::accumulate(x.begin(), x.end(), 0.0) / static_cast<double>(x.size());
  };
  NoiseModel noise;
  for (const auto& x : var) noise.sigma_px.push_back(std::max(std::sqrt(scale(x)), 1e-6));
  noise.carry_scale = std::max(scale(k), 1e-6);
  return noise;
}

}  // namespace slshadow::calib::internal
