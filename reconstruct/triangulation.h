// Two-view triangulation of one point, the geometric core of reconstruct/.
//
// A view is a device (camera or projector) with its cam_from_rig pose; an observation is the
// undistorted normalised image coordinate (x, y) of the point (the ray (x, y, 1) in the device
// frame), i.e. CameraModel::UndistortToNormalized of the pixel. Results are in the rig frame, mm.
//
// Methods (all exact for noise-free observations):
//  - kMidpoint: midpoint of the common perpendicular of the two rays (Hartley & Sturm 1997,
//  sec. 5.3;
//    the method of the structured-light benchmark in ../shared/seeds/).
//  - kDlt: linear triangulation (DLT) of the 4x4 system f [x P3 - P1; y P3 - P2] X = 0 (both
//    views, rows in pixel units), in its inhomogeneous form X = (X, Y, Z, 1) solved by linear least
//    squares (Hartley & Zisserman, 2nd ed., sec. 12.2). Minimises an algebraic error: image errors
//    weighted by the point's depth. (Not the homogeneous SVD form, which costs more per point.)
//  - kOptimal: Lindstrom's niter2 ("Triangulation made easy", CVPR 2010): the smallest correction
//    of both observations, in pixels, that satisfies the epipolar constraint exactly (to second
//    order, which equals Hartley-Sturm's optimum to machine precision in practice), then the
//    intersection of the corrected rays.
// Ray-plane (one coded projector axis): the camera ray cut with the surface of all rays through one
// projector column (or row), solved exactly against the distorted projector model by Newton's
// method on the ray parameter, started from the undistorted plane.
#pragma once

#include <cmath>
#include <optional>
#include <string>

#include <Eigen/Core>

#include "core/camera_model.h"
#include "core/rigid3.h"

namespace slshadow {

enum class TriangulationMethod { kMidpoint, kDlt, kOptimal };
std::string ToString(TriangulationMethod method);  // "midpoint", "dlt", "optimal"
// Parses the names above; throws slshadow::Error listing them on anything else.
TriangulationMethod TriangulationMethodFromString(const std::string& name);

// A device's pose, pre-multiplied for per-pixel use.
struct TriangulationView {
  Eigen::Matrix3d cam_from_rig_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d cam_from_rig_translation = Eigen::Vector3d::Zero();
  Eigen::Vector3d center_in_rig = Eigen::Vector3d::Zero();
  // Scales normalised coordinates to pixels for the optimal method: (fx + fy) / 2 of the model.
  double focal_px = 1.0;

  TriangulationView() = default;
  TriangulationView(const Rigid3d& cam_from_rig, double focal_px);
  // Ray direction (not unit length) in the rig frame through normalised coordinates (x, y).
  Eigen::Vector3d RayInRig(const Eigen::Vector2d& xy) const {
    return cam_from_rig_rotation.transpose() * Eigen::Vector3d(xy.x(), xy.y(), 1.0);
  }
  Eigen::Vector3d ToCam(const Eigen::Vector3d& point_in_rig) const {
    return cam_from_rig_rotation * point_in_rig + cam_from_rig_translation;
  }
};

// Two views and what every pair of observations shares: the fundamental matrix in
// pixel-scaled normalised coordinates (f * x, f * y, 1), with x0^T F x1 = 0.
class TwoViewTriangulator {
 public:
  // Views must have distinct centres (otherwise every point is "parallel rays"). sigma0_px and
  // sigma1_px are the observation noise of each view in its pixels; only their ratio matters, and
  // only to the optimal method, which minimises (e0 / sigma0)^2 + (e1 / sigma1)^2 over the image
  // residuals e (e.g. a reference camera pixel is exact and the decoded coordinate carries the
  // noise: sigma0 << sigma1).
  TwoViewTriangulator(const TriangulationView& view0, const TriangulationView& view1,
                      double sigma0_px = 1.0, double sigma1_px = 1.0);

  const TriangulationView& view0() const { return view0_; }
  const TriangulationView& view1() const { return view1_; }

  // The point seen at normalised coordinates xy0 in view 0 and xy1 in view 1, in the rig frame.
  // std::nullopt when the rays are parallel to machine precision (sin of the angle < 1e-12) or
  // the solution is at infinity. No check of the side of the devices: callers gate on that.
  std::optional<Eigen::Vector3d> Triangulate(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1,
                                             TriangulationMethod method) const;

