#include "workflows/multiview/internal/pose_graph.h"

#include <algorithm>
#include <array>
#include <utility>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "workflows/multiview/internal/relative_pose_delta.h"

namespace slshadow::multiview::internal {
namespace {

// Residual S (w, v) of the discrepancy P_a^-1 P_b M^-1, w its rotation vector and v its
// translation (the left perturbation of the measured a_from_b, as the ICP linearises it).
struct RelativePoseResidual {
  RelativePoseResidual(const Rigid3d& a_from_b, const Matrix6d& sqrt_information)
      : measured_inverse(a_from_b.Inverse()), sqrt_info(sqrt_information) {}

  template <typename T>
  bool operator()(const T* qa, const T* ta, const T* qb, const T* tb, T* residuals) const {
    const Eigen::Map<const Eigen::Quaternion<T>> rot_a(qa), rot_b(qb);
    const Eigen::Map<const Eigen::Matrix<T, 3, 1>> tr_a(ta), tr_b(tb);
    RelativePoseDelta<T>(rot_a, tr_a, rot_b, tr_b, measured_inverse, sqrt_info, residuals);
    return true;
  }

  Rigid3d measured_inverse;
  Matrix6d sqrt_info;
};

}  // namespace

Matrix6d SqrtInformation(const Matrix6d& information) {
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(0.5 * (information + information.transpose()));
  const Eigen::Matrix<double, 6, 1> root = eig.eigenvalues().cwiseMax(0.0).cwiseSqrt();
  return root.asDiagonal() * eig.eigenvectors().transpose();
}

Rigid3d EdgeDiscrepancy(const std::vector<Rigid3d>& part_from_rig, const GraphEdge& edge) {
  const Rigid3d estimated = part_from_rig[static_cast<size_t>(edge.a)].Inverse() *
                            part_from_rig[static_cast<size_t>(edge.b)];
  return estimated * edge.a_from_b.Inverse();
}

GraphSolution OptimizePoseGraph(const std::vector<Rigid3d>& initial,
                                const std::vector<bool>& active, int anchor,
                                const std::vector<GraphEdge>& edges, bool with_covariance) {
  const size_t n = initial.size();
  GraphSolution sol;
  sol.part_from_rig = initial;
  sol.covariance.assign(n, Matrix6d::Zero());
  std::vector<std::array<double, 4>> quat(n);
  std::vector<std::array<double, 3>> trans(n);
  for (size_t i = 0; i < n; ++i) {
    const Eigen::Quaterniond& q = initial[i].rotation;
    quat[i] = {q.x(), q.y(), q.z(), q.w()};  // Eigen's storage order
    trans[i] = {initial[i].translation.x(), initial[i].translation.y(), initial[i].translation.z()};
  }
  ceres::Problem problem;
  for (const GraphEdge& e : edges) {
    auto* cost = new ceres::AutoDiffCostFunction<RelativePoseResidual, 6, 4, 3, 4, 3>(
        new RelativePoseResidual(e.a_from_b, SqrtInformation(e.information)));
    problem.AddResidualBlock(cost, nullptr, quat[static_cast<size_t>(e.a)].data(),
                             trans[static_cast<size_t>(e.a)].data(),
                             quat[static_cast<size_t>(e.b)].data(),
                             trans[static_cast<size_t>(e.b)].data());
  }
  std::vector<int> free_views;
  for (size_t i = 0; i < n; ++i) {
    if (!active[i] || !problem.HasParameterBlock(quat[i].data())) continue;
    problem.SetManifold(quat[i].data(), new ceres::EigenQuaternionManifold);
    if (static_cast<int>(i) == anchor) {
      problem.SetParameterBlockConstant(quat[i].data());
      problem.SetParameterBlockConstant(trans[i].data());
    } else {
      free_views.push_back(static_cast<int>(i));
    }
  }
  if (edges.empty() || free_views.empty()) return sol;

  ceres::Solver::Options options;
  options.linear_solver_type =
      free_views.size() <= 64 ? ceres::DENSE_QR : ceres::SPARSE_NORMAL_CHOLESKY;
  options.max_num_iterations = 100;
  options.function_tolerance = 1e-15;
  options.gradient_tolerance = 1e-30;
  options.parameter_tolerance = 1e-15;
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(options, &problem, &summary);
  sol.iterations = static_cast<int>(summary.iterations.size());
  sol.initial_cost = summary.initial_cost;
  sol.final_cost = summary.final_cost;
  for (int i : free_views) {
    const auto& q = quat[static_cast<size_t>(i)];
    const auto& t = trans[static_cast<size_t>(i)];
    sol.part_from_rig[static_cast<size_t>(i)] =
        Rigid3d(Eigen::Quaterniond(q[3], q[0], q[1], q[2]), Eigen::Vector3d(t[0], t[1], t[2]));
  }
  // The variance factors (pose_graph.h): whitened residuals at the solution.
  sol.view_variance_factor.assign(n, 1.0);
  {
    std::vector<double> sum(n, 0.0), count(n, 0.0);
    double total = 0;
    for (const GraphEdge& e : edges) {
      const Rigid3d d = EdgeDiscrepancy(sol.part_from_rig, e);
      Eigen::Matrix<double, 6, 1> delta;
      delta.head<3>() = RotationVectorFromQuaternion(d.rotation);
      delta.tail<3>() = d.translation;
      const double r2 = (SqrtInformation(e.information) * delta).squaredNorm();
      total += r2;
      for (int v : {e.a, e.b}) {
        sum[static_cast<size_t>(v)] += r2;
        count[static_cast<size_t>(v)] += 1;
      }
    }
    const double edges_n = static_cast<double>(edges.size());
    const double dof = 6.0 * edges_n - 6.0 * static_cast<double>(free_views.size());
    if (dof > 0) {
      sol.variance_factor = std::max(1.0, total / dof);
      for (int i : free_views) {
        const size_t k = static_cast<size_t>(i);
        if (count[k] > 0)
          sol.view_variance_factor[k] = std::max(1.0, sum[k] / (count[k] * dof / edges_n));
      }
    }
  }
  if (!with_covariance) return sol;

  ceres::Covariance::Options cov_options;
  cov_options.algorithm_type = ceres::DENSE_SVD;
  cov_options.num_threads = 1;
  ceres::Covariance covariance(cov_options);
  std::vector<std::pair<const double*, const double*>> blocks;
  for (int i : free_views) {
    const double* q = quat[static_cast<size_t>(i)].data();
    const double* t = trans[static_cast<size_t>(i)].data();
    blocks.emplace_back(q, q);
    blocks.emplace_back(q, t);
    blocks.emplace_back(t, t);
  }
  if (!covariance.Compute(blocks, &problem)) return sol;
  for (int i : free_views) {
    const double* q = quat[static_cast<size_t>(i)].data();
    const double* t = trans[static_cast<size_t>(i)].data();
    Eigen::Matrix<double, 3, 3, Eigen::RowMajor> qq, qt, tt;
    covariance.GetCovarianceBlockInTangentSpace(q, q, qq.data());
    covariance.GetCovarianceBlockInTangentSpace(q, t, qt.data());
    covariance.GetCovarianceBlockInTangentSpace(t, t, tt.data());
    // The quaternion manifold's tangent is half the rotation vector (Plus = Exp(delta) * q with
    // |delta| the half angle), so the rotation vector's covariance is 4 x that of delta.
    Matrix6d c;
    c.topLeftCorner<3, 3>() = 4.0 * qq;
    c.topRightCorner<3, 3>() = 2.0 * qt;
    c.bottomLeftCorner<3, 3>() = 2.0 * qt.transpose();
    c.bottomRightCorner<3, 3>() = tt;
    sol.covariance[static_cast<size_t>(i)] =
        c * std::max(sol.variance_factor, sol.view_variance_factor[static_cast<size_t>(i)]);
  }
  sol.covariance_ok = true;
  return sol;
}

}  // namespace slshadow::multiview::internal
