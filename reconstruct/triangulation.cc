#include "reconstruct/triangulation.h"

#include <cmath>

#include <Eigen/Cholesky>

#include "core/enum_names.h"
#include "core/error.h"

namespace slshadow {

constexpr EnumName<TriangulationMethod> kTriangulationMethodNames[] = {
    {TriangulationMethod::kMidpoint, "midpoint"},
    {TriangulationMethod::kDlt, "dlt"},
    {TriangulationMethod::kOptimal, "optimal"}};

std::string ToString(TriangulationMethod value) {
  return EnumToString(value, kTriangulationMethodNames);
}

TriangulationMethod TriangulationMethodFromString(const std::string& name) {
  return EnumFromString("triangulation method", name, kTriangulationMethodNames);
}

TriangulationView::TriangulationView(const Rigid3d& cam_from_rig, double focal)
    : cam_from_rig_rotation(cam_from_rig.rotation.toRotationMatrix()),
      cam_from_rig_translation(cam_from_rig.translation),
      center_in_rig(cam_from_rig.TargetOriginInSource()),
      focal_px(focal) {}

namespace {

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return m;
}

}  // namespace

TwoViewTriangulator::TwoViewTriangulator(const TriangulationView& view0,
                                         const TriangulationView& view1, double sigma0_px,
                                         double sigma1_px)
    : view0_(view0), view1_(view1) {
  SLSHADOW_CHECK(sigma0_px > 0 && sigma1_px > 0);
  scale0_ = view0.focal_px / sigma0_px;
  scale1_ = view1.focal_px / sigma1_px;
  // cam1_from_cam0: X1 = R X0 + t; essential x1^T [t]x R x0 = 0, so x0^T ([t]x R)^T x1 = 0.
  const Eigen::Matrix3d r = view1.cam_from_rig_rotation * view0.cam_from_rig_rotation.transpose();
  const Eigen::Vector3d t = view1.cam_from_rig_translation - r * view0.cam_from_rig_translation;
  const Eigen::Matrix3d essential01 = (Skew(t) * r).transpose();
  const Eigen::Vector3d k0inv(1.0 / view0.focal_px, 1.0 / view0.focal_px, 1.0);
  const Eigen::Vector3d k1inv(1.0 / view1.focal_px, 1.0 / view1.focal_px, 1.0);
  fundamental_ = k0inv.asDiagonal() * essential01 * k1inv.asDiagonal();
  const Eigen::Vector3d w0inv(1.0 / scale0_, 1.0 / scale0_, 1.0);
  const Eigen::Vector3d w1inv(1.0 / scale1_, 1.0 / scale1_, 1.0);
  weighted_fundamental_ = w0inv.asDiagonal() * essential01 * w1inv.asDiagonal();
  proj0_.leftCols<3>() = view0.cam_from_rig_rotation;
  proj0_.col(3) = view0.cam_from_rig_translation;
  proj1_.leftCols<3>() = view1.cam_from_rig_rotation;
  proj1_.col(3) = view1.cam_from_rig_translation;
}

double TwoViewTriangulator::SinAngle(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1) const {
  return SinAngleOfRays(view0_.RayInRig(xy0), view1_.RayInRig(xy1));
}

double TwoViewTriangulator::SignedEpipolarDistancePx(const Eigen::Vector2d& xy0,
                                                     const Eigen::Vector2d& xy1) const {
  const Eigen::Vector3d x0(view0_.focal_px * xy0.x(), view0_.focal_px * xy0.y(), 1.0);
  const Eigen::Vector3d x1(view1_.focal_px * xy1.x(), view1_.focal_px * xy1.y(), 1.0);
  const Eigen::Vector3d line_in_1 = fundamental_.transpose() * x0;  // l1 = F^T x0
  const double norm = std::sqrt(line_in_1.x() * line_in_1.x() + line_in_1.y() * line_in_1.y());
  if (!(norm > 0)) return 0.0;
  return line_in_1.dot(x1) / norm;
}

std::optional<Eigen::Vector3d> TwoViewTriangulator::Midpoint(const Eigen::Vector2d& xy0,
                                                             const Eigen::Vector2d& xy1) const {
  return MidpointOfRays(view0_.RayInRig(xy0), view1_.RayInRig(xy1));
}

