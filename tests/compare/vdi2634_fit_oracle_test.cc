// The least-squares sphere and plane fits behind the VDI/VDE 2634-2 figures (compare/vdi2634.h
// FitSphere, FitPlane) against oracles: exact analytic least-squares solutions of point sets whose
// symmetry fixes them, and brute-force searches of the geometric cost. The brute-force sphere test
// fails an algebraic (Kasa) fit, which it checks too: the two differ on a noisy cap.
#include "compare/vdi2634.h"

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include <cmath>
#include <random>
#include <vector>

namespace slshadow::compare {
namespace {

using Eigen::Vector3d;

double SphereCost(const std::vector<Vector3d>& pts, const Vector3d& c, double r) {
  double s = 0;
  for (const auto& p : pts) s += std::pow((p - c).norm() - r, 2);
  return s;
}
// The radius that minimises the geometric cost for a fixed centre: the mean distance.
double BestRadius(const std::vector<Vector3d>& pts, const Vector3d& c) {
  double s = 0;
  for (const auto& p : pts) s += (p - c).norm();
  return s / static_cast<double>(pts.size());
}
double PlaneCost(const std::vector<Vector3d>& pts, const Vector3d& n) {
  Vector3d m = Vector3d::Zero();
  for (const auto& p : pts) m += p;
  m /= static_cast<double>(pts.size());
  double s = 0;
  for (const auto& p : pts) s += std::pow((p - m).dot(n.normalized()), 2);
  return s;
}

Eigen::Matrix3d SomeRotation() {
  return (Eigen::AngleAxisd(0.7, Vector3d(1, 2, 3).normalized()) *
          Eigen::AngleAxisd(-0.4, Vector3d(0.3, -1, 0.2).normalized()))
      .toRotationMatrix();
}

// 26 directions (faces, edges, corners of a cube) in 13 antipodal pairs; each pair at its own
// distance from c0. The gradient of sum (|p - c| - r)^2 in c vanishes at c0 (antipodal points
// cancel), and in r at the mean distance: the least-squares sphere is (c0, mean), exactly, and
// its form error PF the range of the distances.
TEST(FitSphereOracle, PointSymmetricSetGivesItsCentreAndMeanDistance) {
  const Vector3d c0(12.3, -45.6, 500.7);
  const Eigen::Matrix3d rot = SomeRotation();
  std::vector<Vector3d> pts;
  std::vector<double> rho;
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-0.05, 0.05);
  for (int x = -1; x <= 1; ++x) {
    for (int y = -1; y <= 1; ++y) {
      for (int z = -1; z <= 1; ++z) {
        const Vector3d d(x, y, z);
        // One of each antipodal pair: the first non-zero coordinate positive.
        const bool first = x > 0 || (x == 0 && (y > 0 || (y == 0 && z > 0)));
        if (!first) continue;
        const double r = 12.7 + u(rng);
        const Vector3d dir = rot * d.normalized();
        pts.push_back(c0 + r * dir);
        pts.push_back(c0 - r * dir);
        rho.push_back(r);
        rho.push_back(r);
      }
    }
  }
  ASSERT_EQ(pts.size(), 26u);
  double mean = 0, lo = 1e9, hi = -1e9;
  for (double r : rho) {
    mean += r / static_cast<double>(rho.size());
    lo = std::min(lo, r);
    hi = std::max(hi, r);
  }
  double ss = 0;
  for (double r : rho) ss += (r - mean) * (r - mean);
  SphereFit fit;
  ASSERT_TRUE(FitSphere(pts, &fit));
  EXPECT_LT((fit.center - c0).norm(), 1e-9);
  EXPECT_NEAR(fit.radius, mean, 1e-10);
  EXPECT_NEAR(fit.rms_mm, std::sqrt(ss / static_cast<double>(rho.size())), 1e-10);

