#include "workflows/multiview/internal/pairwise.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "compare/median_spacing.h"
#include "core/error.h"

namespace slshadow::multiview::internal {
namespace {

struct Accumulator {
  Matrix6d ata = Matrix6d::Zero();
  Eigen::Matrix<double, 6, 1> atb = Eigen::Matrix<double, 6, 1>::Zero();
  double sum_r2 = 0;      // point-to-plane squared residuals
  double sum_p2p_sq = 0;  // nearest-point squared distances (drive the gate)
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
Accumulator Correspond(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                       double gate, double max_residual, const MergeOptions& o) {
  Accumulator acc;
  acc.abs_residuals.reserve(b.icp_sample.size());
  const double cos_max = std::cos(o.icp_max_normal_angle_deg * M_PI / 180.0);
  const Eigen::Matrix3d r = a_from_b.rotation.toRotationMatrix();
  const auto& pa = *a.points;
  const auto& pb = *b.points;
  const float max_var = static_cast<float>(o.icp_max_surface_variation);
  Neighbor nb;
  for (uint32_t i : b.icp_sample) {
    const Eigen::Vector3d s = r * pb[i] + a_from_b.translation;
    if (!a.tree->Nearest(s, &nb, gate)) continue;
    if (a.variation[nb.index] > max_var) continue;
    const Eigen::Vector3d nb_in_a = r * b.normals[i];
    if (a.normals[nb.index].dot(nb_in_a) < cos_max) continue;
    // Symmetric point-to-plane (Rusinkiewicz 2019): the mean of both normals, for which the
    // residual of two points on one circle is zero, so curved surfaces add no bias.
    const Eigen::Vector3d na = (a.normals[nb.index] + nb_in_a).normalized();
    const double res = na.dot(s - pa[nb.index]);
    acc.abs_residuals.push_back(static_cast<float>(std::abs(res)));
    if (std::abs(res) > max_residual) continue;
    Eigen::Matrix<double, 6, 1> j;
    j.head<3>() = s.cross(na);
    j.tail<3>() = na;
    acc.ata.selfadjointView<Eigen::Upper>().rankUpdate(j);
    acc.atb += j * res;
    acc.sum_r2 += res * res;
    acc.sum_p2p_sq += nb.distance_sq;
    acc.sum_s += s;
    acc.sum_s_sq += s.squaredNorm();
    ++acc.n;
  }
  acc.ata = acc.ata.selfadjointView<Eigen::Upper>();
  return acc;
}

void FillOutcome(const Accumulator& acc, const ViewGeometry& b, IcpOutcome* out) {
  out->correspondences = static_cast<int>(acc.n);
  out->fitness = b.icp_sample.empty()
                     ? 0.0
                     : static_cast<double>(acc.n) / static_cast<double>(b.icp_sample.size());
  if (acc.n < 7) return;
  const double n = static_cast<double>(acc.n);
  out->rms_mm = std::sqrt(acc.sum_r2 / n);
  const double sigma2 = std::max(acc.sum_r2 / (n - 6.0), 1e-18);
  out->information = acc.ata / sigma2;
  out->centroid_in_a = acc.sum_s / n;
  out->radius_mm = std::sqrt(std::max(0.0, acc.sum_s_sq / n - out->centroid_in_a.squaredNorm()));
}

}  // namespace

void PrepareView(const PointCloud& cloud, const MergeOptions& o, ViewGeometry* view) {
  const auto& pts = cloud.points;
  SLSHADOW_THROW_IF(pts.size() < static_cast<size_t>(o.normal_neighbors) + 1, "merge: a view has ",
                    pts.size(), " points (need more than normal_neighbors = ", o.normal_neighbors,
                    ")");
  view->points = &pts;
  view->tree = std::make_unique<KdTree>(pts);
  view->spacing_mm = compare::MedianSpacing(*view->tree);
  view->normals.resize(pts.size());
  view->variation.resize(pts.size());
  const bool given = cloud.HasNormals();
  std::vector<float> radius(pts.size());
  tbb::parallel_for(tbb::blocked_range<size_t>(0, pts.size(), 4096),
                    [&](const tbb::blocked_range<size_t>& range) {
                      std::vector<Neighbor> nn;
                      for (size_t i = range.begin(); i != range.end(); ++i) {
                        view->tree->KNearest(pts[i], o.normal_neighbors, &nn);
                        radius[i] = static_cast<float>(std::sqrt(nn.back().distance_sq));
                        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
                        for (const auto& q : nn) mean += pts[q.index];
                        mean /= static_cast<double>(nn.size());
                        Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
                        for (const auto& q : nn) {
                          const Eigen::Vector3d d = pts[q.index] - mean;
                          cov += d * d.transpose();
                        }
                        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
                        eig.computeDirect(cov);
                        const double sum = eig.eigenvalues().sum();
                        view->variation[i] =
                            sum > 0 ? static_cast<float>(eig.eigenvalues()[0] / sum) : 1.0f;
                        Eigen::Vector3d n = given ? cloud.normals[i].cast<double>().normalized()
                                                  : Eigen::Vector3d(eig.eigenvectors().col(0));
                        if (!given && n.dot(pts[i]) > 0) n = -n;  // towards the camera (origin)
                        view->normals[i] = n;
                      }
                    });
  // k points within the k-th neighbour's radius r: sqrt(area per point) = r sqrt(pi / k).
  std::nth_element(radius.begin(), radius.begin() + static_cast<long>(radius.size() / 2),
                   radius.end());
  view->area_spacing_mm = radius[radius.size() / 2] * std::sqrt(M_PI / o.normal_neighbors);
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const auto& p : pts) sum += p;
  view->centroid = sum / static_cast<double>(pts.size());