std::optional<Eigen::Vector3d> TwoViewTriangulator::Dlt(const Eigen::Vector2d& xy0,
                                                        const Eigen::Vector2d& xy1) const {
  if (!(SinAngle(xy0, xy1) > 1e-12)) return std::nullopt;
  Eigen::Matrix4d a;
  a.row(0) = xy0.x() * proj0_.row(2) - proj0_.row(0);
  a.row(1) = xy0.y() * proj0_.row(2) - proj0_.row(1);
  a.row(2) = xy1.x() * proj1_.row(2) - proj1_.row(0);
  a.row(3) = xy1.y() * proj1_.row(2) - proj1_.row(1);
  // Rows in pixel units (times the focal length), as the textbook DLT on pixel coordinates: the
  // algebraic residual of each row is then its image error in pixels times the point's depth.
  a.topRows<2>() *= view0_.focal_px;
  a.bottomRows<2>() *= view1_.focal_px;
  // Inhomogeneous form (X = (X, Y, Z, 1)): least squares A3 X = -a4 by the 3x3 normal equations.
  const Eigen::Matrix<double, 4, 3> a3 = a.leftCols<3>();
  const Eigen::Matrix3d normal = a3.transpose() * a3;
  const Eigen::Vector3d rhs = -(a3.transpose() * a.col(3));
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(normal);
  if (ldlt.info() != Eigen::Success ||
      !(ldlt.vectorD().minCoeff() > 1e-12 * ldlt.vectorD().maxCoeff())) {
    return std::nullopt;
  }
  const Eigen::Vector3d point = ldlt.solve(rhs);
  if (!point.allFinite()) return std::nullopt;
  return point;
}

bool TwoViewTriangulator::CorrectNiter2(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1,
                                        Eigen::Vector2d* corrected0,
                                        Eigen::Vector2d* corrected1) const {
  // Lindstrom 2010, algorithm niter2, with x = view 0 and x' = view 1 in noise-scaled coordinates.
  const double f0 = scale0_, f1 = scale1_;
  const Eigen::Vector3d x(f0 * xy0.x(), f0 * xy0.y(), 1.0);
  const Eigen::Vector3d xp(f1 * xy1.x(), f1 * xy1.y(), 1.0);
  const Eigen::Matrix3d& e = weighted_fundamental_;
  const Eigen::Matrix2d e_tilde = e.topLeftCorner<2, 2>();
  Eigen::Vector2d n = (e * xp).head<2>();
  Eigen::Vector2d np = (e.transpose() * x).head<2>();
  const double a = n.dot(e_tilde * np);
  const double b = 0.5 * (n.squaredNorm() + np.squaredNorm());
  const double c = x.dot(e * xp);
  const double disc = b * b - a * c;
  if (!(disc >= 0)) return false;
  const double d = std::sqrt(disc);
  if (!(b + d > 0)) return false;
  double lambda = c / (b + d);
  Eigen::Vector2d dx = lambda * n;
  Eigen::Vector2d dxp = lambda * np;
  n -= e_tilde * dxp;
  np -= e_tilde.transpose() * dx;
  const double nn = n.squaredNorm() + np.squaredNorm();
  if (nn > 0) lambda *= 2.0 * d / nn;
  dx = lambda * n;
  dxp = lambda * np;
  *corrected0 = (x.head<2>() - dx) / f0;
  *corrected1 = (xp.head<2>() - dxp) / f1;
  return corrected0->allFinite() && corrected1->allFinite();
}

std::optional<Eigen::Vector3d> TwoViewTriangulator::Optimal(const Eigen::Vector2d& xy0,
                                                            const Eigen::Vector2d& xy1) const {
  Eigen::Vector2d c0, c1;
  if (!CorrectNiter2(xy0, xy1, &c0, &c1)) return std::nullopt;
  // The corrected rays intersect (to rounding); their midpoint is the intersection.
  return Midpoint(c0, c1);
}

std::optional<Eigen::Vector3d> TwoViewTriangulator::Triangulate(const Eigen::Vector2d& xy0,
                                                                const Eigen::Vector2d& xy1,
                                                                TriangulationMethod method) const {
  switch (method) {
    case TriangulationMethod::kMidpoint:
      return Midpoint(xy0, xy1);
    case TriangulationMethod::kDlt:
      return Dlt(xy0, xy1);
    case TriangulationMethod::kOptimal:
      return Optimal(xy0, xy1);
  }
  return std::nullopt;
}

