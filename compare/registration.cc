// The only translation unit that includes PCL (compile cost: DEVICE-MOCKS.md "Build facts").
#include "compare/registration.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <unordered_map>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <pcl/features/fpfh_omp.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/registration/sample_consensus_prerejective.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_reduce.h>

#include "compare/distances.h"
#include "compare/kdtree.h"
#include "core/error.h"

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
std::vector<Eigen::Vector3d> VoxelDownsample(const std::vector<Eigen::Vector3d>& pts, double voxel) {
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

struct GlobalResult {
  bool found = false;
  Rigid3d reference_from_cloud;
  double fitness = 0;
};

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

  pcl::SampleConsensusPrerejective<PointT, PointT, FeatureT> align;
  align.setInputSource(src_pcl);
  align.setSourceFeatures(src_f);
  align.setInputTarget(dst_pcl);
  align.setTargetFeatures(dst_f);
  align.setMaximumIterations(o.ransac_iterations);
  align.setNumberOfSamples(3);
  align.setCorrespondenceRandomness(3);
  align.setSimilarityThreshold(0.9f);
  align.setMaxCorrespondenceDistance(static_cast<float>(1.5 * voxel));
  align.setInlierFraction(static_cast<float>(o.ransac_inlier_fraction));
  std::srand(o.seed);  // PCL draws its samples with rand()
  pcl::PointCloud<PointT> aligned;
  align.align(aligned);
  if (!align.hasConverged()) return g;
  const Eigen::Matrix4d m = align.getFinalTransformation().cast<double>();
  g.found = true;
  g.reference_from_cloud = Rigid3d::FromMatrix(m);
  g.fitness = static_cast<double>(align.getInliers().size()) / static_cast<double>(src.size());
  return g;
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

IcpAcc Correspond(const std::vector<Eigen::Vector3d>& src, const Rigid3d& t, const KdTree& tree,
                  const std::vector<Eigen::Vector3d>& normals, double gate) {
  return tbb::parallel_reduce(
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

}  // namespace

std::string RegistrationMethodName(RegistrationMethod m) {
  switch (m) {
    case RegistrationMethod::kNone: return "none";
    case RegistrationMethod::kIcp: return "icp";
    case RegistrationMethod::kGlobalIcp: return "global+icp";
  }
  return "none";
}

RegistrationMethod ParseRegistrationMethod(const std::string& name) {
  if (name == "none") return RegistrationMethod::kNone;
  if (name == "icp") return RegistrationMethod::kIcp;
  if (name == "global+icp") return RegistrationMethod::kGlobalIcp;
  SLSHADOW_THROW("registration method: must be none, icp or global+icp (got '", name, "')");
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
                    "registration.ransac_inlier_fraction: must be in (0, 1] (got ", ransac_inlier_fraction, ")");
  SLSHADOW_THROW_IF(icp_max_iterations < 1, "registration.icp_max_iterations: must be >= 1 (got ",
                    icp_max_iterations, ")");
  SLSHADOW_THROW_IF(icp_max_points < 10, "registration.icp_max_points: must be >= 10 (got ", icp_max_points, ")");
  SLSHADOW_THROW_IF(!(icp_tolerance > 0), "registration.icp_tolerance: must be > 0 (got ", icp_tolerance, ")");
}

std::string RegistrationResult::BriefReport() const {
  char buf[320];
  const Eigen::AngleAxisd aa(reference_from_cloud.rotation);
  std::snprintf(buf, sizeof(buf),
                "registration %s: rotation %.4f deg, translation (%.4f, %.4f, %.4f) mm, fitness %.4f, "
                "inlier RMSE %.4f mm at %.3f mm, %d ICP iterations%s, %.2f s",
                RegistrationMethodName(method).c_str(), aa.angle() * 180.0 / M_PI,
                reference_from_cloud.translation.x(), reference_from_cloud.translation.y(),
                reference_from_cloud.translation.z(), fitness, inlier_rmse_mm, max_correspondence_mm,
                icp_iterations, converged ? "" : " (not converged)", time_s);
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
  SLSHADOW_THROW_IF(cloud.size() < 10, "registration: the compared cloud has ", cloud.size(), " points (need >= 10)");
  SLSHADOW_THROW_IF(reference.size() < 10, "registration: the reference has ", reference.size(), " points (need >= 10)");
  SLSHADOW_THROW_IF(!reference_normals.empty() && reference_normals.size() != reference.size(),
                    "registration: ", reference_normals.size(), " reference normals for ", reference.size(), " points");
  const double diag = Diagonal(reference);
  const double voxel = options.voxel_mm > 0 ? options.voxel_mm : diag / 60.0;
  const KdTree tree(reference);
  const std::vector<Eigen::Vector3d> normals =
      reference_normals.empty() ? EstimateNormals(reference, tree, 12, {}, Eigen::Vector3d(0, 0, 1e6))
                                : reference_normals;
  double gate = options.icp_max_correspondence_mm;
  if (options.method == RegistrationMethod::kGlobalIcp) {
    const double radius = options.feature_radius_mm > 0 ? options.feature_radius_mm : 5.0 * voxel;
    const GlobalResult g = GlobalAlign(cloud, reference, voxel, radius, options);
    r.global_found = g.found;
    r.global_fitness = g.fitness;
    if (g.found) r.reference_from_cloud = g.reference_from_cloud;
    if (gate == 0) gate = 2.0 * voxel;
  }
  if (gate == 0) gate = 0.05 * diag;
  // ICP subset: evenly strided.
  std::vector<Eigen::Vector3d> src;
  const size_t stride = std::max<size_t>(1, cloud.size() / static_cast<size_t>(options.icp_max_points));
  for (size_t i = 0; i < cloud.size(); i += stride) src.push_back(cloud[i]);
  const double min_gate = 3.0 * MedianSpacing(tree);
  Rigid3d t = r.reference_from_cloud;
  r.converged = false;
  for (int it = 0; it < options.icp_max_iterations; ++it) {
    const IcpAcc acc = Correspond(src, t, tree, normals, gate);
    r.icp_iterations = it + 1;
    if (acc.n < 6) break;
    const Eigen::Matrix<double, 6, 1> x =
        acc.ata.selfadjointView<Eigen::Upper>().ldlt().solve(-acc.atb);
    const Eigen::Vector3d w = x.head<3>();
    const double angle = w.norm();
    const Eigen::Quaterniond dq =
        angle > 0 ? Eigen::Quaterniond(Eigen::AngleAxisd(angle, w / angle)) : Eigen::Quaterniond::Identity();
    t = Rigid3d(dq, x.tail<3>()) * t;
    const double rms = std::sqrt(acc.sum_sq_p2p / static_cast<double>(acc.n));
    const double motion = angle * diag + x.tail<3>().norm();
    const double next_gate = std::max(std::min(gate, 3.0 * rms), min_gate);
    if (motion < options.icp_tolerance * diag && next_gate >= gate) {
      r.converged = true;
      break;
    }
    gate = next_gate;
  }
  r.reference_from_cloud = t;
  const IcpAcc fin = Correspond(src, t, tree, normals, gate);
  r.max_correspondence_mm = gate;
  r.fitness = static_cast<double>(fin.n) / static_cast<double>(src.size());
  r.inlier_rmse_mm = fin.n > 0 ? std::sqrt(fin.sum_sq_p2p / static_cast<double>(fin.n)) : 0.0;
  r.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return r;
}

}  // namespace slshadow::compare
