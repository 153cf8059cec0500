#include "workflows/multiview/internal/turntable_graph.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <memory>
#include <utility>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "workflows/multiview/internal/relative_pose_delta.h"

namespace slshadow::multiview::internal {
namespace {

// The unknowns, in one place: axis direction u (unit), the axis point's offsets across the axis
// (along e1, e2 from c0), one angle per view (table views), one pose per view (hand views).
struct Params {
  std::array<double, 3> u{};
  std::array<double, 2> c{};
  std::vector<double> theta;
  std::vector<std::array<double, 4>> q;  // Eigen's order x, y, z, w
  std::vector<std::array<double, 3>> t;
};

struct Frame {
  Rigid3d m;  // the gauge
  Eigen::Vector3d c0, e1, e2;
};

template <typename T>
void TablePose(const Frame& f, const T* u, const T* c2, const T* theta, Eigen::Quaternion<T>* q,
               Eigen::Matrix<T, 3, 1>* t) {
  using std::cos;
  using std::sin;
  const T half = theta[0] * T(0.5);
  const T s = sin(half);
  const Eigen::Quaternion<T> r(cos(half), s * u[0], s * u[1], s * u[2]);
  const Eigen::Matrix<T, 3, 1> c = f.c0.cast<T>() + f.e1.cast<T>() * c2[0] + f.e2.cast<T>() * c2[1];
  const Eigen::Quaternion<T> r_inv = r.conjugate();
  const Eigen::Quaternion<T> mq = f.m.rotation.cast<T>();
  *q = mq * r_inv;
  *t = mq * (c - r_inv * c) + f.m.translation.cast<T>();
}

template <typename T>
void HandPose(const T* qv, const T* tv, Eigen::Quaternion<T>* q, Eigen::Matrix<T, 3, 1>* t) {
  *q = Eigen::Quaternion<T>(qv[3], qv[0], qv[1], qv[2]);
  *t = Eigen::Matrix<T, 3, 1>(tv[0], tv[1], tv[2]);
}

// One pair's residual S (w, v) of P_a^-1 P_b M^-1 (pose_graph.cc), each end a table or hand view.
// Parameter blocks: [u, c] when either end is a table view, then per end theta or (q, t).
struct ModelEdgeResidual {
  struct End {
    bool table = false;
    int theta = -1, q = -1, t = -1;  // slots in the parameter list
  };
  Frame frame;
  End a, b;
  int u_slot = -1, c_slot = -1;
  Rigid3d measured_inverse;
  Matrix6d sqrt_info;

  template <typename T>
  void Pose(const End& e, T const* const* p, Eigen::Quaternion<T>* q,
            Eigen::Matrix<T, 3, 1>* t) const {
    if (e.table)
      TablePose(frame, p[u_slot], p[c_slot], p[e.theta], q, t);
    else
      HandPose(p[e.q], p[e.t], q, t);
  }

  template <typename T>
  bool operator()(T const* const* p, T* residuals) const {
    Eigen::Quaternion<T> rot_a, rot_b;
    Eigen::Matrix<T, 3, 1> tr_a, tr_b;
    Pose(a, p, &rot_a, &tr_a);
    Pose(b, p, &rot_b, &tr_b);
    RelativePoseDelta<T>(rot_a, tr_a, rot_b, tr_b, measured_inverse, sqrt_info, residuals);
    return true;
  }
};

Rigid3d PoseOf(const Frame& f, const Params& p, const std::vector<double>& angle, size_t i) {
  Eigen::Quaterniond q;
  Eigen::Vector3d t;
  if (std::isfinite(angle[i]))
    TablePose(f, p.u.data(), p.c.data(), &p.theta[i], &q, &t);
  else
    HandPose(p.q[i].data(), p.t[i].data(), &q, &t);
  return Rigid3d(q.normalized(), t);
}

// All poses from the parameters, moved so that the anchor sits at its initial pose.
std::vector<Rigid3d> Poses(const Frame& f, const Params& p, const std::vector<double>& angle,
                           const std::vector<Rigid3d>& initial, const std::vector<bool>& active,
                           int anchor) {
  std::vector<Rigid3d> out = initial;
  const size_t ia = static_cast<size_t>(anchor);
  const Rigid3d g = initial[ia] * PoseOf(f, p, angle, ia).Inverse();
  for (size_t i = 0; i < initial.size(); ++i)
    if (active[i]) out[i] = g * PoseOf(f, p, angle, i);
  out[ia] = initial[ia];
  return out;
}

double WhitenedNorm(const std::vector<Rigid3d>& poses, const GraphEdge& e) {
  const Rigid3d d = EdgeDiscrepancy(poses, e);
  Eigen::Matrix<double, 6, 1> delta;
  delta.head<3>() = RotationVectorFromQuaternion(d.rotation);
  delta.tail<3>() = d.translation;
  return (SqrtInformation(e.information) * delta).norm();
}

}  // namespace

bool TableModelApplies(const TableModel& model, const std::vector<bool>& active) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (size_t i = 0; i < active.size() && i < model.angle_rad.size(); ++i) {
    if (!active[i] || !std::isfinite(model.angle_rad[i])) continue;
    lo = std::min(lo, model.angle_rad[i]);
    hi = std::max(hi, model.angle_rad[i]);
  }
  return hi - lo > M_PI / 180.0;
}