std::optional<Eigen::Vector3d> TriangulateRayAxis(const Eigen::Vector3d& center_in_rig,
                                                  const Eigen::Vector3d& ray_in_rig,
                                                  const CameraModel& projector,
                                                  const TriangulationView& projector_view, int axis,
                                                  double proj_coord_px, double* sin_angle) {
  SLSHADOW_CHECK(axis == 0 || axis == 1);
  const double* p = projector.params.data();
  const double f = axis == 0 ? p[CameraModel::kFx] : p[CameraModel::kFy];
  const double c = axis == 0 ? p[CameraModel::kCx] : p[CameraModel::kCy];
  // Point on the ray in the projector frame: q(s) = a + s * b.
  const Eigen::Vector3d a = projector_view.ToCam(center_in_rig);
  const Eigen::Vector3d b = projector_view.cam_from_rig_rotation * ray_in_rig;
  // Start: the undistorted plane  q[axis] - m q.z = 0.
  const double m = (proj_coord_px - c) / f;
  const double denom = b[axis] - m * b.z();
  if (!(std::abs(denom) > 1e-300)) return std::nullopt;
  if (sin_angle) {
    // The undistorted plane's normal (e_axis - m e_z); refined at the solution below.
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    n[axis] = 1;
    n.z() = -m;
    *sin_angle = std::abs(n.dot(b)) / (n.norm() * b.norm());
  }
  double s = -(a[axis] - m * a.z()) / denom;
  if (!std::isfinite(s)) return std::nullopt;
  const double k1 = p[CameraModel::kK1], k2 = p[CameraModel::kK2], p1 = p[CameraModel::kP1],
               p2 = p[CameraModel::kP2], k3 = p[CameraModel::kK3];
  const bool distorted = projector.HasDistortion();
  double gx = 0, gy = 0;  // d coord / d (x, y) at the solution
  bool converged = false;
  for (int it = 0; it < 20; ++it) {
    const Eigen::Vector3d q = a + s * b;
    if (!(q.z() > 0)) return std::nullopt;
    const double x = q.x() / q.z(), y = q.y() / q.z();
    double value, dvx, dvy;
    if (distorted) {
      const double r2 = x * x + y * y;
      const double radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3));
      const double dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2);
      if (axis == 0) {
        value = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x);
        dvx = radial + 2 * x * x * dradial + 2 * p1 * y + 6 * p2 * x;
        dvy = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y;
      } else {
        value = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y;
        dvx = 2 * x * y * dradial + 2 * p1 * x + 2 * p2 * y;
        dvy = radial + 2 * y * y * dradial + 6 * p1 * y + 2 * p2 * x;
      }
    } else {
      value = axis == 0 ? x : y;
      dvx = axis == 0 ? 1 : 0;
      dvy = axis == 0 ? 0 : 1;
    }
    const double residual = f * value + c - proj_coord_px;
    const double dx_ds = (b.x() * q.z() - q.x() * b.z()) / (q.z() * q.z());
    const double dy_ds = (b.y() * q.z() - q.y() * b.z()) / (q.z() * q.z());
    const double deriv = f * (dvx * dx_ds + dvy * dy_ds);
    gx = dvx;
    gy = dvy;
    if (std::abs(residual) < 1e-9) {
      converged = true;
      break;
    }
    if (!(std::abs(deriv) > 0)) return std::nullopt;
    const double step = residual / deriv;
    s -= step;
    if (!std::isfinite(s)) return std::nullopt;
    if (std::abs(step) < 1e-13 * (1 + std::abs(s))) {
      converged = true;
      break;
    }
  }
  if (!converged || !(s > 0)) return std::nullopt;
  const Eigen::Vector3d q = a + s * b;
  if (!(q.z() > 0)) return std::nullopt;
  if (sin_angle) {
    // Normal of the coded surface: gradient of the coordinate with respect to q.
    const Eigen::Vector3d grad_q(gx / q.z(), gy / q.z(),
                                 -(gx * q.x() + gy * q.y()) / (q.z() * q.z()));
    const double gn = grad_q.norm(), bn = b.norm();
    *sin_angle = gn > 0 && bn > 0 ? std::abs(grad_q.dot(b)) / (gn * bn) : 0.0;
  }
  return center_in_rig + s * ray_in_rig;
}

}  // namespace slshadow