  // Sine of the angle between the two viewing rays.
  double SinAngle(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1) const;

  // The same from the rays in the rig frame (view0().RayInRig(xy0), view1().RayInRig(xy1)), for
  // callers that gate on the angle and then triangulate by the midpoint: the rays are formed once.
  // Bit-identical to SinAngle and Midpoint.
  static double SinAngleOfRays(const Eigen::Vector3d& d0, const Eigen::Vector3d& d1) {
    return d0.cross(d1).norm() / (d0.norm() * d1.norm());
  }
  std::optional<Eigen::Vector3d> MidpointOfRays(const Eigen::Vector3d& d0,
                                                const Eigen::Vector3d& d1) const {
    const Eigen::Vector3d w = view0_.center_in_rig - view1_.center_in_rig;
    const double a = d0.squaredNorm(), b = d0.dot(d1), c = d1.squaredNorm();
    const double d = d0.dot(w), e = d1.dot(w);
    const double denom = a * c - b * b;  // = |d0 x d1|^2
    if (!(denom > 1e-24 * a * c)) return std::nullopt;
    const double s = (b * e - c * d) / denom;
    const double t = (a * e - b * d) / denom;
    const Eigen::Vector3d p0 = view0_.center_in_rig + s * d0;
    const Eigen::Vector3d p1 = view1_.center_in_rig + t * d1;
    const Eigen::Vector3d mid = 0.5 * (p0 + p1);
    if (!mid.allFinite()) return std::nullopt;
    return mid;
  }

  // Distance, in view 1's pixel-scaled units, of observation xy1 from the epipolar line of xy0.
  double EpipolarDistancePx(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1) const {
    return std::abs(SignedEpipolarDistancePx(xy0, xy1));
  }
  // The same with a sign: which side of the line xy1 lies on. The side is fixed by the rig (the
  // fundamental matrix), so over one reconstruction a calibration error shows as a field of one
  // sign where decoding noise averages to zero.
  double SignedEpipolarDistancePx(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1) const;

  // The individual methods.
  std::optional<Eigen::Vector3d> Midpoint(const Eigen::Vector2d& xy0,
                                          const Eigen::Vector2d& xy1) const;
  std::optional<Eigen::Vector3d> Dlt(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1) const;
  std::optional<Eigen::Vector3d> Optimal(const Eigen::Vector2d& xy0,
                                         const Eigen::Vector2d& xy1) const;
  // Lindstrom's niter2 correction alone: the corrected normalised observations.
  bool CorrectNiter2(const Eigen::Vector2d& xy0, const Eigen::Vector2d& xy1,
                     Eigen::Vector2d* corrected0, Eigen::Vector2d* corrected1) const;

 private:
  TriangulationView view0_, view1_;
  Eigen::Matrix3d fundamental_;  // pixel-scaled: x0~^T F x1~ = 0
  double scale0_,
      scale1_;  // focal / sigma: the units in which the optimal method's noise is isotropic
  Eigen::Matrix3d weighted_fundamental_;  // the same in those units
  Eigen::Matrix<double, 3, 4> proj0_, proj1_;
};

// One coded projector axis: the point on the camera ray (center_in_rig + s * ray_in_rig, s > 0)
// that the projector images at coordinate `proj_coord_px` along `axis` (0: column x, 1: row y),
// with the projector's full distortion model. Newton's method on s from the undistorted plane;
// std::nullopt when it does not converge (to 1e-9 px within 20 steps) or lands behind either
// device. `sin_angle` (optional) receives the sine of the angle between the ray and the plane
// tangent to the coded surface at the solution (0 = ray inside the plane: no depth information);
// when there is no solution it is set from the undistorted plane, so callers can tell near-parallel
// rays from other failures.
std::optional<Eigen::Vector3d> TriangulateRayAxis(const Eigen::Vector3d& center_in_rig,
                                                  const Eigen::Vector3d& ray_in_rig,
                                                  const CameraModel& projector,
                                                  const TriangulationView& projector_view, int axis,
                                                  double proj_coord_px,
                                                  double* sin_angle = nullptr);

}  // namespace slshadow
