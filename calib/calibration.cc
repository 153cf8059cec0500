#include "calib/calibration.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <numeric>
#include <sstream>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>

#include "calib/internal/calibration_problem.h"
#include "calib/internal/initialization.h"
#include "calib/internal/noise_model.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/statistics.h"
#include "core/threads.h"

namespace slshadow {
namespace {

using namespace calib::internal;  // NOLINT: calib's own internal helpers

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
SolveOutput SolveOnce(const CalibrationInput& input, const CalibrationOptions& options, State* s,
                      bool want_covariance, const NoiseModel* noise,
                      std::vector<ViewNoiseKernel>* kernels,
                      std::vector<std::vector<int>>* pinned) {
  auto held_of = [&](size_t d) {
    std::vector<int> held = HeldIntrinsics(options, input.devices[d], s->aspect[d]);
    held.insert(held.end(), (*pinned)[d].begin(), (*pinned)[d].end());
    std::sort(held.begin(), held.end());
    held.erase(std::unique(held.begin(), held.end()), held.end());
    return held;
  };
  ceres::Problem problem;
  std::vector<bool> device_used(input.devices.size(), false),
      pose_used(static_cast<size_t>(input.num_poses), false);
  // Points in a joint pair, per view (not added again alone).
  std::vector<std::vector<bool>> paired(input.views.size());
  // Single-point residual blocks in order, and their (view, point).
  std::vector<ceres::ResidualBlockId> block_ids;
  std::vector<std::pair<int, int>> block_points;
  for (size_t vi = 0; noise && vi < input.views.size(); ++vi) {
    const BoardView& v = input.views[vi];
    if (!v.IsCarried() || !s->pose_known[v.pose]) continue;
    const auto si =
        static_cast<size_t>(FindView(input, v.source_device, v.pose));  // exists (input.Check())
    const BoardView& src = input.views[si];
    paired[vi].resize(v.pixels_px.size(), false);
    paired[si].resize(src.pixels_px.size(), false);
    const double sigma = noise->sigma_px[src.device];
    for (size_t i = 0; i < v.pixels_px.size(); ++i) {
      const auto j = static_cast<size_t>(v.source_points[i]);
      if (paired[si][j]) continue;  // a source point pairs once
      const auto w = PairWhitening(sigma, v.source_jacobians[i],
                                   noise->carry_scale * v.carry_covariances_px2[i]);
      if (!w) continue;
      auto* cost = new ceres::AutoDiffCostFunction<CarriedPairFunctor, 4, CameraModel::kNumParams,
                                                   6, CameraModel::kNumParams, 6, 6, 2>(
          new CarriedPairFunctor{ReprojectionFunctor(src.points_in_board_mm[j], src.pixels_px[j],
                                                     s->aspect[src.device], s->extent),
                                 ReprojectionFunctor(v.points_in_board_mm[i], v.pixels_px[i],
                                                     s->aspect[v.device], s->extent),
                                 *w});
      problem.AddResidualBlock(cost, MakeLoss(options, options.loss_scale_px / sigma),
                               s->intrinsics[src.device].data(), s->dev_from_rig[src.device].data(),
                               s->intrinsics[v.device].data(), s->dev_from_rig[v.device].data(),
                               s->rig_from_board[v.pose].data(), s->warp.data());
      paired[vi][i] = paired[si][j] = true;
    }
  }
  for (size_t vi = 0; vi < input.views.size(); ++vi) {
    const BoardView& v = input.views[vi];
    if (!s->pose_known[v.pose]) continue;
    const double weight = noise ? 1 / noise->sigma_px[v.device] : 1.0;
    for (size_t i = 0; i < v.points_in_board_mm.size(); ++i) {
      if (!paired[vi].empty() && paired[vi][i]) continue;
      auto* f = new ReprojectionFunctor(v.points_in_board_mm[i], v.pixels_px[i],
                                        s->aspect[v.device], s->extent);
      f->weight = weight;
      auto* cost =
          new ceres::AutoDiffCostFunction<ReprojectionFunctor, 2, CameraModel::kNumParams, 6, 6, 2>(
              f);
      // The loss is owned by the problem, one per residual.
      block_points.emplace_back(static_cast<int>(vi), static_cast<int>(i));
      block_ids.push_back(problem.AddResidualBlock(
          cost, MakeLoss(options, options.loss_scale_px * weight), s->intrinsics[v.device].data(),
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
      if (!held.empty())
        problem.SetManifold(intr, new ceres::SubsetManifold(CameraModel::kNumParams, held));
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
  const bool estimate_warp =
      options.estimate_board_warp && problem.HasParameterBlock(s->warp.data());
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
      const double upper =
          (i == CameraModel::kCx ? input.devices[d].width : input.devices[d].height) - 0.5;
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
          for (int b = crs.rows[r]; b < crs.rows[r + 1]; ++b)
            jtj(crs.cols[a], crs.cols[b]) += crs.values[a] * crs.values[b];
        }
      }
      const Eigen::VectorXd scale = jtj.diagonal().cwiseMax(1e-300).cwiseSqrt().cwiseInverse();
      const Eigen::MatrixXd scaled = scale.asDiagonal() * jtj * scale.asDiagonal();
      const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(scaled);
      const double max_ev = es.eigenvalues().maxCoeff();
      if (es.info() == Eigen::Success && es.eigenvalues().minCoeff() > 1e-12 * max_ev) {
        const Eigen::MatrixXd inv =
            scale.asDiagonal() *
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
              c(free[a], free[b]) =
                  full(intr_column[d] + static_cast<int>(a), intr_column[d] + static_cast<int>(b));
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
          for (size_t d = 0; d < input.devices.size(); ++d)
            out.correlated_covariance.push_back(lift(sandwich_cov, d));
        }
      }
    }
  }
  return out;
}

// SolveOnce until no principal-point coordinate leaves its image (at most once per coordinate).
SolveOutput Solve(const CalibrationInput& input, const CalibrationOptions& options, State* s,
                  bool want_covariance, const NoiseModel* noise = nullptr,
                  std::vector<ViewNoiseKernel>* kernels = nullptr) {
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

}  // namespace

constexpr EnumName<LossType> kLossTypeNames[] = {
    {LossType::kNone, "none"}, {LossType::kHuber, "huber"}, {LossType::kCauchy, "cauchy"}};

std::string ToString(LossType value) { return EnumToString(value, kLossTypeNames); }

LossType LossTypeFromString(const std::string& name) {
  return EnumFromString("loss", name, kLossTypeNames);
}

void CalibrationOptions::Check() const {
  SLSHADOW_THROW_IF(!(aspect_ratio > 0 && std::isfinite(aspect_ratio)),
                    "calibration options: aspect_ratio: must be positive (got ", aspect_ratio, ")");
  SLSHADOW_THROW_IF(!(loss_scale_px > 0),
                    "calibration options: loss_scale_px: must be positive (got ", loss_scale_px,
                    ")");
  SLSHADOW_THROW_IF(max_iterations < 1,
                    "calibration options: max_iterations: must be at least 1 (got ", max_iterations,
                    ")");
  SLSHADOW_THROW_IF(!(outlier_view_factor > 1),
                    "calibration options: outlier_view_factor: must be > 1 (got ",
                    outlier_view_factor, ")");
}

void CalibrationInput::Check() const {
  SLSHADOW_THROW_IF(devices.empty(), "calibration: no devices");
  SLSHADOW_THROW_IF(num_poses < 1, "calibration: no board poses (got num_poses ", num_poses, ")");
  for (const auto& d : devices) {
    SLSHADOW_THROW_IF(d.width <= 0 || d.height <= 0, "calibration: device '", d.name,
                      "': image size must be positive (got ", d.width, "x", d.height, ")");
    if (d.initial) d.initial->Check("calibration: device '" + d.name + "': initial model");
    SLSHADOW_THROW_IF(d.hold_intrinsics && !d.initial, "calibration: device '", d.name,
                      "': hold_intrinsics needs initial intrinsics");
    for (int i : d.held_params) {
      SLSHADOW_THROW_IF(i < 0 || i >= CameraModel::kNumParams, "calibration: device '", d.name,
                        "': held_params: parameter index must be in 0..",
                        CameraModel::kNumParams - 1, " (got ", i, ")");
    }
    SLSHADOW_THROW_IF(d.initial && (d.initial->width != d.width || d.initial->height != d.height),
                      "calibration: device '", d.name, "': initial model is ", d.initial->width,
                      "x", d.initial->height, " but the device is ", d.width, "x", d.height,
                      " (mismatched image sizes)");
  }
  std::vector<int> views_per_device(devices.size(), 0);
  for (const auto& v : views) {
    const std::string what = "calibration: view '" + v.label + "'";
    SLSHADOW_THROW_IF(v.device < 0 || v.device >= static_cast<int>(devices.size()), what,
                      ": device index out of range (got ", v.device, ")");
    SLSHADOW_THROW_IF(v.pose < 0 || v.pose >= num_poses, what, ": pose index out of range (got ",
                      v.pose, ")");
    SLSHADOW_THROW_IF(v.points_in_board_mm.size() != v.pixels_px.size(), what, ": ",
                      v.points_in_board_mm.size(), " board points but ", v.pixels_px.size(),
                      " pixels");
    SLSHADOW_THROW_IF(v.pixels_px.size() < 4, what, ": needs at least 4 points (got ",
                      v.pixels_px.size(), ")");
    const auto& dev = devices[static_cast<size_t>(v.device)];
    for (const auto& px : v.pixels_px) {
      // 2 px of slack: noisy detections at the border.
      SLSHADOW_THROW_IF(!px.allFinite() || px.x() < -2.5 || px.y() < -2.5 ||
                            px.x() > dev.width + 1.5 || px.y() > dev.height + 1.5,
                        what, ": pixel (", px.x(), ", ", px.y(), ") outside the ", dev.width, "x",
                        dev.height, " image of device '", dev.name, "' (mismatched image sizes?)");
    }
    if (v.IsCarried()) {
      SLSHADOW_THROW_IF(
          v.source_device >= static_cast<int>(devices.size()) || v.source_device == v.device, what,
          ": source_device must be another device of the input (got ", v.source_device, ")");
      const size_t n = v.pixels_px.size();
      SLSHADOW_THROW_IF(
          v.source_points.size() != n || v.source_jacobians.size() != n ||
              v.carry_covariances_px2.size() != n,
          what,
          ": a carried view needs one source point, Jacobian and carry covariance per point (", n,
          " points, ", v.source_points.size(), " source points, ", v.source_jacobians.size(),
          " Jacobians, ", v.carry_covariances_px2.size(), " covariances)");
      const int si = FindView(*this, v.source_device, v.pose);
      SLSHADOW_THROW_IF(si < 0, what, ": carried from device '",
                        devices[static_cast<size_t>(v.source_device)].name,
                        "', which has no view of pose ", v.pose);
      const BoardView& src = views[static_cast<size_t>(si)];
      for (size_t i = 0; i < n; ++i) {
        const int j = v.source_points[i];
        SLSHADOW_THROW_IF(
            j < 0 || j >= static_cast<int>(src.pixels_px.size()) ||
                (src.points_in_board_mm[static_cast<size_t>(j)] - v.points_in_board_mm[i]).norm() >
                    1e-9,
            what, ": point ", i, ": source point ", j, " is not the same board point in view '",
            src.label, "'");
        const Eigen::Matrix2d& c = v.carry_covariances_px2[i];
        SLSHADOW_THROW_IF(!v.source_jacobians[i].allFinite() || !c.allFinite() ||
                              std::abs(c(0, 1) - c(1, 0)) > 1e-9 * c.norm() ||
                              Eigen::LLT<Eigen::Matrix2d>(c).info() != Eigen::Success,
                          what, ": point ", i,
                          ": the source Jacobian must be finite and the carry covariance symmetric "
                          "positive definite");
      }
    }
    // Collinear (or coincident) board points give no pose.
    Eigen::MatrixXd centred(3, static_cast<Eigen::Index>(v.points_in_board_mm.size()));
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : v.points_in_board_mm) mean += p;
    mean /= static_cast<double>(v.points_in_board_mm.size());
    for (size_t i = 0; i < v.points_in_board_mm.size(); ++i)
      centred.col(static_cast<Eigen::Index>(i)) = v.points_in_board_mm[i] - mean;
    const Eigen::JacobiSVD<Eigen::MatrixXd> svd(centred);
    const auto sv = svd.singularValues();
    SLSHADOW_THROW_IF(
        !(sv(1) > 1e-6 * sv(0)) || !(sv(0) > 0), what,
        ": the board points are collinear; a view needs points spanning the board in 2D");
    ++views_per_device[static_cast<size_t>(v.device)];
  }
  for (size_t d = 0; d < devices.size(); ++d) {
    if (devices[d].initial) {
      SLSHADOW_THROW_IF(views_per_device[d] < 1, "calibration: device '", devices[d].name,
                        "': no views");
    } else {
      SLSHADOW_THROW_IF(
          views_per_device[d] < 2, "calibration: device '", devices[d].name,
          "': ", views_per_device[d],
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
    for (int i : {CameraModel::kK1, CameraModel::kK2, CameraModel::kP1, CameraModel::kP2,
                  CameraModel::kK3}) {
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
          candidates.push_back(FromPose6(per_device[d].rig_from_board[p]) *
                               FromPose6(s.rig_from_board[p]).Inverse());
        }
      }
      if (candidates.empty()) continue;
      const Rigid3d dev_from_rig = Medoid(candidates);
      s.dev_from_rig[d] = ToPose6(dev_from_rig);
      for (int p = 0; p < input.num_poses; ++p) {
        if (!s.pose_known[p] && per_device[d].pose_known[p]) {
          s.rig_from_board[p] =
              ToPose6(dev_from_rig.Inverse() * FromPose6(per_device[d].rig_from_board[p]));
          s.pose_known[p] = true;
        }
      }
      placed[d] = true;
      progress = true;
    }
  }
  for (int d = 1; d < num_devices; ++d) {
    SLSHADOW_THROW_IF(!placed[d], "calibration: device '", input.devices[d].name,
                      "' shares no board pose with device '", input.devices[0].name,
                      "' (directly or through other devices): its pose in the rig is unknown; "
                      "capture poses where both see the board");
  }