  std::vector<uint32_t> flat;
  for (uint32_t i = 0; i < pts.size(); ++i)
    if (view->variation[i] <= o.icp_max_surface_variation) flat.push_back(i);
  const size_t stride = std::max<size_t>(1, flat.size() / static_cast<size_t>(o.icp_points));
  std::vector<Eigen::Vector3d> chosen;
  std::vector<uint32_t> chosen_index;
  for (size_t k = 0; k < flat.size(); k += stride) {
    chosen.push_back(pts[flat[k]]);
    chosen_index.push_back(flat[k]);
  }
  const std::vector<uint32_t> order = SpatialOrder(chosen);
  view->icp_sample.clear();
  for (uint32_t k : order) view->icp_sample.push_back(chosen_index[k]);
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
    // A tiny damping keeps unobservable directions (a plane's in-plane motions) at zero.
    Matrix6d ata = acc.ata;
    ata.diagonal().array() += 1e-12 * ata.trace();
    const Eigen::Matrix<double, 6, 1> x = ata.ldlt().solve(-acc.atb);
    const Eigen::Vector3d w = x.head<3>();
    const double angle = w.norm();
    const Eigen::Quaterniond dq = QuaternionFromRotationVector(w);
    t = Rigid3d(dq, x.tail<3>()) * t;
    // The gate shrinks (halving, down to 3 point spacings) only once the pose has settled at the
    // current one, so that correspondences on the few surfaces that fix a weakly constrained
    // direction (walls across a large plane) are not cut before that direction has converged.
    const double motion = angle * lever + x.tail<3>().norm();
    out.last_motion_mm = motion;
    if (gate > min_gate) {
      if (motion < 0.01 * gate) gate = std::max(min_gate, 0.5 * gate);
    } else if (motion < o.icp_tolerance_mm) {
      out.converged = true;
      break;
    }
  }
  out.a_from_b = t;
  out.gate_mm = gate;
  out.max_residual_mm = max_residual;
  FillOutcome(Correspond(a, b, t, gate, max_residual, o), b, &out);
  return out;
}

IcpOutcome LinearizePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                         double gate_mm, double max_residual_mm, const MergeOptions& options) {
  IcpOutcome out;
  out.gate_mm = gate_mm;
  out.max_residual_mm = max_residual_mm;
  out.converged = true;
  const Accumulator acc = Correspond(a, b, a_from_b, gate_mm, max_residual_mm, options);
  FillOutcome(acc, b, &out);
  out.a_from_b = a_from_b;
  if (acc.n < 7) return out;
  Matrix6d ata = acc.ata;
  ata.diagonal().array() += 1e-12 * ata.trace();
  const Eigen::Matrix<double, 6, 1> x = ata.ldlt().solve(-acc.atb);
  out.a_from_b = Rigid3d(QuaternionFromRotationVector(x.head<3>()), x.tail<3>()) * a_from_b;
  return out;
}

IcpOutcome EvaluatePair(const ViewGeometry& a, const ViewGeometry& b, const Rigid3d& a_from_b,
                        double gate_mm, double max_residual_mm, const MergeOptions& options) {
  IcpOutcome out;
  out.a_from_b = a_from_b;
  out.gate_mm = gate_mm;
  out.max_residual_mm = max_residual_mm;
  out.converged = true;
  FillOutcome(Correspond(a, b, a_from_b, gate_mm, max_residual_mm, options), b, &out);
  return out;
}

}  // namespace slshadow::multiview::internal
