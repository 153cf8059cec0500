#include "workflows/multiview/internal/pairwise.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <span>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "compare/median_spacing.h"
#include "core/error.h"

namespace slshadow::multiview::internal {
namespace {

using Vector6d = Eigen::Matrix<double, 6, 1>;

struct Accumulator {
  Matrix6d ata = Matrix6d::Zero();  // weighted: sum w J^T J
  Vector6d atb = Vector6d::Zero();  // sum w J^T r
  double sum_r2 = 0;                // point-to-plane squared residuals
  double sum_wr2 = 0;               // weighted
  double sum_p2p_sq = 0;            // nearest-point squared distances (drive the gate)
  Eigen::Vector3d sum_s = Eigen::Vector3d::Zero();
  double sum_s_sq = 0;
  size_t n = 0;
  std::vector<float> abs_residuals;  // |point-to-plane| of every correspondence within the gate
};

// Robust scale of the residuals: 1.4826 x their median absolute value (0 when none).
double RobustSigma(std::vector<float> r) {
  if (r.empty()) return 0.0;
  const auto mid = r.begin() + static_cast<long>(r.size() / 2);
  std::nth_element(r.begin(), mid, r.end());
  return 1.4826 * static_cast<double>(*mid);
}

// Correspondences of b's ICP sample moved by a_from_b with a's flat points: nearest point within
// the gate, normals compatible, point-to-plane residual within max_residual (outliers of the
// reconstruction, a few points far off the surface, would otherwise pull the least squares).
// Residual n . (s - q) with n the mean of both normals, Jacobian [s x n, n] of the left
// perturbation s -> s + w x s + v (n held fixed).
// `sample`: b's points to match (null: its ICP sample).
Accumulator Correspond(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                       double gate, double max_residual, const MergeOptions& o,
                       const std::vector<uint32_t>* sample = nullptr) {
  const std::vector<uint32_t>& source = sample != nullptr ? *sample : b.icp_sample;
  // MergeOptions::icp_table_normals_only: the PCA normals on the table sample only.
  const bool plain = o.icp_table_normals_only && sample == nullptr;
  const std::vector<Eigen::Vector3d>& normals_a = plain ? a.normals : a.icp_normals;
  const std::vector<Eigen::Vector3d>& normals_b = plain ? b.normals : b.icp_normals;
  Accumulator acc;
  acc.abs_residuals.reserve(source.size());
  const double cos_max = std::cos(o.icp_max_normal_angle_deg * M_PI / 180.0);
  const Eigen::Matrix3d r = a_from_b.rotation.toRotationMatrix();
  const auto& pa = *a.points;
  const auto& pb = *b.points;
  const float max_var = static_cast<float>(o.icp_max_surface_variation);
  const bool weighted = o.icp_noise_weights && !a.noise_var.empty() && !b.noise_var.empty();
  Neighbor nb;
  for (uint32_t i : source) {
    const Eigen::Vector3d s = r * pb[i] + a_from_b.translation;
    if (!a.tree->Nearest(s, &nb, gate)) continue;
    if (a.variation[nb.index] > max_var) continue;
    const Eigen::Vector3d nb_in_a = r * normals_b[i];
    if (normals_a[nb.index].dot(nb_in_a) < cos_max) continue;
    // Symmetric point-to-plane (Rusinkiewicz 2019): the mean of both normals, for which the
    // residual of two points on one circle is zero, so curved surfaces add no bias.
    const Eigen::Vector3d na = (normals_a[nb.index] + nb_in_a).normalized();
    const double res = na.dot(s - pa[nb.index]);
    acc.abs_residuals.push_back(static_cast<float>(std::abs(res)));
    if (std::abs(res) > max_residual) continue;
    Vector6d j;
    j.head<3>() = s.cross(na);
    j.tail<3>() = na;
    // Weighted by the two points' measured noise (each view's PCA residual variance).
    const double w =
        weighted ? 1.0 / static_cast<double>(a.noise_var[nb.index] + b.noise_var[i]) : 1.0;
    acc.ata.selfadjointView<Eigen::Upper>().rankUpdate(j, w);
    acc.atb += j * (w * res);
    acc.sum_r2 += res * res;
    acc.sum_wr2 += w * res * res;
    acc.sum_p2p_sq += nb.distance_sq;
    acc.sum_s += s;
    acc.sum_s_sq += s.squaredNorm();
    ++acc.n;
  }
  acc.ata = acc.ata.selfadjointView<Eigen::Upper>();
  return acc;
}

// Statistics of the correspondences; returns the weighted residual variance per unit weight
// (0 when fewer than 7).
double FillOutcome(const Accumulator& acc, const ViewGeometry& b, IcpOutcome* out,
                   const std::vector<uint32_t>* sample = nullptr) {
  const size_t size = sample != nullptr ? sample->size() : b.icp_sample.size();
  out->correspondences = static_cast<int>(acc.n);
  out->fitness = size == 0 ? 0.0 : static_cast<double>(acc.n) / static_cast<double>(size);
  if (acc.n < 7) return 0.0;
  const double n = static_cast<double>(acc.n);
  out->rms_mm = std::sqrt(acc.sum_r2 / n);
  out->centroid_in_a = acc.sum_s / n;
  out->radius_mm = std::sqrt(std::max(0.0, acc.sum_s_sq / n - out->centroid_in_a.squaredNorm()));
  return std::max(acc.sum_wr2 / (n - 6.0), 1e-30);
}

// The Gauss-Newton step of the linearised cost at t, with the degenerate directions (pairwise.h)
// held at the prior: in coordinates y = (L w, v + w x c) (rotation about the centroid c of the
// matched points scaled by their RMS radius L, so all six are displacements in mm) the normal
// matrix's eigenvectors with eigenvalue >= ratio x the largest are solved, the others set to the
// step that reaches the prior. The information (frame a, left perturbation of t) is J^T W J /
// sigma2 along the solved eigenvectors and the prior's along the others.
struct Step {
  Vector6d x = Vector6d::Zero();
  Matrix6d information = Matrix6d::Zero();
  std::vector<DegenerateDirection> degenerate;
  double min_ratio = 0;
  double max_sigma_mm = 0;  // 1-sigma of the solved displacements y, the least fixed one
};

Step SolveStep(const Accumulator& acc, const Rigid3d& t, const Rigid3d& prior, double sigma2,
               const MergeOptions& o) {
  Step step;
  const double n = static_cast<double>(acc.n);
  const Eigen::Vector3d c = acc.sum_s / n;
  const double radius = std::sqrt(std::max(0.0, acc.sum_s_sq / n - c.squaredNorm()));
  const double l = std::max(radius, 1e-3);
  Matrix6d tm, ti;  // y = tm x, x = ti y
  CentredScaling(c, l, &tm, &ti);
  const Matrix6d hy = ti.transpose() * acc.ata * ti;
  const Vector6d gy = ti.transpose() * acc.atb;
  const Eigen::SelfAdjointEigenSolver<Matrix6d> eig(0.5 * (hy + hy.transpose()));
  const double largest = std::max(eig.eigenvalues().maxCoeff(), 1e-300);
  step.min_ratio = std::max(0.0, eig.eigenvalues().minCoeff()) / largest;
  const Rigid3d d = prior * t.Inverse();
  Vector6d xp;
  xp.head<3>() = RotationVectorFromQuaternion(d.rotation);
  xp.tail<3>() = d.translation;
  const Vector6d yp = tm * xp;
  const double sr = o.prior_sigma_deg * M_PI / 180.0 * l, st = o.prior_sigma_mm;
  Vector6d prior_var;
  prior_var << sr * sr, sr * sr, sr * sr, st * st, st * st, st * st;
  Vector6d y = Vector6d::Zero();
  Matrix6d info_y = Matrix6d::Zero();
  Matrix6d free = Matrix6d::Zero();  // projector onto the degenerate directions
  for (int k = 0; k < 6; ++k) {
    const Vector6d v = eig.eigenvectors().col(k);
    const double lambda = eig.eigenvalues()[k];
    if (lambda >= o.icp_degenerate_ratio * largest && lambda > 0) {
      y -= v * (v.dot(gy) / lambda);
      info_y += v * v.transpose() * (lambda / sigma2);
      step.max_sigma_mm = std::max(step.max_sigma_mm, std::sqrt(sigma2 / lambda));
      continue;
    }
    y += v * v.dot(yp);
    free += v * v.transpose();
    DegenerateDirection dd;
    dd.rotation = v.head<3>().squaredNorm() > v.tail<3>().squaredNorm();
    dd.axis = (dd.rotation ? v.head<3>() : v.tail<3>()).normalized();
    dd.ratio = std::max(lambda, 0.0) / largest;
    step.degenerate.push_back(dd);
  }
  // The prior's information on the degenerate subspace (projected: whichever eigenvectors span it).
  info_y += free * prior_var.cwiseInverse().asDiagonal() * free;
  step.x = ti * y;
  step.information = tm.transpose() * info_y * tm;
  step.information = 0.5 * (step.information + step.information.transpose());
  return step;
}

// Scatter matrix of the neighbours about their mean.
Eigen::Matrix3d NeighbourScatter(const std::vector<Eigen::Vector3d>& pts,
                                 std::span<const Neighbor> nn) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& q : nn) mean += pts[q.index];
  mean /= static_cast<double>(nn.size());
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const auto& q : nn) {
    const Eigen::Vector3d d = pts[q.index] - mean;
    cov += d * d.transpose();
  }
  return cov;
}

