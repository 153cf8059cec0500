// The only translation unit that includes PCL (compile cost: DEVICE-MOCKS.md "Build facts").
#include "compare/registration.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <random>
#include <unordered_map>

#include <pcl/features/fpfh_omp.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>
#include <Eigen/Cholesky>
#include <Eigen/Geometry>

#include "compare/distances.h"
#include "compare/median_spacing.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/kdtree.h"

namespace slshadow::compare {
namespace {

double Diagonal(const std::vector<Eigen::Vector3d>& pts) {
  Eigen::Vector3d lo = pts.front(), hi = pts.front();
  for (const auto& p : pts) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  return (hi - lo).norm();
}

// Centroid of the points in each occupied voxel (deterministic order: first occurrence).
std::vector<Eigen::Vector3d> VoxelDownsample(const std::vector<Eigen::Vector3d>& pts,
                                             double voxel) {
  struct Acc {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    int n = 0;
  };
  std::unordered_map<uint64_t, size_t> index;
  std::vector<Acc> acc;
  index.reserve(pts.size() / 4);
  for (const auto& p : pts) {
    const Eigen::Vector3d q = (p / voxel).array().floor();
    const auto key = (static_cast<uint64_t>(static_cast<int64_t>(q.x()) & 0x1FFFFF) << 42) |
                     (static_cast<uint64_t>(static_cast<int64_t>(q.y()) & 0x1FFFFF) << 21) |
                     static_cast<uint64_t>(static_cast<int64_t>(q.z()) & 0x1FFFFF);
    auto [it, inserted] = index.try_emplace(key, acc.size());
    if (inserted) acc.push_back({});
    acc[it->second].sum += p;
    ++acc[it->second].n;
  }
  std::vector<Eigen::Vector3d> out;
  out.reserve(acc.size());
  for (const auto& a : acc) out.push_back(a.sum / a.n);
  return out;
}

using PointT = pcl::PointNormal;
using FeatureT = pcl::FPFHSignature33;
constexpr int kDim = 33;  // FPFH histogram length

pcl::PointCloud<PointT>::Ptr ToPcl(const std::vector<Eigen::Vector3d>& pts,
                                   const std::vector<Eigen::Vector3d>& normals) {
  auto c = pcl::make_shared<pcl::PointCloud<PointT>>();
  c->resize(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    auto& q = (*c)[i];
    q.x = static_cast<float>(pts[i].x());
    q.y = static_cast<float>(pts[i].y());
    q.z = static_cast<float>(pts[i].z());
    q.normal_x = static_cast<float>(normals[i].x());
    q.normal_y = static_cast<float>(normals[i].y());
    q.normal_z = static_cast<float>(normals[i].z());
  }
  return c;
}

pcl::PointCloud<FeatureT>::Ptr Fpfh(const pcl::PointCloud<PointT>::Ptr& cloud, double radius) {
  pcl::FPFHEstimationOMP<PointT, PointT, FeatureT> est(2);
  est.setInputCloud(cloud);
  est.setInputNormals(cloud);
  est.setRadiusSearch(radius);
  auto features = pcl::make_shared<pcl::PointCloud<FeatureT>>();
  est.compute(*features);
  return features;
}

// One pose hypothesis of the global stage: reference_from_cloud, the feature correspondences it
// explains (its support) and the share of the voxel cloud it lands on the reference.
struct Hypothesis {
  Rigid3d reference_from_cloud;
  size_t support = 0;
  double fitness = 0;
};

struct GlobalResult {
  bool found = false;
  // Distinct hypotheses (most supported first), each refined on its inliers; the first is
  // RANSAC's best.
  std::vector<Hypothesis> candidates;
  double fitness = 0;  // the most supported hypothesis's
};

// Mutual nearest neighbours in FPFH space (33-D, L2), by brute force over the voxel clouds'
// features (a few thousand each): pairs (source index, target index). Falls back to one-way
// nearest neighbours when fewer than 30 pairs are mutual.
std::vector<std::pair<uint32_t, uint32_t>> MatchFeatures(const pcl::PointCloud<FeatureT>& src,
                                                         const pcl::PointCloud<FeatureT>& dst) {
  using Mat = Eigen::Matrix<float, Eigen::Dynamic, kDim, Eigen::RowMajor>;
  auto to_mat = [](const pcl::PointCloud<FeatureT>& f) {
    Mat m(static_cast<long>(f.size()), kDim);
    for (size_t i = 0; i < f.size(); ++i)
      for (int k = 0; k < kDim; ++k)
        m(static_cast<long>(i), k) = std::isfinite(f[i].histogram[k]) ? f[i].histogram[k] : 0.f;
    return m;
  };
  const Mat a = to_mat(src), b = to_mat(dst);
  const Eigen::VectorXf an = a.rowwise().squaredNorm(), bn = b.rowwise().squaredNorm();
  std::vector<uint32_t> best_ab(static_cast<size_t>(a.rows())),
      best_ba(static_cast<size_t>(b.rows()));
  std::vector<float> dist_ba(static_cast<size_t>(b.rows()), std::numeric_limits<float>::max());
  std::vector<float> dist_ab(static_cast<size_t>(a.rows()));
  constexpr long kBlock = 256;
  for (long r0 = 0; r0 < a.rows(); r0 += kBlock) {
    const long rows = std::min(kBlock, a.rows() - r0);
    // |a - b|^2 = |a|^2 + |b|^2 - 2 a.b, a block of rows at a time.
    const Eigen::MatrixXf d =
        (-2.0f * (a.middleRows(r0, rows) * b.transpose())).rowwise() + bn.transpose();
    for (long i = 0; i < rows; ++i) {
      long j = 0;
      const float di = d.row(i).minCoeff(&j) + an[r0 + i];
      best_ab[static_cast<size_t>(r0 + i)] = static_cast<uint32_t>(j);
      dist_ab[static_cast<size_t>(r0 + i)] = di;
      for (long k = 0; k < d.cols(); ++k) {
        const float v = d(i, k) + an[r0 + i];
        if (v < dist_ba[static_cast<size_t>(k)]) {
          dist_ba[static_cast<size_t>(k)] = v;
          best_ba[static_cast<size_t>(k)] = static_cast<uint32_t>(r0 + i);
        }
      }
    }
  }
  std::vector<std::pair<uint32_t, uint32_t>> mutual, oneway;
  for (size_t i = 0; i < best_ab.size(); ++i) {
    oneway.emplace_back(static_cast<uint32_t>(i), best_ab[i]);
    if (best_ba[best_ab[i]] == i) mutual.emplace_back(static_cast<uint32_t>(i), best_ab[i]);
  }
  return mutual.size() >= 30 ? mutual : oneway;
}

// Least-squares rigid transform dst ~ R src + t (Kabsch / Umeyama without scale).
Rigid3d Kabsch(const std::vector<Eigen::Vector3d>& s, const std::vector<Eigen::Vector3d>& d) {
  Eigen::Matrix3Xd a(3, static_cast<long>(s.size())), b(3, static_cast<long>(d.size()));
  for (size_t i = 0; i < s.size(); ++i) {
    a.col(static_cast<long>(i)) = s[i];
    b.col(static_cast<long>(i)) = d[i];
  }
  const Eigen::Matrix4d m = Eigen::umeyama(a, b, false);
  return Rigid3d::FromMatrix(m);
}

// RANSAC over feature correspondences with edge-length prerejection (Buch et al. 2013: a
// 3-sample whose pairwise distances differ by more than 10 % between the clouds is rejected
// before any pose is computed), adaptive iteration count for 99.9 % confidence, final
// least-squares fit on the inliers.
//
// Not only the best pose: a part with a large plain surface (a table, a plate) or a near
// symmetry has several poses that explain about as many correspondences, and the most supported
// one is not always the true one (a scan that lost its occlusion edges: the demo's block turned
// 20 deg about the table's normal, docs/benchmarks/log/2026-12-07-shadow-registration.md). So the
// `keep` most supported distinct hypotheses are returned, for the ICP to decide between on the
// full clouds. Two hypotheses are the same when they differ by less than 5 deg and move the
// cloud's centroid less than 2 voxels apart; the more supported one stands for both.
GlobalResult RansacOnCorrespondences(const std::vector<Eigen::Vector3d>& src,
                                     const std::vector<Eigen::Vector3d>& dst,
                                     const std::vector<std::pair<uint32_t, uint32_t>>& corr,
                                     double inlier_mm, double voxel, int keep,
                                     const RegistrationOptions& o) {
  GlobalResult g;
  std::mt19937 rng(o.seed);
  std::uniform_int_distribution<size_t> pick(0, corr.size() - 1);
  const double thr2 = inlier_mm * inlier_mm;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : src) centroid += p;
  centroid /= static_cast<double>(src.size());
  const auto same_pose = [&](const Rigid3d& a, const Rigid3d& b) {
    return RotationDifferenceDeg(a, b) < 5.0 && (a * centroid - b * centroid).norm() < 2 * voxel;
  };
  std::vector<Hypothesis> hyps;  // distinct, unsorted until the end
  size_t best_inliers = 0;
  long needed = o.ransac_iterations;
  auto count_inliers = [&](const Rigid3d& t) {
    size_t n = 0;
    for (const auto& [i, j] : corr) n += (t * src[i] - dst[j]).squaredNorm() < thr2 ? 1 : 0;
    return n;
  };
  const auto by_support = [](const Hypothesis& a, const Hypothesis& b) {
    return a.support > b.support;
  };
  const size_t capacity = static_cast<size_t>(std::max(1, keep)) * 4;
  for (long it = 0; it < needed && it < o.ransac_iterations; ++it) {
    const size_t k0 = pick(rng), k1 = pick(rng), k2 = pick(rng);
    if (k0 == k1 || k1 == k2 || k0 == k2) continue;
    const size_t ks[3] = {k0, k1, k2};
    bool ok = true;
    for (int x = 0; x < 3 && ok; ++x) {
      const auto& p = corr[ks[x]];
      const auto& q = corr[ks[(x + 1) % 3]];
      const double ls = (src[p.first] - src[q.first]).norm();
      const double ld = (dst[p.second] - dst[q.second]).norm();
      if (ls < 2 * inlier_mm || std::abs(ls - ld) > 0.1 * std::max(ls, ld)) ok = false;
    }
    if (!ok) continue;
    std::vector<Eigen::Vector3d> s3, d3;
    for (size_t k : ks) {
      s3.push_back(src[corr[k].first]);
      d3.push_back(dst[corr[k].second]);
    }
    const Rigid3d t = Kabsch(s3, d3);
    const size_t n = count_inliers(t);
    if (n < 3) continue;
    bool merged = false;
    for (auto& h : hyps) {
      if (!same_pose(h.reference_from_cloud, t)) continue;
      if (n > h.support) h = {t, n, 0.0};
      merged = true;
      break;
    }
    if (!merged) {
      hyps.push_back({t, n, 0.0});
      if (hyps.size() > 2 * capacity) {
        std::stable_sort(hyps.begin(), hyps.end(), by_support);
        hyps.resize(capacity);
      }
    }
    if (n > best_inliers) {
      best_inliers = n;
      const double w = static_cast<double>(n) / static_cast<double>(corr.size());
      const double denom = std::log(std::max(1e-12, 1.0 - w * w * w));
      needed = std::max<long>(1000, static_cast<long>(std::ceil(std::log(1e-3) / denom)));
    }
  }
  if (hyps.empty()) return g;
  std::stable_sort(hyps.begin(), hyps.end(), by_support);
  const KdTree tree(dst);
  for (auto& h : hyps) {
    if (g.candidates.size() >= static_cast<size_t>(std::max(1, keep))) break;
    // Refine on the inliers (twice: the refined pose may admit a few more).
    Rigid3d best = h.reference_from_cloud;
    for (int pass = 0; pass < 2; ++pass) {
      std::vector<Eigen::Vector3d> s, d;
      for (const auto& [i, j] : corr) {
        if ((best * src[i] - dst[j]).squaredNorm() < thr2) {
          s.push_back(src[i]);
          d.push_back(dst[j]);
        }
      }
      if (s.size() >= 3) best = Kabsch(s, d);
    }
    // Refinement may bring two hypotheses together: keep the first (more supported).
    bool duplicate = false;
    for (const auto& c : g.candidates)
      duplicate = duplicate || same_pose(c.reference_from_cloud, best);
    if (duplicate) continue;
    // Accept when enough of the voxel cloud lands on the target.
    size_t on = 0;
    Neighbor nb;
    for (const auto& p : src) on += tree.Nearest(best * p, &nb, inlier_mm) ? 1 : 0;
    const double fitness = static_cast<double>(on) / static_cast<double>(src.size());
    if (g.candidates.empty()) g.fitness = fitness;
    if (fitness < o.ransac_inlier_fraction) continue;
    g.candidates.push_back({best, h.support, fitness});
  }
  g.found = !g.candidates.empty();
  return g;
}

GlobalResult GlobalAlign(const std::vector<Eigen::Vector3d>& cloud,
                         const std::vector<Eigen::Vector3d>& reference, double voxel,
                         double feature_radius, const RegistrationOptions& o) {
  const auto src = VoxelDownsample(cloud, voxel);
  const auto dst = VoxelDownsample(reference, voxel);
  GlobalResult g;
  if (src.size() < 10 || dst.size() < 10) return g;
  const KdTree src_tree(src), dst_tree(dst);
  // Normals oriented consistently enough for FPFH: towards the centroid's far side is unknown,
  // so orient towards a viewpoint far along +z of each cloud's frame (FPFH's Darboux frame is
  // sign-sensitive only through the relative orientation of neighbours, which this keeps).
  const Eigen::Vector3d far(0, 0, 1e6);
  const auto src_n = EstimateNormals(src, src_tree, 12, {}, far);
  const auto dst_n = EstimateNormals(dst, dst_tree, 12, {}, far);
  const auto src_pcl = ToPcl(src, src_n);
  const auto dst_pcl = ToPcl(dst, dst_n);
  const auto src_f = Fpfh(src_pcl, feature_radius);
  const auto dst_f = Fpfh(dst_pcl, feature_radius);

  const auto corr = MatchFeatures(*src_f, *dst_f);
  if (corr.size() < 3) return g;
  return RansacOnCorrespondences(src, dst, corr, 1.5 * voxel, voxel, o.global_candidates, o);
}

struct IcpAcc {
  Eigen::Matrix<double, 6, 6> ata = Eigen::Matrix<double, 6, 6>::Zero();
  Eigen::Matrix<double, 6, 1> atb = Eigen::Matrix<double, 6, 1>::Zero();
  double sum_sq_p2p = 0;  // point-to-point squared distances of the correspondences
  size_t n = 0;
  void Add(const IcpAcc& o) {
    ata += o.ata;
    atb += o.atb;
    sum_sq_p2p += o.sum_sq_p2p;
    n += o.n;
  }
};

// Deterministic reduction: the same chunks summed in the same order whatever the threads do, so
// the same input gives the same pose to the bit.
IcpAcc Correspond(const std::vector<Eigen::Vector3d>& src, const Rigid3d& t, const KdTree& tree,
                  const std::vector<Eigen::Vector3d>& normals, double gate) {
  return tbb::parallel_deterministic_reduce(
      tbb::blocked_range<size_t>(0, src.size(), 2048), IcpAcc{},
      [&](const tbb::blocked_range<size_t>& r, IcpAcc acc) {
        Neighbor nb;
        for (size_t i = r.begin(); i != r.end(); ++i) {
          const Eigen::Vector3d s = t * src[i];
          if (!tree.Nearest(s, &nb, gate)) continue;
          const Eigen::Vector3d& q = tree.points()[nb.index];
          const Eigen::Vector3d& n = normals[nb.index];
          Eigen::Matrix<double, 6, 1> j;
          j.head<3>() = s.cross(n);
          j.tail<3>() = n;
          const double res = n.dot(s - q);
          acc.ata.selfadjointView<Eigen::Upper>().rankUpdate(j);
          acc.atb += j * res;
          acc.sum_sq_p2p += nb.distance_sq;
          ++acc.n;
        }
        return acc;
      },
      [](IcpAcc a, const IcpAcc& b) {
        a.Add(b);
        return a;
      });
}

struct IcpRun {
  Rigid3d pose;
  double gate = 0;  // the final correspondence gate
  int iterations = 0;
  bool converged = false;
};

// Point-to-plane ICP from `t`; the gate shrinks each iteration to max(3 x RMS, min_gate).
IcpRun RunIcp(const std::vector<Eigen::Vector3d>& src, const KdTree& tree,
              const std::vector<Eigen::Vector3d>& normals, Rigid3d t, double gate, double min_gate,
              double diag, int max_iterations, double tolerance) {
  IcpRun r;
  for (int it = 0; it < max_iterations; ++it) {
    const IcpAcc acc = Correspond(src, t, tree, normals, gate);
    r.iterations = it + 1;
    if (acc.n < 6) break;
    // A tiny additive damping keeps unobservable directions (e.g. rotations of a sphere about
    // its centre) at zero instead of letting them drift.
    Eigen::Matrix<double, 6, 6> ata = acc.ata.selfadjointView<Eigen::Upper>();
    ata.diagonal().array() += 1e-9 * ata.trace();
    const Eigen::Matrix<double, 6, 1> x = ata.ldlt().solve(-acc.atb);
    const Eigen::Vector3d w = x.head<3>();
    const double angle = w.norm();
    const Eigen::Quaterniond dq = QuaternionFromRotationVector(w);
    t = Rigid3d(dq, x.tail<3>()) * t;
    const double rms = std::sqrt(acc.sum_sq_p2p / static_cast<double>(acc.n));
    const double motion = angle * diag + x.tail<3>().norm();
    double next_gate = std::max(std::min(gate, 3.0 * rms), min_gate);
    if (next_gate > 0.95 * gate) next_gate = gate;  // settled: do not shrink by crumbs forever
    // Converged when the update is negligible, or when it moves the points only along the
    // surface (RMS displacement along the normals, sqrt(x' A'A x / n), below a tenth of the
    // statistical noise floor RMS / sqrt(n)): a symmetric part (a sphere, a cylinder) leaves
    // such motions unobservable, and they would never settle.
    const double normal_motion =
        std::sqrt(std::max(0.0, x.dot(acc.ata.selfadjointView<Eigen::Upper>() * x)) /
                  static_cast<double>(acc.n));
    const double noise_floor = 0.1 * rms / std::sqrt(static_cast<double>(acc.n));
    if ((motion < tolerance * diag || normal_motion < noise_floor) && next_gate >= gate) {
      r.converged = true;
      break;
    }
    gate = next_gate;
  }
  r.pose = t;
  r.gate = gate;
  return r;
}

// Fitness (share of `src` with a reference point within `gate`) and the RMS of those distances.
struct Fit {
  double fitness = 0;
  double rmse = 0;
};
Fit FitAt(const std::vector<Eigen::Vector3d>& src, const Rigid3d& t, const KdTree& tree,
          const std::vector<Eigen::Vector3d>& normals, double gate) {
  const IcpAcc acc = Correspond(src, t, tree, normals, gate);
  Fit f;
  f.fitness = static_cast<double>(acc.n) / static_cast<double>(src.size());
  f.rmse = acc.n > 0 ? std::sqrt(acc.sum_sq_p2p / static_cast<double>(acc.n)) : 0.0;
  return f;
}

}  // namespace

