// Stereo correspondences from two cameras' ProjectorMaps: rectify both maps to a common
// orientation (rows are epipolar lines), then find, along each row, where the right map's
// projector column equals the left one (sub-pixel, by cubic interpolation of the right map's
// samples). Used by ReconstructStereo (reconstruct.h).
//
// Rectification (Fusiello, Trucco & Verri 2000): rect x axis along the baseline (left centre to
// right centre), z the mean optical axis made orthogonal to x, y = z cross x (down). Both
// rectified cameras share the orientation, focal length and cy; each has its own cx and width so
// its rectified image covers its own camera image. Rectified pixel (u, v) is the ray
// ((u - cx) / f, (v - cy) / f, 1) in the rect frame; disparity (u_l - cx_l) - (u_r - cx_r) =
// f * baseline / z_rect.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/projector_map.h"
#include "core/rig.h"

namespace slshadow {

struct StereoRectification {
  Eigen::Matrix3d rect_from_rig_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d center_in_rig[2];  // left, right optical centres
  double baseline_mm = 0;
  double focal_px = 1;
  double cy = 0;
  int height = 0;
  double cx[2] = {0, 0};
  int width[2] = {0, 0};

  // Normalised rect-frame coordinates of rectified pixel (u, v) of camera 0 (left) or 1 (right).
  Eigen::Vector2d Normalized(int camera, double u, double v) const {
    return {(u - cx[camera]) / focal_px, (v - cy) / focal_px};
  }
  // The rectified camera's pose: rect orientation, centred on the camera's optical centre.
  Rigid3d RectCamFromRig(int camera) const;
};

// Throws slshadow::Error when the centres coincide. The rectified images keep the left camera's
// mean focal length; their extents cover each camera's image (border rays in front of the rect
// plane), clamped to max_size_factor times the camera's size.
StereoRectification ComputeStereoRectification(const RigDevice& left, const RigDevice& right,
                                               double max_size_factor = 2.0);

// One camera's ProjectorMap resampled on its rectified grid at the rectified pixel's position in
// the original, distorted image. A cell is valid only when the 4 source pixels around that position
// are decoded, of quality >= min_quality, and their projector coordinates differ by at most
// max_step_px (which keeps interpolation from bridging code jumps). The projector coordinates are
// then interpolated bicubically (4-point Lagrange in each axis, exact for cubics: the error on a
// smooth map is O(h^4) instead of bilinear O(h^2)) when the 4x4 source pixels around the position
// are all decoded and no two neighbours among them differ by more than max_step_px, bilinearly
// over the 4 otherwise; quality is interpolated bilinearly. Where each rectified cell falls in the
// original image depends on the geometry only: it is computed once per rectification and camera
// and kept in a small process-wide cache (4 grids of 16 B per rectified cell, least recently used
// first out).
struct RectifiedMap {
  int width = 0;
  int height = 0;
  bool has_y = false;
  std::vector<double> proj_x, proj_y;  // NaN where invalid (proj_y NaN when rows are not coded)
  std::vector<float> quality;
  std::vector<float> source_u, source_v;  // position in the original image, px
  std::vector<uint8_t> reason;            // RejectReason: kAccepted where valid
  size_t Index(int u, int v) const { return static_cast<size_t>(v) * width + u; }
};
// Accepts proj_x / proj_y of type CV_32F or CV_64F. Requires map.has_x.
// cubic = false: bilinear everywhere (the O(h^2) bias, but the least noise on decoded maps).
// max_step_ratio > 0: nor across a code jump below max_step_px, a step between two neighbouring
// pixels (along a row or a column) larger than 0.5 projector px and than max_step_ratio times
// each of the steps on either side of it (ReconstructOptions::max_code_step_ratio: the occlusion
// edges and the wall's foot at grazing incidence, where an interpolated code lies between two
// surfaces); 0 disables the test.
RectifiedMap RectifyProjectorMap(const StereoRectification& rect, int camera,
                                 const RigDevice& device, const ProjectorMap& map,
                                 double max_step_px, float min_quality, bool cubic = true,
                                 double max_step_ratio = 0);
// The same into `out`, reusing its buffers (every cell is written, row-parallel): a caller that
// rectifies repeatedly keeps the pages it has touched.
void RectifyProjectorMap(const StereoRectification& rect, int camera, const RigDevice& device,
                         const ProjectorMap& map, double max_step_px, float min_quality, bool cubic,
                         double max_step_ratio, RectifiedMap* out);

// The value of a rectified row (`row`, `width` samples) at fractional column u: the cubic through
// the 4 samples around u (4-point Lagrange) when they are finite and no two neighbours differ by
// more than max_step_px, else linear between the 2 around u; NaN when those are not finite or u is
// outside [0, width - 1].
// cubic = false: always linear.
double InterpolateRow(const double* row, int width, double u, double max_step_px,
                      bool cubic = true);

// For every left rectified cell with a valid code, the right rectified column u_r with equal
// projector column on the same row and disparity in [min_disparity_px, max_disparity_px]. The
// crossing is found between two right samples (linear), then refined on the cubic through the 4
// samples around it (Newton's method on the 4-point Lagrange interpolant, as InterpolateRow) when
// those are finite and free of code jumps, which makes the sub-pixel position exact to O(h^4) on
// smooth maps instead of O(h^2).
// right_u is NaN where there is none; reason says kNoMatch / kAmbiguousMatch (two or more
// distinct solutions) or carries the left cell's own reason. Segments between right samples that
// differ by more than max_step_px are not searched (code jumps).
struct StereoMatches {
  std::vector<double> right_u;
  std::vector<uint8_t> reason;
};
// cubic = false: the linear crossing only.
StereoMatches MatchRectifiedMaps(const StereoRectification& rect, const RectifiedMap& left,
                                 const RectifiedMap& right, double min_disparity_px,
                                 double max_disparity_px, double max_step_px, bool cubic = true);
// The same into `out`, reusing its buffers.
void MatchRectifiedMaps(const StereoRectification& rect, const RectifiedMap& left,
                        const RectifiedMap& right, double min_disparity_px, double max_disparity_px,
                        double max_step_px, bool cubic, StereoMatches* out);

}  // namespace slshadow