Rigid3d Apply(const Vector6d& x, const Rigid3d& t) {
  return Rigid3d(QuaternionFromRotationVector(x.head<3>()), x.tail<3>()) * t;
}

}  // namespace

void PrepareView(const PointCloud& cloud, const MergeOptions& o, ViewGeometry* view,
                 const TurntableAxis* table_axis) {
  const auto& pts = cloud.points;
  SLSHADOW_THROW_IF(pts.size() < static_cast<size_t>(o.normal_neighbors) + 1, "merge: a view has ",
                    pts.size(), " points (need more than normal_neighbors = ", o.normal_neighbors,
                    ")");
  view->points = &pts;
  view->tree = std::make_unique<KdTree>(pts);
  view->spacing_mm = compare::MedianSpacing(*view->tree);
  view->normals.resize(pts.size());
  // With icp_table_normals_only the wide normals are read on the table sample only (and for its
  // draw): a view without one (a hand view, no axis) does not compute them.
  const bool table_sample = table_axis != nullptr && o.icp_table_share > 0 && o.icp_table_angles;
  const int k_icp = o.icp_table_normals_only && !table_sample ? 0 : o.icp_normal_neighbors;
  view->icp_normals.resize(k_icp > 0 ? pts.size() : 0);
  const int k_query = std::max(o.normal_neighbors, k_icp);
  view->variation.resize(pts.size());
  view->noise_var.resize(pts.size());
  const bool given = cloud.HasNormals();
  std::vector<float> radius(pts.size());
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, pts.size(), 4096),
      [&](const tbb::blocked_range<size_t>& range) {
        std::vector<Neighbor> all;
        for (size_t i = range.begin(); i != range.end(); ++i) {
          // Sorted by distance: the first normal_neighbors are the k of the
          // normals and the variation, all k_query those of the ICP normal.
          view->tree->KNearest(pts[i], k_query, &all);
          const std::span<const Neighbor> nn(
              all.data(), std::min(all.size(), static_cast<size_t>(o.normal_neighbors)));
          radius[i] = static_cast<float>(std::sqrt(nn.back().distance_sq));
          Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
          eig.computeDirect(NeighbourScatter(pts, nn));
          const double sum = eig.eigenvalues().sum();
          view->variation[i] = sum > 0 ? static_cast<float>(eig.eigenvalues()[0] / sum) : 1.0f;
          view->noise_var[i] =
              static_cast<float>(std::max(0.0, eig.eigenvalues()[0]) /
                                 std::max(1.0, static_cast<double>(nn.size()) - 3.0));
          Eigen::Vector3d n = given ? cloud.normals[i].cast<double>().normalized()
                                    : Eigen::Vector3d(eig.eigenvectors().col(0));
          if (!given && n.dot(pts[i]) > 0) n = -n;  // towards the camera (origin)
          view->normals[i] = n;
          if (k_icp > 0) {
            Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> wide;
            wide.computeDirect(NeighbourScatter(pts, all));
            Eigen::Vector3d m = wide.eigenvectors().col(0);
            view->icp_normals[i] = m.dot(n) < 0 ? -m : m;
          }
        }
      });
  if (k_icp <= 0) view->icp_normals = view->normals;
  // k points within the k-th neighbour's radius r: sqrt(area per point) = r sqrt(pi / k).
  std::nth_element(radius.begin(), radius.begin() + static_cast<long>(radius.size() / 2),
                   radius.end());
  view->area_spacing_mm = radius[radius.size() / 2] * std::sqrt(M_PI / o.normal_neighbors);
  {
    std::vector<float> var = view->noise_var;
    std::nth_element(var.begin(), var.begin() + static_cast<long>(var.size() / 2), var.end());
    const float floor = std::max(0.25f * var[var.size() / 2], 1e-12f);
    for (float& v : view->noise_var) v = std::max(v, floor);
  }
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& p : pts) sum += p;
  view->centroid = sum / static_cast<double>(pts.size());

  std::vector<uint32_t> flat;
  for (uint32_t i = 0; i < pts.size(); ++i)
    if (view->variation[i] <= o.icp_max_surface_variation) flat.push_back(i);
  // The ICP sample: evenly strided, and with a table axis a share drawn where the points fix the
  // table angle (pairwise.h).
  auto sample = [&](size_t n_table) {
    const size_t n_strided = static_cast<size_t>(o.icp_points) - n_table;
    std::vector<Eigen::Vector3d> chosen;
    std::vector<uint32_t> chosen_index;
    std::vector<uint8_t> taken(n_table > 0 ? pts.size() : 0, 0);
    if (n_strided > 0) {
      const size_t stride = std::max<size_t>(1, flat.size() / n_strided);
      for (size_t k = 0; k < flat.size(); k += stride) {
        chosen.push_back(pts[flat[k]]);
        chosen_index.push_back(flat[k]);
        if (n_table > 0) taken[flat[k]] = 1;
      }
    }
    if (n_table > 0 && !flat.empty()) {
      // Systematic sampling with probability proportional to |g|, g = n . (u x (p - c)): how far
      // the point moves along its normal per radian of table turn (u the axis direction, c a
      // point on it). A point drawn twice, or already in the strided share, counts once.
      const Eigen::Vector3d u = table_axis->direction_in_rig.normalized();
      const Eigen::Vector3d c = table_axis->point_in_rig_mm;
      std::vector<double> cumulative(flat.size());
      double total = 0;
      for (size_t k = 0; k < flat.size(); ++k) {
        const uint32_t i = flat[k];
        total += std::abs(view->icp_normals[i].dot(u.cross(pts[i] - c)));
        cumulative[k] = total;
      }
      const double step = total / static_cast<double>(n_table);
      size_t k = 0;
      for (size_t j = 0; j < n_table && total > 0; ++j) {
        const double target = (static_cast<double>(j) + 0.5) * step;
        while (k + 1 < flat.size() && cumulative[k] < target) ++k;
        const uint32_t i = flat[k];
        if (taken[i]) continue;
        taken[i] = 1;
        chosen.push_back(pts[i]);
        chosen_index.push_back(i);
      }
    }
    const std::vector<uint32_t> order = SpatialOrder(chosen);
    std::vector<uint32_t> out;
    for (uint32_t k : order) out.push_back(chosen_index[k]);
    return out;
  };
  const size_t n_table =
      table_axis != nullptr ? static_cast<size_t>(o.icp_table_share * o.icp_points) : 0;
  view->table_sample.clear();
  if (o.icp_table_angles && n_table > 0) {
    view->icp_sample = sample(0);
    view->table_sample = sample(n_table);
  } else {
    view->icp_sample = sample(n_table);
  }
  const size_t ostride = std::max<size_t>(1, pts.size() / static_cast<size_t>(o.overlap_samples));
  view->overlap_sample.clear();
  for (size_t i = 0; i < pts.size(); i += ostride)
    view->overlap_sample.push_back(static_cast<uint32_t>(i));
}