constexpr EnumName<RegistrationMethod> kRegistrationMethodNames[] = {
    {RegistrationMethod::kNone, "none"},
    {RegistrationMethod::kIcp, "icp"},
    {RegistrationMethod::kGlobalIcp, "global+icp"}};

std::string ToString(RegistrationMethod value) {
  return EnumToString(value, kRegistrationMethodNames);
}

RegistrationMethod RegistrationMethodFromString(const std::string& name) {
  return EnumFromString("registration method", name, kRegistrationMethodNames);
}

void RegistrationOptions::Check() const {
  auto nonneg = [](double v, const char* field) {
    SLSHADOW_THROW_IF(!(v >= 0) || !std::isfinite(v), "registration.", field,
                      ": must be finite and >= 0 (got ", v, ")");
  };
  nonneg(voxel_mm, "voxel_mm");
  nonneg(feature_radius_mm, "feature_radius_mm");
  nonneg(icp_max_correspondence_mm, "icp_max_correspondence_mm");
  SLSHADOW_THROW_IF(ransac_iterations < 1, "registration.ransac_iterations: must be >= 1 (got ",
                    ransac_iterations, ")");
  SLSHADOW_THROW_IF(!(ransac_inlier_fraction > 0 && ransac_inlier_fraction <= 1),
                    "registration.ransac_inlier_fraction: must be in (0, 1] (got ",
                    ransac_inlier_fraction, ")");
  SLSHADOW_THROW_IF(global_candidates < 1, "registration.global_candidates: must be >= 1 (got ",
                    global_candidates, ")");
  SLSHADOW_THROW_IF(global_candidate_points < 10,
                    "registration.global_candidate_points: must be >= 10 (got ",
                    global_candidate_points, ")");
  SLSHADOW_THROW_IF(global_candidate_iterations < 1,
                    "registration.global_candidate_iterations: must be >= 1 (got ",
                    global_candidate_iterations, ")");
  SLSHADOW_THROW_IF(icp_max_iterations < 1, "registration.icp_max_iterations: must be >= 1 (got ",
                    icp_max_iterations, ")");
  SLSHADOW_THROW_IF(icp_max_points < 10, "registration.icp_max_points: must be >= 10 (got ",
                    icp_max_points, ")");
  SLSHADOW_THROW_IF(!(icp_tolerance > 0), "registration.icp_tolerance: must be > 0 (got ",
                    icp_tolerance, ")");
}