  // PF and PS through the acceptance test's evaluation, whose segmentation keeps every point.
  ArtefactSpec spec;
  spec.spheres = {{"s", c0, 25.0}};
  Vdi2634Options options;
  options.min_points = 20;
  PointCloud cloud;
  cloud.points = pts;
  const Vdi2634Result r = EvaluateVdi2634(cloud, spec, options);
  ASSERT_TRUE(r.spheres[0].found);
  EXPECT_EQ(r.spheres[0].points, 26u);
  EXPECT_NEAR(r.spheres[0].pf_mm, hi - lo, 1e-10);
  EXPECT_NEAR(r.spheres[0].ps_mm, 2 * mean - 25.0, 1e-10);
}

TEST(FitSphereOracle, ExactCapPointsGiveTheSphere) {
  const Vector3d c0(-3, 7, 480);
  const double r0 = 10.0;
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> u(0, 1);
  std::vector<Vector3d> pts;
  const Eigen::Matrix3d rot = SomeRotation();
  while (pts.size() < 500) {  // a 40 degree cap (half angle)
    const double ct = 1 - u(rng) * (1 - std::cos(40 * M_PI / 180)), ph = 2 * M_PI * u(rng);
    const double st = std::sqrt(1 - ct * ct);
    pts.push_back(c0 + r0 * (rot * Vector3d(st * std::cos(ph), st * std::sin(ph), ct)));
  }
  SphereFit fit;
  ASSERT_TRUE(FitSphere(pts, &fit));
  EXPECT_LT((fit.center - c0).norm(), 1e-9);
  EXPECT_NEAR(fit.radius, r0, 1e-10);
  EXPECT_LT(fit.rms_mm, 1e-10);
}

// A noisy 50 degree cap: no centre on a grid around the fit (and refined around the grid's best)
// has a lower geometric cost; the fit's centre is where the brute-force minimum is. An algebraic
// fit (|p|^2 + D.p + E = 0 by linear least squares) does not pass: its cost is measurably higher.
TEST(FitSphereOracle, NoisyCapFitIsTheBruteForceMinimumOfTheGeometricCost) {
  const Vector3d c0(20, -10, 520);
  const double r0 = 12.7;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(0, 1);
  std::normal_distribution<double> g(0, 0.05);
  std::vector<Vector3d> pts;
  const Eigen::Matrix3d rot = SomeRotation();
  while (pts.size() < 1500) {
    const double ct = 1 - u(rng) * (1 - std::cos(50 * M_PI / 180)), ph = 2 * M_PI * u(rng);
    const double st = std::sqrt(1 - ct * ct);
    pts.push_back(c0 + (r0 + g(rng)) * (rot * Vector3d(st * std::cos(ph), st * std::sin(ph), ct)));
  }
  SphereFit fit;
  ASSERT_TRUE(FitSphere(pts, &fit));
  const double fit_cost = SphereCost(pts, fit.center, fit.radius);
  EXPECT_NEAR(fit.radius, BestRadius(pts, fit.center), 1e-9);  // stationary in r

  Vector3d best = fit.center;
  double best_cost = fit_cost;
  for (const double step : {0.02, 0.002, 0.0002}) {
    const Vector3d around = best;
    for (int i = -10; i <= 10; ++i) {
      for (int j = -10; j <= 10; ++j) {
        for (int k = -10; k <= 10; ++k) {
          const Vector3d c = around + step * Vector3d(i, j, k);
          const double cost = SphereCost(pts, c, BestRadius(pts, c));
          if (cost < best_cost) {
            best_cost = cost;
            best = c;
          }
        }
      }
    }
  }
  EXPECT_LE(fit_cost, best_cost * (1 + 1e-12)) << "a grid centre beats the fit";
  EXPECT_LT((best - fit.center).norm(), 1e-3);

  // The algebraic fit, as the fitter's start: the brute force tells it apart.
  Eigen::MatrixXd a(static_cast<long>(pts.size()), 4);
  Eigen::VectorXd b(static_cast<long>(pts.size()));
  for (size_t i = 0; i < pts.size(); ++i) {
    const Vector3d q = pts[i] - c0;
    a.row(static_cast<long>(i)) << q.x(), q.y(), q.z(), 1.0;
    b[static_cast<long>(i)] = -q.squaredNorm();
  }
  const Eigen::Vector4d x = a.colPivHouseholderQr().solve(b);
  const Vector3d kasa = c0 - 0.5 * x.head<3>();
  const double kasa_cost =
      SphereCost(pts, kasa, std::sqrt(0.25 * x.head<3>().squaredNorm() - x[3]));
  EXPECT_GT(kasa_cost, fit_cost * (1 + 1e-6));
}

// A checkerboard of +-a offsets on an even grid in a plane: the offsets have zero mean and no
// correlation with either in-plane coordinate, so the least-squares plane is the grid's plane,
// exactly; flatness F = 2a, RMS = a.
TEST(FitPlaneOracle, CheckerboardOffsetsGiveTheGridPlane) {
  const Eigen::Matrix3d rot = SomeRotation();
  const Vector3d t(5, -8, 530);
  const double a = 0.03;
  std::vector<Vector3d> pts;
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 12; ++j) {
      const double e = ((i + j) % 2 == 0 ? a : -a);
      pts.push_back(t + rot * Vector3d(3.0 * (i - 9.5), 2.5 * (j - 5.5), e));
    }
  }
  PlaneFit fit;
  ASSERT_TRUE(FitPlane(pts, &fit));
  const Vector3d n0 = rot * Vector3d::UnitZ();
  EXPECT_NEAR(std::abs(fit.normal.dot(n0)), 1.0, 1e-14);
  EXPECT_LT((fit.point - t).norm(), 1e-9);
  EXPECT_NEAR(fit.rms_mm, a, 1e-12);

  ArtefactSpec spec;
  spec.planes = {{"p", t, n0, 40.0}};
  PointCloud cloud;
  cloud.points = pts;
  const Vdi2634Result r = EvaluateVdi2634(cloud, spec);
  ASSERT_TRUE(r.planes[0].found);
  EXPECT_EQ(r.planes[0].points, pts.size());
  EXPECT_NEAR(r.planes[0].f_mm, 2 * a, 1e-10);
}

// Noisy points of a tilted rectangle: no normal on a grid of directions around the fit has a
// lower sum of squared distances (about the centroid).
TEST(FitPlaneOracle, NoisyPlaneFitIsTheBruteForceMinimum) {
  const Eigen::Matrix3d rot = SomeRotation();
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-1, 1);
  std::normal_distribution<double> g(0, 0.05);
  std::vector<Vector3d> pts;
  for (int i = 0; i < 2000; ++i)
    pts.push_back(Vector3d(0, 0, 500) + rot * Vector3d(60 * u(rng), 20 * u(rng), g(rng)));
  PlaneFit fit;
  ASSERT_TRUE(FitPlane(pts, &fit));
  const double fit_cost = PlaneCost(pts, fit.normal);
  const Vector3d e1 = fit.normal.unitOrthogonal(), e2 = fit.normal.cross(e1);
  double best = fit_cost;
  for (const double step : {1e-3, 1e-5}) {
    for (int i = -20; i <= 20; ++i) {
      for (int j = -20; j <= 20; ++j) {
        best = std::min(best, PlaneCost(pts, fit.normal + step * (i * e1 + j * e2)));
      }
    }
  }
  EXPECT_LE(fit_cost, best * (1 + 1e-12));
  EXPECT_NEAR(fit.rms_mm, std::sqrt(fit_cost / static_cast<double>(pts.size())), 1e-12);
}

}  // namespace
}  // namespace slshadow::compare