double OverlapShare(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                    double gate_mm, double max_normal_angle_deg) {
  if (b.overlap_sample.empty()) return 0.0;
  const double cos_max = std::cos(max_normal_angle_deg * M_PI / 180.0);
  size_t hits = 0;
  Neighbor nb;
  for (uint32_t i : b.overlap_sample) {
    const Eigen::Vector3d s = a_from_b * (*b.points)[i];
    if (!a.tree->Nearest(s, &nb, gate_mm)) continue;
    if (a.normals[nb.index].dot(a_from_b.rotation * b.normals[i]) >= cos_max) ++hits;
  }
  return static_cast<double>(hits) / static_cast<double>(b.overlap_sample.size());
}

IcpOutcome RegisterPair(const ViewGeometry& a, const ViewGeometry& b,
                        const Rigid3d& a_from_b_initial, const MergeOptions& o) {
  IcpOutcome out;
  Rigid3d t = a_from_b_initial;
  double gate = o.initial_gate_mm;
  double max_residual = std::numeric_limits<double>::infinity();
  const double min_gate = std::min(gate, 3.0 * a.spacing_mm);
  // Lever arm for the motion test: the farthest the sample's points are from frame a's origin.
  double lever = 0;
  for (uint32_t i : b.icp_sample) lever = std::max(lever, (t * (*b.points)[i]).norm());
  for (int it = 0; it < o.icp_max_iterations; ++it) {
    const Accumulator acc = Correspond(a, b, t, gate, max_residual, o);
    out.iterations = it + 1;
    if (acc.n < 7) break;
    // The next iteration's residual bound from this one's robust scale (every residual within the
    // gate, so an outlier share below half cannot inflate it).
    if (o.icp_max_residual_sigmas > 0)
      max_residual = std::max(o.icp_max_residual_sigmas * RobustSigma(acc.abs_residuals), 1e-6);
    // Directions the overlap leaves free (a plane's in-plane motions) stay at the prior.
    const double n = static_cast<double>(acc.n);
    const Step step =
        SolveStep(acc, t, a_from_b_initial, std::max(acc.sum_wr2 / (n - 6.0), 1e-30), o);
    const Vector6d& x = step.x;
    const double angle = x.head<3>().norm();
    t = Apply(x, t);
    // The gate shrinks (halving, down to 3 point spacings) only once the pose has settled at the
    // current one, so that correspondences on the few surfaces that fix a weakly constrained
    // direction (walls across a large plane) are not cut before that direction has converged.
    const double motion = angle * lever + x.tail<3>().norm();
    out.last_motion_mm = motion;
    if (gate > min_gate) {
      if (motion < 0.01 * gate) gate = std::max(min_gate, 0.5 * gate);
    } else if (motion < std::max(o.icp_tolerance_mm, o.icp_noise_tolerance * step.max_sigma_mm)) {
      // Settled within the tolerance, or within a small share of its own standard deviation
      // (with noise the correspondences jitter at that level; the joint refinement re-linearises
      // the pair at the graph's poses anyway).
      out.converged = true;
      break;
    }
  }
  out.a_from_b = t;
  out.gate_mm = gate;
  out.max_residual_mm = max_residual;
  const Accumulator acc = Correspond(a, b, t, gate, max_residual, o);
  const double sigma2 = FillOutcome(acc, b, &out);
  if (acc.n >= 7) {
    Step step = SolveStep(acc, t, a_from_b_initial, sigma2, o);
    out.information = step.information;
    out.degenerate = std::move(step.degenerate);
    out.min_eigen_ratio = step.min_ratio;
  }
  return out;
}