std::string RegistrationResult::BriefReport() const {
  char buf[320];
  const Eigen::AngleAxisd aa(reference_from_cloud.rotation);
  std::snprintf(
      buf, sizeof(buf),
      "registration %s: rotation %.4f deg, translation (%.4f, %.4f, %.4f) mm, fitness %.4f, "
      "inlier RMSE %.4f mm at %.3f mm, %d ICP iterations%s, %.2f s",
      ToString(method).c_str(), aa.angle() * 180.0 / M_PI, reference_from_cloud.translation.x(),
      reference_from_cloud.translation.y(), reference_from_cloud.translation.z(), fitness,
      inlier_rmse_mm, max_correspondence_mm, icp_iterations, converged ? "" : " (not converged)",
      time_s);
  return buf;
}

double RotationDifferenceDeg(const Rigid3d& a, const Rigid3d& b) {
  return a.rotation.angularDistance(b.rotation) * 180.0 / M_PI;
}

RegistrationResult Register(const std::vector<Eigen::Vector3d>& cloud,
                            const std::vector<Eigen::Vector3d>& reference,
                            const std::vector<Eigen::Vector3d>& reference_normals,
                            const RegistrationOptions& options) {
  options.Check();
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationResult r;
  r.method = options.method;
  if (options.method == RegistrationMethod::kNone) return r;
  SLSHADOW_THROW_IF(cloud.size() < 10, "registration: the compared cloud has ", cloud.size(),
                    " points (need >= 10)");
  SLSHADOW_THROW_IF(reference.size() < 10, "registration: the reference has ", reference.size(),
                    " points (need >= 10)");
  SLSHADOW_THROW_IF(!reference_normals.empty() && reference_normals.size() != reference.size(),
                    "registration: ", reference_normals.size(), " reference normals for ",
                    reference.size(), " points");
  const double diag = Diagonal(reference);
  const double voxel = options.voxel_mm > 0 ? options.voxel_mm : diag / 60.0;
  const KdTree tree(reference);
  const std::vector<Eigen::Vector3d> normals =
      reference_normals.empty()
          ? EstimateNormals(reference, tree, 12, {}, Eigen::Vector3d(0, 0, 1e6))
          : reference_normals;
  // ICP subset: evenly strided.
  std::vector<Eigen::Vector3d> src;
  const size_t stride =
      std::max<size_t>(1, cloud.size() / static_cast<size_t>(options.icp_max_points));
  for (size_t i = 0; i < cloud.size(); i += stride) src.push_back(cloud[i]);
  {
    // Morton order: coherent kd-tree queries in every ICP iteration.
    const std::vector<uint32_t> order = SpatialOrder(src);
    std::vector<Eigen::Vector3d> sorted(src.size());
    for (size_t k = 0; k < order.size(); ++k) sorted[k] = src[order[k]];
    src = std::move(sorted);
  }
  const double min_gate = 3.0 * MedianSpacing(tree);
  double gate = options.icp_max_correspondence_mm;
  if (options.method == RegistrationMethod::kGlobalIcp) {
    const double radius = options.feature_radius_mm > 0 ? options.feature_radius_mm : 5.0 * voxel;
    const GlobalResult g = GlobalAlign(cloud, reference, voxel, radius, options);
    r.global_found = g.found;
    r.global_fitness = g.fitness;
    if (gate == 0) gate = 2.0 * voxel;
    r.global_candidates = static_cast<int>(g.candidates.size());
    if (g.candidates.size() == 1) {
      r.reference_from_cloud = g.candidates.front().reference_from_cloud;
    } else if (g.candidates.size() > 1) {
      // Every hypothesis refined by ICP on a subset of the full cloud (a Morton-ordered cloud
      // strided: spread over it) and judged at the same gate, the reference's finest: the share
      // of the points it puts on the reference's surface. RANSAC's support only decides between
      // refined poses whose shares differ by less than kTie.
      constexpr double kTie = 0.01;
      std::vector<Eigen::Vector3d> sub;
      const size_t sub_stride =
          std::max<size_t>(1, src.size() / static_cast<size_t>(options.global_candidate_points));
      for (size_t i = 0; i < src.size(); i += sub_stride) sub.push_back(src[i]);
      struct Scored {
        Rigid3d pose;
        size_t support;
        double global_fitness;
        Fit fit;
      };
      std::vector<Scored> scored;
      for (const Hypothesis& h : g.candidates) {
        const IcpRun run = RunIcp(sub, tree, normals, h.reference_from_cloud, gate, min_gate, diag,
                                  options.global_candidate_iterations, options.icp_tolerance);
        scored.push_back(
            {run.pose, h.support, h.fitness, FitAt(sub, run.pose, tree, normals, min_gate)});
      }
      size_t best = 0;
      for (size_t k = 1; k < scored.size(); ++k) {
        const double df = scored[k].fit.fitness - scored[best].fit.fitness;
        if (df > kTie || (df > -kTie && scored[k].support > scored[best].support)) best = k;
      }
      r.reference_from_cloud = scored[best].pose;
      r.global_fitness = scored[best].global_fitness;
      r.candidate_fitness = scored[best].fit.fitness;
      // The runner-up: the best-fitting refined pose that is not the chosen one.
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (const auto& p : sub) centroid += p;
      centroid /= static_cast<double>(sub.size());
      for (size_t k = 0; k < scored.size(); ++k) {
        const double moved = (scored[k].pose * centroid - scored[best].pose * centroid).norm();
        const double turned = RotationDifferenceDeg(scored[k].pose, scored[best].pose);
        if (k == best || (turned < 5.0 && moved < 2 * voxel)) continue;
        if (r.alternative_fitness < 0 || scored[k].fit.fitness > r.alternative_fitness) {
          r.alternative_fitness = scored[k].fit.fitness;
          r.alternative_rotation_deg = turned;
          r.alternative_translation_mm = moved;
        }
      }
    }
  }
  if (gate == 0) gate = 0.05 * diag;
  const IcpRun run = RunIcp(src, tree, normals, r.reference_from_cloud, gate, min_gate, diag,
                            options.icp_max_iterations, options.icp_tolerance);
  r.reference_from_cloud = run.pose;
  r.icp_iterations = run.iterations;
  r.converged = run.converged;
  const Fit fin = FitAt(src, run.pose, tree, normals, run.gate);
  r.max_correspondence_mm = run.gate;
  r.fitness = fin.fitness;
  r.inlier_rmse_mm = fin.rmse;
  r.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace slshadow::compare