  // Final joint solve. With carried views and correlated_carried_noise: solve with independent
  // weights, estimate the noise model from its residuals, solve whitened, re-estimate once, and
  // solve whitened again (with the covariance).
  bool joint = false;
  for (const auto& v : input.views)
    joint = joint || (options.correlated_carried_noise && v.IsCarried());
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
    correlated_covariance =
        Solve(input, evaluate_only, &s, true, nullptr, &kernels).correlated_covariance;
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
  sum.termination = ceres::TerminationTypeToString(final_solve.summary.termination_type) +
                    std::string(": ") + final_solve.summary.message;
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
      const double v = s.intrinsics[d][i],
                   upper = (i == CameraModel::kCx ? dev.width : dev.height) - 0.5;
      if (std::abs(v - upper) > 1e-6 && std::abs(v + 0.5) > 1e-6) continue;
      char line[160];
      std::snprintf(line, sizeof(line), "%s %s = %.1f (%s bound)", dev.name.c_str(),
                    i == CameraModel::kCx ? "cx" : "cy", v, v > 0 ? "upper" : "lower");
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
  SLSHADOW_THROW_IF(
      view.device < 0 || view.device >= static_cast<int>(result.devices.size()) || view.pose < 0 ||
          view.pose >= static_cast<int>(result.rig_from_board.size()) ||
          !result.rig_from_board[view.pose],
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
  out << "calibration: " << devices.size() << " device(s), " << views.size() << " views, "
      << num_points << " points: RMS " << rms_px << " px (worst " << max_px << " px), "
      << num_outlier_views << " outlier view(s); cost " << initial_cost << " -> " << final_cost
      << ", " << iterations << " iterations, " << (converged ? "converged" : "NOT converged")
      << ", " << solve_time_s << " s";
  return out.str();
}

std::string CalibrationSummary::FullReport() const {
  std::ostringstream out;
  out << BriefReport() << "\n";
  char line[512];
  std::snprintf(line, sizeof(line),
                "termination: %s\nfree parameters: %d, residual sigma %.4f px per coordinate\n",
                termination.c_str(), num_free_parameters, residual_sigma_px);
  out << line;
  if (joint_noise) {
    out << "noise model: carried points whitened with their source points; corner noise per device "
           "(px):";
    for (size_t d = 0; d < noise_sigma_px.size(); ++d) {
      std::snprintf(line, sizeof(line), " %s %.4f", devices[d].name.c_str(), noise_sigma_px[d]);
      out << line;
    }
    std::snprintf(line, sizeof(line), "; carry scale %.4g; chi2/dof %.4f\n", carry_scale,
                  variance_factor);
    out << line;
  }
  if (!view_noise.empty()) {
    out << "corner errors within a view (sigma px, correlated share, length in squares):";
    for (size_t d = 0; d < view_noise.size() && d < devices.size(); ++d) {
      std::snprintf(line, sizeof(line), " %s %.4f %.2f %.2f", devices[d].name.c_str(),
                    view_noise[d].sigma_px, view_noise[d].share, view_noise[d].length_squares);
      out << line;
    }
    out << "\n";
  }
  for (const auto& b : bounds_active)
    out << "principal point on its bound (the data pull it outside the image): " << b << "\n";
  out << "device           views  points  RMS px   worst px\n";
  for (const auto& d : devices) {
    std::snprintf(line, sizeof(line), "%-16s %5d %7d %8.4f %9.4f\n", d.name.c_str(), d.num_views,
                  d.num_points, d.rms_px, d.max_px);
    out << line;
  }
  out << "view                             device pose points  RMS px   worst px\n";
  for (const auto& v : views) {
    std::snprintf(line, sizeof(line), "%-32s %6d %4d %6d %8.4f %9.4f%s\n", v.label.c_str(),
                  v.device, v.pose, v.num_points, v.rms_px, v.max_px,
                  v.outlier ? "  OUTLIER" : (v.num_points ? "" : "  (not posed)"));
    out << line;
  }
  return out.str();
}

}  // namespace slshadow