GraphSolution OptimizeTurntableGraph(const std::vector<Rigid3d>& initial,
                                     const std::vector<bool>& active, int anchor,
                                     const std::vector<GraphEdge>& edges, const TableModel& model,
                                     bool with_covariance, TableFit* fit) {
  const size_t n = initial.size();
  const std::vector<double>& angle = model.angle_rad;
  GraphSolution sol;
  sol.part_from_rig = initial;
  sol.covariance.assign(n, Matrix6d::Zero());
  *fit = TableFit();
  fit->angle_rad.assign(n, std::numeric_limits<double>::quiet_NaN());
  fit->sigma_angle_deg.assign(n, 0.0);

  // The reference table view: the anchor when it is one, else the first active table view.
  const size_t ia = static_cast<size_t>(anchor);
  int ref = std::isfinite(angle[ia]) ? anchor : -1;
  for (size_t i = 0; i < n && ref < 0; ++i)
    if (active[i] && std::isfinite(angle[i])) ref = static_cast<int>(i);
  fit->reference = ref;
  const Eigen::Vector3d u0 = model.direction_in_rig.normalized();
  Frame frame;
  frame.c0 = model.point_in_rig_mm;
  frame.e1 = u0.unitOrthogonal();
  frame.e2 = u0.cross(frame.e1);
  auto turn = [&](double theta) {
    const Eigen::Quaterniond r(Eigen::AngleAxisd(theta, u0));
    return Rigid3d(r, frame.c0 - r * frame.c0);
  };
  const size_t iref = static_cast<size_t>(ref);
  frame.m = initial[iref] * turn(angle[iref]);

  Params p;
  p.u = {u0.x(), u0.y(), u0.z()};
  p.c = {0.0, 0.0};
  p.theta.assign(n, 0.0);
  p.q.resize(n);
  p.t.resize(n);
  for (size_t i = 0; i < n; ++i) {
    if (std::isfinite(angle[i])) p.theta[i] = angle[i];
    const Eigen::Quaterniond& q = initial[i].rotation;
    p.q[i] = {q.x(), q.y(), q.z(), q.w()};
    p.t[i] = {initial[i].translation.x(), initial[i].translation.y(), initial[i].translation.z()};
  }

  // The problem, built twice when robust (a plain solve first sets the loss's corner).
  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::SphereManifold<3> sphere;
  ceres::EigenQuaternionManifold quaternion;
  double huber = 0;
  std::vector<Rigid3d> poses;
  ceres::Solver::Summary summary;
  std::vector<double*> free_blocks;  // in the covariance's order
  auto build_and_solve = [&](ceres::Problem* problem) {
    for (const GraphEdge& e : edges) {
      auto* functor = new ModelEdgeResidual;
      functor->frame = frame;
      functor->measured_inverse = e.a_from_b.Inverse();
      functor->sqrt_info = SqrtInformation(e.information);
      std::vector<double*> blocks;
      std::vector<int> sizes;
      const bool any_table = std::isfinite(angle[static_cast<size_t>(e.a)]) ||
                             std::isfinite(angle[static_cast<size_t>(e.b)]);
      if (any_table) {
        functor->u_slot = 0;
        functor->c_slot = 1;
        blocks = {p.u.data(), p.c.data()};
        sizes = {3, 2};
      }
      for (auto [end, view] : {std::pair{&functor->a, e.a}, std::pair{&functor->b, e.b}}) {
        const size_t v = static_cast<size_t>(view);
        end->table = std::isfinite(angle[v]);
        if (end->table) {
          end->theta = static_cast<int>(blocks.size());
          blocks.push_back(&p.theta[v]);
          sizes.push_back(1);
        } else {
          end->q = static_cast<int>(blocks.size());
          blocks.push_back(p.q[v].data());
          sizes.push_back(4);
          end->t = static_cast<int>(blocks.size());
          blocks.push_back(p.t[v].data());
          sizes.push_back(3);
        }
      }
      auto* cost = new ceres::DynamicAutoDiffCostFunction<ModelEdgeResidual, 8>(functor);
      for (int s : sizes) cost->AddParameterBlock(s);
      cost->SetNumResiduals(6);
      problem->AddResidualBlock(cost, huber > 0 ? new ceres::HuberLoss(huber) : nullptr, blocks);
    }
    free_blocks.clear();
    if (problem->HasParameterBlock(p.u.data())) {
      problem->SetManifold(p.u.data(), &sphere);
      if (model.fix_axis) {
        problem->SetParameterBlockConstant(p.u.data());
        problem->SetParameterBlockConstant(p.c.data());
      } else {
        free_blocks.push_back(p.u.data());
        free_blocks.push_back(p.c.data());
      }
    }
    for (size_t i = 0; i < n; ++i) {
      if (!active[i]) continue;
      if (std::isfinite(angle[i])) {
        if (!problem->HasParameterBlock(&p.theta[i])) continue;
        if (static_cast<int>(i) == ref)
          problem->SetParameterBlockConstant(&p.theta[i]);
        else
          free_blocks.push_back(&p.theta[i]);
      } else if (problem->HasParameterBlock(p.q[i].data())) {
        problem->SetManifold(p.q[i].data(), &quaternion);
        free_blocks.push_back(p.q[i].data());
        free_blocks.push_back(p.t[i].data());
      }
    }
    ceres::Solver::Options options;
    options.linear_solver_type = ceres::DENSE_QR;
    options.max_num_iterations = 100;
    options.function_tolerance = 1e-15;
    options.gradient_tolerance = 1e-30;
    options.parameter_tolerance = 1e-15;
    options.num_threads = 1;
    options.logging_type = ceres::SILENT;
    ceres::Solve(options, problem, &summary);
    poses = Poses(frame, p, angle, initial, active, anchor);
  };

  if (model.robust_k > 0 && !edges.empty()) {
    const Params start = p;
    {
      ceres::Problem first(problem_options);
      build_and_solve(&first);
    }
    std::vector<double> norms;
    for (const GraphEdge& e : edges) norms.push_back(WhitenedNorm(poses, e));
    std::nth_element(norms.begin(), norms.begin() + static_cast<long>(norms.size() / 2),
                     norms.end());
    huber = std::max(model.robust_k * norms[norms.size() / 2], 1e-9);
    p = start;
  }
  auto problem = std::make_unique<ceres::Problem>(problem_options);
  build_and_solve(problem.get());
  sol.initial_cost = summary.initial_cost;
  fit->huber_corner = huber;
  sol.iterations = static_cast<int>(summary.iterations.size());
  sol.final_cost = summary.final_cost;
  sol.part_from_rig = poses;

  const Eigen::Vector3d u(p.u[0], p.u[1], p.u[2]);
  fit->direction_in_rig = u.normalized();
  const Eigen::Vector3d c = frame.c0 + frame.e1 * p.c[0] + frame.e2 * p.c[1];
  // The axis point nearest the starting one.
  fit->point_in_rig_mm = c + fit->direction_in_rig * fit->direction_in_rig.dot(frame.c0 - c);
  for (size_t i = 0; i < n; ++i)
    if (active[i] && std::isfinite(angle[i])) fit->angle_rad[i] = p.theta[i];
  double sum_sq = 0;
  for (const GraphEdge& e : edges) {
    const double r = WhitenedNorm(poses, e);
    sum_sq += r * r;
  }
  size_t unknowns = 0;
  for (double* b : free_blocks) unknowns += problem->ParameterBlockTangentSize(b);
  const double dof = 6.0 * static_cast<double>(edges.size()) - static_cast<double>(unknowns);
  fit->variance_factor = dof > 0 ? std::max(1.0, sum_sq / dof) : 1.0;
  if (!with_covariance || free_blocks.empty()) return sol;

  // Covariance of the unknowns (tangent space), then each pose's by finite differences of the
  // poses (anchor held) over the unknowns.
  ceres::Covariance::Options cov_options;
  cov_options.algorithm_type = ceres::DENSE_SVD;
  cov_options.num_threads = 1;
  ceres::Covariance covariance(cov_options);
  std::vector<std::pair<const double*, const double*>> pairs;
  for (size_t x = 0; x < free_blocks.size(); ++x)
    for (size_t y = x; y < free_blocks.size(); ++y)
      pairs.emplace_back(free_blocks[x], free_blocks[y]);
  if (!covariance.Compute(pairs, problem.get())) return sol;
  std::vector<int> offset(free_blocks.size() + 1, 0);
  for (size_t x = 0; x < free_blocks.size(); ++x)
    offset[x + 1] = offset[x] + problem->ParameterBlockTangentSize(free_blocks[x]);
  const int dim = offset.back();
  Eigen::MatrixXd cov(dim, dim);
  for (size_t x = 0; x < free_blocks.size(); ++x) {
    for (size_t y = x; y < free_blocks.size(); ++y) {
      const int rx = offset[x + 1] - offset[x], ry = offset[y + 1] - offset[y];
      Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> block(rx, ry);
      covariance.GetCovarianceBlockInTangentSpace(free_blocks[x], free_blocks[y], block.data());
      cov.block(offset[x], offset[y], rx, ry) = block;
      cov.block(offset[y], offset[x], ry, rx) = block.transpose();
    }
  }
  cov *= fit->variance_factor;
  // Finite differences through the manifolds' Plus.
  Eigen::MatrixXd jac = Eigen::MatrixXd::Zero(6 * static_cast<long>(n), dim);
  constexpr double kStep = 1e-6;
  for (size_t x = 0; x < free_blocks.size(); ++x) {
    double* block = free_blocks[x];
    const int size = problem->ParameterBlockSize(block);
    const int tangent = problem->ParameterBlockTangentSize(block);
    const std::vector<double> saved(block, block + size);
    const ceres::Manifold* manifold = problem->GetManifold(block);
    for (int k = 0; k < tangent; ++k) {
      std::vector<double> delta(static_cast<size_t>(tangent), 0.0);
      delta[static_cast<size_t>(k)] = kStep;
      if (manifold != nullptr)
        manifold->Plus(saved.data(), delta.data(), block);
      else
        block[k] = saved[static_cast<size_t>(k)] + kStep;
      const std::vector<Rigid3d> moved = Poses(frame, p, angle, initial, active, anchor);
      std::copy(saved.begin(), saved.end(), block);
      for (size_t i = 0; i < n; ++i) {
        if (!active[i]) continue;
        jac.block<3, 1>(6 * static_cast<long>(i), offset[x] + k) =
            RotationVectorFromQuaternion(moved[i].rotation * poses[i].rotation.conjugate()) / kStep;
        jac.block<3, 1>(6 * static_cast<long>(i) + 3, offset[x] + k) =
            (moved[i].translation - poses[i].translation) / kStep;
      }
    }
  }
  for (size_t i = 0; i < n; ++i) {
    if (!active[i] || static_cast<int>(i) == anchor) continue;
    const Eigen::MatrixXd j = jac.middleRows(6 * static_cast<long>(i), 6);
    sol.covariance[i] = j * cov * j.transpose();
  }
  if (problem->HasParameterBlock(p.u.data()) && !model.fix_axis) {
    // free_blocks[0] is u (tangent 2), [1] is c (2).
    const Eigen::Matrix2d cu = cov.block<2, 2>(0, 0), cc = cov.block<2, 2>(2, 2);
    fit->sigma_direction_deg =
        std::sqrt(std::max(
            0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cu).eigenvalues().maxCoeff())) *
        180.0 / M_PI;
    fit->sigma_point_mm = std::sqrt(
        std::max(0.0, Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cc).eigenvalues().maxCoeff()));
  }
  for (size_t x = 0; x < free_blocks.size(); ++x) {
    for (size_t i = 0; i < n; ++i) {
      if (free_blocks[x] == &p.theta[i])
        fit->sigma_angle_deg[i] = std::sqrt(std::max(0.0, cov(offset[x], offset[x]))) * 180 / M_PI;
    }
  }
  sol.covariance_ok = true;
  return sol;
}

}  // namespace slshadow::multiview::internal