IcpOutcome RegisterTablePair(const ViewGeometry& a, const ViewGeometry& b,
                             const Rigid3d& a_from_b_initial, const MergeOptions& o) {
  if (o.icp_hold_gate_sigmas <= 0 || o.icp_degenerate_ratio <= 0)
    return RegisterPair(a, b, a_from_b_initial, o);
  MergeOptions free_options = o;
  free_options.icp_degenerate_ratio = 0;
  IcpOutcome free = RegisterPair(a, b, a_from_b_initial, free_options);
  if (free.converged && free.correspondences >= 7) {
    // The weak directions at the free result (the held step's eigen-decomposition there) and
    // the departure from the prior along them, in the prior's sigmas.
    const Accumulator acc = Correspond(a, b, free.a_from_b, free.gate_mm, free.max_residual_mm, o);
    if (acc.n >= 7) {
      const double n = static_cast<double>(acc.n);
      const Step held = SolveStep(acc, free.a_from_b, a_from_b_initial,
                                  std::max(acc.sum_wr2 / (n - 6.0), 1e-30), o);
      // The held step moves the pose to the prior along the weak directions (and to the
      // linearised minimum along the others, about zero at a converged result): its part
      // along the weak directions is the departure.
      const Eigen::Vector3d c = acc.sum_s / n;
      const double l = std::max(std::sqrt(std::max(0.0, acc.sum_s_sq / n - c.squaredNorm())), 1e-3);
      Matrix6d tm, ti;
      CentredScaling(c, l, &tm, &ti);
      const Vector6d y = tm * held.x;
      const double sr = o.prior_sigma_deg * M_PI / 180.0 * l, st = o.prior_sigma_mm;
      const double chi =
          std::sqrt(y.head<3>().squaredNorm() / (sr * sr) + y.tail<3>().squaredNorm() / (st * st));
      if (held.degenerate.empty() || chi <= o.icp_hold_gate_sigmas) {
        free.hold_released = !held.degenerate.empty();
        return free;
      }
    }
  }
  return RegisterPair(a, b, a_from_b_initial, o);
}

