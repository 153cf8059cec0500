// Pinhole camera with OpenCV's Brown-Conrady distortion, used for cameras and, as an inverse
// camera, for the projector (whose "image" is the pattern).
//
// Pixel convention (OpenCV's): integer coordinates are pixel centres, (0,0) is the centre of the
// top-left pixel, x right, y down. Camera frame: x right, y down, z forward (optical axis).
//
// Model, with (X, Y, Z) a point in the camera frame, Z > 0:
//   x = X/Z, y = Y/Z, r2 = x^2 + y^2
//   radial = 1 + k1 r2 + k2 r2^2 + k3 r2^3
//   xd = x radial + 2 p1 x y + p2 (r2 + 2 x^2)
//   yd = y radial + p1 (r2 + 2 y^2) + 2 p2 x y
//   u = fx xd + cx,  v = fy yd + cy
// exactly cv::projectPoints with distCoeffs (k1, k2, p1, p2, k3), so numbers from
// cv::calibrateCamera can be pasted in and out.
#pragma once

#include <array>
#include <optional>
#include <string>

#include <Eigen/Core>

namespace slshadow {

class CameraModel {
 public:
  // Flat parameter layout, also the Ceres parameter block: fx, fy, cx, cy, k1, k2, p1, p2, k3.
  static constexpr int kNumParams = 9;
  enum Index { kFx = 0, kFy, kCx, kCy, kK1, kK2, kP1, kP2, kK3 };

  CameraModel() = default;
  CameraModel(int width_px, int height_px, double fx, double fy, double cx, double cy,
              double k1 = 0, double k2 = 0, double p1 = 0, double p2 = 0, double k3 = 0);

  int width = 0;   // image width in pixels
  int height = 0;  // image height in pixels
  std::array<double, kNumParams> params{};

  double fx() const { return params[kFx]; }
  double fy() const { return params[kFy]; }
  double cx() const { return params[kCx]; }
  double cy() const { return params[kCy]; }
  double k1() const { return params[kK1]; }
  double k2() const { return params[kK2]; }
  double p1() const { return params[kP1]; }
  double p2() const { return params[kP2]; }
  double k3() const { return params[kK3]; }
  bool HasDistortion() const;

  // Throws slshadow::Error naming `what` (e.g. "rig.yaml: cameras[0]") when a parameter is
  // non-finite, a focal length is not positive or the image size is not positive.
  void Check(const std::string& what) const;

  // Distortion of normalised coordinates (x, y) -> (xd, yd). Templated for Ceres Jets.
  template <typename T>
  static void Distort(const T* params, const T& x, const T& y, T* xd, T* yd);

  // Camera frame -> pixel. Templated for Ceres; no check of Z > 0.
  template <typename T>
  static void ImgFromCam(const T* params, const T* point_in_cam, T* pixel);

  // Camera frame -> pixel; std::nullopt when the point is not in front of the camera (Z <= 0).
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& point_in_cam) const;

  // Pixel -> undistorted normalised coordinates (x, y) with Z = 1, by Newton iteration on the
  // distortion. std::nullopt when the iteration does not converge to 1e-12 within
  // max_iterations, or converges where the distortion folds over (Jacobian determinant <= 0):
  // such a pixel is not an image of any point in front of the lens.
  std::optional<Eigen::Vector2d> UndistortToNormalized(const Eigen::Vector2d& pixel,
                                                       int max_iterations = 50) const;

  // Pixel -> unit-length viewing ray in the camera frame (Z > 0), or std::nullopt as above.
  std::optional<Eigen::Vector3d> Unproject(const Eigen::Vector2d& pixel) const;

  // Horizontal and vertical field of view in radians, measured through the image edges' centres.
  double HorizontalFovRad() const;
  double VerticalFovRad() const;

  bool IsInImage(const Eigen::Vector2d& pixel) const {
    return pixel.x() >= -0.5 && pixel.y() >= -0.5 && pixel.x() < width - 0.5 &&
           pixel.y() < height - 0.5;
  }
};

template <typename T>
void CameraModel::Distort(const T* params, const T& x, const T& y, T* xd, T* yd) {
  const T& k1 = params[kK1];
  const T& k2 = params[kK2];
  const T& p1 = params[kP1];
  const T& p2 = params[kP2];
  const T& k3 = params[kK3];
  const T x2 = x * x;
  const T y2 = y * y;
  const T xy = x * y;
  const T r2 = x2 + y2;
  const T radial = T(1) + r2 * (k1 + r2 * (k2 + r2 * k3));
  *xd = x * radial + T(2) * p1 * xy + p2 * (r2 + T(2) * x2);
  *yd = y * radial + p1 * (r2 + T(2) * y2) + T(2) * p2 * xy;
}

template <typename T>
void CameraModel::ImgFromCam(const T* params, const T* point_in_cam, T* pixel) {
  const T x = point_in_cam[0] / point_in_cam[2];
  const T y = point_in_cam[1] / point_in_cam[2];
  T xd, yd;
  Distort(params, x, y, &xd, &yd);
  pixel[0] = params[kFx] * xd + params[kCx];
  pixel[1] = params[kFy] * yd + params[kCy];
}

}  // namespace slshadow