IcpOutcome LinearizePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                         const Rigid3d& a_from_b_prior, double gate_mm, double max_residual_mm,
                         const MergeOptions& options, const std::vector<uint32_t>* sample) {
  IcpOutcome out;
  out.gate_mm = gate_mm;
  out.max_residual_mm = max_residual_mm;
  out.converged = true;
  const Accumulator acc = Correspond(a, b, a_from_b, gate_mm, max_residual_mm, options, sample);
  const double sigma2 = FillOutcome(acc, b, &out, sample);
  out.a_from_b = a_from_b;
  if (acc.n < 7) return out;
  Step step = SolveStep(acc, a_from_b, a_from_b_prior, sigma2, options);
  out.a_from_b = Apply(step.x, a_from_b);
  out.information = step.information;
  out.degenerate = std::move(step.degenerate);
  out.min_eigen_ratio = step.min_ratio;
  return out;
}

IcpOutcome EvaluatePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                        double gate_mm, double max_residual_mm, const MergeOptions& options) {
  IcpOutcome out;
  out.a_from_b = a_from_b;
  out.gate_mm = gate_mm;
  out.max_residual_mm = max_residual_mm;
  out.converged = true;
  const Accumulator acc = Correspond(a, b, a_from_b, gate_mm, max_residual_mm, options);
  const double sigma2 = FillOutcome(acc, b, &out);
  if (acc.n >= 7) out.information = acc.ata / sigma2;
  return out;
}

void CentredScaling(const Eigen::Vector3d& c, double l, Matrix6d* tm, Matrix6d* ti) {
  Eigen::Matrix3d cx;
  cx << 0, -c.z(), c.y(), c.z(), 0, -c.x(), -c.y(), c.x(), 0;
  tm->setZero();
  tm->topLeftCorner<3, 3>() = l * Eigen::Matrix3d::Identity();
  tm->bottomLeftCorner<3, 3>() = -cx;
  tm->bottomRightCorner<3, 3>() = Eigen::Matrix3d::Identity();
  ti->setZero();
  ti->topLeftCorner<3, 3>() = Eigen::Matrix3d::Identity() / l;
  ti->bottomLeftCorner<3, 3>() = cx / l;
  ti->bottomRightCorner<3, 3>() = Eigen::Matrix3d::Identity();
}

}  // namespace slshadow::multiview::internal
