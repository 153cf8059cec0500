#include "reconstruct/reconstruct.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <optional>
#include <sstream>
#include <utility>

#include "core/config.h"
#include "core/error.h"
#include "core/stage_meter.h"
#include "reconstruct/filters.h"
#include "reconstruct/ray_cache.h"
#include "reconstruct/stereo_matcher.h"

namespace slshadow {

namespace {

// Per-thread buffers reused by the next reconstruction on the same thread (fresh pages cost page
// faults); ReleaseReconstructionBuffers frees the calling thread's. (Referenced, not named, inside
// parallel bodies: a worker naming a thread_local gets its own.)
thread_local std::vector<float> reproj_buffer, epi_buffer;
thread_local std::vector<Eigen::Vector3f> normals_buffer;
thread_local RectifiedMap left_buffer, right_buffer;
thread_local StereoMatches matches_buffer;

constexpr uint8_t Code(RejectReason r) { return static_cast<uint8_t>(r); }

inline double ReadCoord(const cv::Mat& m, int x, int y) {
  return m.depth() == CV_64F ? m.at<double>(y, x) : static_cast<double>(m.at<float>(y, x));
}

void CheckMap(const ProjectorMap& map, const RigDevice& camera) {
  SLSHADOW_THROW_IF(map.width() != camera.model.width || map.height() != camera.model.height,
                    "reconstruct: camera '", camera.name, "': projector map is ", map.width(), "x",
                    map.height(), " but the camera is ", camera.model.width, "x",
                    camera.model.height);
  SLSHADOW_THROW_IF(!map.has_x && !map.has_y, "reconstruct: camera '", camera.name,
                    "': the projector map codes neither projector columns nor rows");
  auto check = [&](const cv::Mat& m, const char* name, bool coded) {
    if (!coded) return;
    SLSHADOW_THROW_IF(m.rows != map.height() || m.cols != map.width() || m.channels() != 1 ||
                          (m.depth() != CV_32F && m.depth() != CV_64F),
                      "reconstruct: camera '", camera.name, "': ", name,
                      " must be a single-channel CV_32F or CV_64F image of the camera's size");
  };
  check(map.proj_x, "proj_x", map.has_x);
  check(map.proj_y, "proj_y", map.has_y);
  SLSHADOW_THROW_IF(map.status.type() != CV_8UC1, "reconstruct: camera '", camera.name,
                    "': status must be CV_8UC1");
  SLSHADOW_THROW_IF(map.quality.type() != CV_32FC1 || map.quality.size() != map.status.size(),
                    "reconstruct: camera '", camera.name,
                    "': quality must be CV_32FC1 of the camera's size");
}

double FocalOf(const CameraModel& m) { return 0.5 * (m.fx() + m.fy()); }

// A device's pixel -> normalised coordinates for the dense loop: the bilinear interpolation of the
// device's RayGrid, then one Newton step on the distortion (as UndistortFrom). The interpolation
// is off by ~1e-9 (the grid spacing squared times the distortion's curvature) and Newton's method
// converges quadratically, so after a step below 1e-7 the remaining error is ~1e-14 or less; a
// larger step, a start next to an invalid or outside the grid, or a fold of the distortion falls
// back to the full iteration (UndistortWithGrid).
class GridUndistorter {
 public:
  GridUndistorter(const CameraModel& model, const RayGrid& grid) : model_(model), grid_(grid) {
    const double* p = model.params.data();
    fx_ = p[CameraModel::kFx], fy_ = p[CameraModel::kFy], cx_ = p[CameraModel::kCx],
    cy_ = p[CameraModel::kCy];
    k1_ = p[CameraModel::kK1], k2_ = p[CameraModel::kK2], p1_ = p[CameraModel::kP1],
    p2_ = p[CameraModel::kP2];
    k3_ = p[CameraModel::kK3];
    distorted_ = model.HasDistortion();
  }

  bool operator()(double px, double py, double* xo, double* yo) const {
    const double tx = (px - cx_) / fx_, ty = (py - cy_) / fy_;
    if (!distorted_) {
      *xo = tx;
      *yo = ty;
      return true;
    }
    if (px >= 0 && py >= 0 && px < grid_.width - 1 && py < grid_.height - 1) {
      const int x0 = static_cast<int>(px), y0 = static_cast<int>(py);
      const double ax = px - x0, ay = py - y0;
      const Eigen::Vector2d* row0 = grid_.xy.data() + static_cast<size_t>(y0) * grid_.width + x0;
      const Eigen::Vector2d* row1 = row0 + grid_.width;
      const double x = (1 - ay) * ((1 - ax) * row0[0].x() + ax * row0[1].x()) +
                       ay * ((1 - ax) * row1[0].x() + ax * row1[1].x());
      const double y = (1 - ay) * ((1 - ax) * row0[0].y() + ax * row0[1].y()) +
                       ay * ((1 - ax) * row1[0].y() + ax * row1[1].y());
      if (std::isfinite(x) && std::isfinite(y)) {
        const double x2 = x * x, y2 = y * y, r2 = x2 + y2;
        const double radial = 1 + r2 * (k1_ + r2 * (k2_ + r2 * k3_));
        const double dradial = k1_ + r2 * (2 * k2_ + 3 * k3_ * r2);
        const double rx = x * radial + 2 * p1_ * x * y + p2_ * (r2 + 2 * x2) - tx;
        const double ry = y * radial + p1_ * (r2 + 2 * y2) + 2 * p2_ * x * y - ty;
        const double a = radial + 2 * x2 * dradial + 2 * p1_ * y + 6 * p2_ * x;
        const double b = 2 * x * y * dradial + 2 * p1_ * x + 2 * p2_ * y;
        const double d = radial + 2 * y2 * dradial + 6 * p1_ * y + 2 * p2_ * x;
        const double det = a * d - b * b;
        if (det > 0) {
          const double sx = (d * rx - b * ry) / det, sy = (a * ry - b * rx) / det;
          if (std::abs(sx) < 1e-7 && std::abs(sy) < 1e-7) {
            *xo = x - sx;
            *yo = y - sy;
            return true;
          }
        }
      }
    }
    const auto xy = UndistortWithGrid(model_, grid_, Eigen::Vector2d(px, py));
    if (!xy) return false;
    *xo = xy->x();
    *yo = xy->y();
    return true;
  }

 private:
  const CameraModel& model_;
  const RayGrid& grid_;
  double fx_, fy_, cx_, cy_, k1_, k2_, p1_, p2_, k3_;
  bool distorted_;
};

// The residual gates of accepted cell i, whose |epipolar error| is `abs_epipolar_px` (NaN: none).
inline void ApplyGates(const ReconstructOptions& options, float abs_epipolar_px, size_t i,
                       DenseGrid* grid) {
  if (!(grid->reprojection_error_px[i] <= options.max_reprojection_error_px)) {
    grid->reason[i] = Code(RejectReason::kReprojectionError);
  } else if (abs_epipolar_px > options.max_epipolar_error_px) {
    grid->reason[i] = Code(RejectReason::kEpipolarError);
  }
}

// Residual statistics (options.report_residuals), gates, filters, normals and the cloud: the part
// both modes share.
void Finish(const ReconstructOptions& options, size_t max_cloud_points, Reconstruction* out) {
  DenseGrid& grid = out->grid;
  ReconstructSummary& s = out->summary;
  StageTimer t0;
  const int w = grid.width, h = grid.height;
  if (!options.report_residuals) {
    // The gates alone, without the residuals' statistics (left empty in the summary).
    cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        for (size_t i = grid.Index(0, v), end = i + static_cast<size_t>(w); i < end; ++i) {
          if (grid.Accepted(i)) ApplyGates(options, std::abs(grid.epipolar_error_px[i]), i, &grid);
        }
      }
    });
  } else {
    // Per-thread buffers (see reproj_buffer above).
    std::vector<float>& reproj = reproj_buffer;
    std::vector<float>& epi = epi_buffer;
    // The residuals of the accepted cells in row-major order, gathered row-parallel: rows are
    // counted, then filled at their prefix offsets while the gates are applied.
    std::vector<std::array<size_t, 2>> row_start(static_cast<size_t>(h) + 1, {0, 0});
    cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        size_t n = 0, ne = 0;
        for (size_t i = grid.Index(0, v), end = i + static_cast<size_t>(w); i < end; ++i) {
          if (!grid.Accepted(i)) continue;
          ++n;
          ne += std::isfinite(grid.epipolar_error_px[i]) ? 1 : 0;
        }
        row_start[static_cast<size_t>(v) + 1] = {n, ne};
      }
    });
    for (size_t v = 0; v < static_cast<size_t>(h); ++v) {
      row_start[v + 1][0] += row_start[v][0];
      row_start[v + 1][1] += row_start[v][1];
    }
    reproj.resize(row_start.back()[0]);
    epi.resize(row_start.back()[1]);
    cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
      for (int v = rows.start; v < rows.end; ++v) {
        size_t k = row_start[static_cast<size_t>(v)][0], ke = row_start[static_cast<size_t>(v)][1];
        for (size_t i = grid.Index(0, v), end = i + static_cast<size_t>(w); i < end; ++i) {
          if (!grid.Accepted(i)) continue;
          reproj[k++] = grid.reprojection_error_px[i];
          const float epipolar = std::abs(grid.epipolar_error_px[i]);  // signed in the grid
          if (std::isfinite(epipolar)) epi[ke++] = epipolar;
          ApplyGates(options, epipolar, i, &grid);
        }
      }
    });
    cv::parallel_for_(cv::Range(0, 2), [&](const cv::Range& r) {
      for (int k = r.start; k < r.end; ++k) {
        if (k == 0) s.reprojection_error_px = ComputeResidualStats(std::move(reproj));
        if (k == 1) s.epipolar_error_px = ComputeResidualStats(std::move(epi));
      }
    });
  }
  if (options.filter_depth_discontinuities) {
    FilterDepthDiscontinuities(grid, options.max_depth_jump_footprints,
                               options.discontinuity_dilation_px);
  }
  if (options.filter_outliers) {
    FilterStatisticalOutliers(grid, options.outlier_window_radius_px, options.outlier_neighbors,
                              options.outlier_std_ratio, options.outlier_min_distance_footprints);
  }
  t0.Elapsed(&s.filter_s, &s.filter_cpu_s);
  t0.Restart();
  std::vector<Eigen::Vector3f>& normals = normals_buffer;
  if (options.estimate_normals) EstimateNormals(grid, &normals, &s.normal_fallbacks);
  out->cloud = grid.ToPointCloud(options.estimate_normals ? &normals : nullptr, max_cloud_points);
  t0.Elapsed(&s.normals_s, &s.normals_cpu_s);
  s.grid_width = grid.width;
  s.grid_height = grid.height;
  s.cells = static_cast<int64_t>(grid.reason.size());
  s.rejected = grid.CountByReason();
  s.points = s.rejected[0];
}

}  // namespace

namespace {

// The calibration check (calibration_check.h) of per-cell signed residuals `residual_px` (the
// grid's epipolar errors, or the projector error of one-axis stereo), at the reference camera's
// source pixels in normalised coordinates scaled to +-1 across its width. `reason_unavailable`
// non-empty: the mode leaves no residual; the check says why. Not run (and says so) when
// options.report_residuals is false.
void RunCalibrationCheck(const ReconstructOptions& options, const DenseGrid& grid,
                         const std::vector<float>& residual_px, const CameraModel& reference,
                         const CalibrationCheckSetup& setup, const std::string& reason_unavailable,
                         ReconstructSummary* s) {
  if (!options.report_residuals) {
    s->calibration_check =
        UnavailableCalibrationCheck(setup.pair, "the reconstruct option report_residuals is false");
    return;
  }
  if (!reason_unavailable.empty()) {
    s->calibration_check = UnavailableCalibrationCheck(setup.pair, reason_unavailable);
    return;
  }
  const double half_width = 0.5 * reference.width, aspect = reference.fx() / reference.fy();
  std::vector<float> x, y, e;
  std::vector<double> range_mm;
  for (size_t i = 0; i < residual_px.size(); ++i) {
    if (!std::isfinite(residual_px[i])) continue;
    x.push_back(static_cast<float>((grid.source_u[i] - reference.cx()) / half_width));
    y.push_back(static_cast<float>((grid.source_v[i] - reference.cy()) / half_width * aspect));
    e.push_back(residual_px[i]);
    if (e.size() % 16 == 0 && grid.point_in_rig[i].allFinite())
      range_mm.push_back((grid.point_in_rig[i] - grid.viewpoint_in_rig).norm());
  }
  // The working distance of this scan: the median range of its points (the rig file's nominal
  // working_distance_mm when too few).
  CalibrationCheckSetup at = setup;
  if (range_mm.size() >= 10) {
    std::nth_element(range_mm.begin(),
                     range_mm.begin() + static_cast<std::ptrdiff_t>(range_mm.size() / 2),
                     range_mm.end());
    at.working_distance_mm = range_mm[range_mm.size() / 2];
  }
  // setup.mm_per_px holds 1 / (f B) until the distance is known.
  at.mm_per_px = setup.mm_per_px * at.working_distance_mm * at.working_distance_mm;
  s->calibration_check = FitCalibrationCheck(x, y, e, at);
  if (s->calibration_check.warn) s->warnings.push_back(s->calibration_check.Message());
}

// The local field of the fitted projector error: blocks across the image width.
constexpr int kFittedProjectorBlocks = 16;
// Its automatic threshold in units of calibration_noise_factor x the noise: the RMS over all the
// points is diluted by the parts of the scene a fitted projector explains whatever the rig (a
// plane), so a quarter of the noise, and a quarter of the floor (margins:
// docs/benchmarks/log/calibration-check-one-axis.md).
constexpr double kFittedProjectorNoiseFactor = 0.25;

CalibrationCheckSetup CheckSetup(const ReconstructOptions& options, const Rig& rig,
                                 const RigDevice& a, const RigDevice& b, bool stereo) {
  CalibrationCheckSetup setup;
  setup.pair = a.name + "-" + b.name;
  setup.stereo = stereo;
  setup.warning_px = options.calibration_warning_px;
  setup.noise_factor = options.calibration_noise_factor;
  setup.min_warning_px = options.calibration_min_warning_px;
  setup.working_distance_mm = rig.working_distance_mm;
  const double baseline_mm = (a.CenterInRig() - b.CenterInRig()).norm();
  if (rig.projector && baseline_mm > 0)
    setup.mm_per_px = 1.0 / (FocalOf(rig.projector->model) * baseline_mm);
  return setup;
}

}  // namespace

Reconstruction ReconstructWithProjector(const Rig& rig, const std::string& camera_name,
                                        const ProjectorMap& map, const ReconstructOptions& options,
                                        size_t max_cloud_points) {
  options.Check();
  const StageTimer start;
  SLSHADOW_THROW_IF(!rig.projector, "reconstruct: rig '", rig.name,
                    "' has no projector (projector mode needs one)");
  const RigDevice& cam = rig.Camera(camera_name);
  const RigDevice& proj = *rig.projector;
  CheckMap(map, cam);
  Reconstruction out;
  ReconstructSummary& s = out.summary;
  s.mode = ReconstructMode::kProjector;
  s.method = options.method;
  s.camera = cam.name;
  s.other_device = proj.name;
  s.decode_status = map.CountByStatus();

  StageTimer t0;
  const std::shared_ptr<const RayGrid> rays = CachedRayGrid(cam.model);
  const bool both = map.has_x && map.has_y;
  // Projector pixels are undistorted per camera pixel, started from the projector's own grid.
  const std::shared_ptr<const RayGrid> proj_rays = both ? CachedRayGrid(proj.model) : nullptr;
  t0.Elapsed(&s.rays_s, &s.rays_cpu_s);

  t0.Restart();
  const TriangulationView cam_view(cam.cam_from_rig, FocalOf(cam.model));
  const TriangulationView proj_view(proj.cam_from_rig, FocalOf(proj.model));
  const TwoViewTriangulator tri(cam_view, proj_view, options.reference_noise_ratio, 1.0);
  DenseGrid& grid = out.grid;
  grid.Allocate(cam.model.width, cam.model.height);
  grid.viewpoint_in_rig = cam_view.center_in_rig;
  grid.focal_px = cam_view.focal_px;
  const double sin_min = std::sin(options.min_triangulation_angle_deg * M_PI / 180.0);
  const int axis = map.has_x ? 0 : 1;
  const bool midpoint = options.method == TriangulationMethod::kMidpoint;
  const double* cam_params = cam.model.params.data();
  const double* proj_params = proj.model.params.data();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::optional<GridUndistorter> proj_undistort;
  if (both) proj_undistort.emplace(proj.model, *proj_rays);
  // The midpoint in the camera frame (the camera centre at the origin, its ray (x, y, 1)): the
  // projector's rotation and centre relative to the camera, and the camera's pose for the output.
  const Eigen::Matrix3d& rc = cam_view.cam_from_rig_rotation;
  const Eigen::Vector3d& tc = cam_view.cam_from_rig_translation;
  const Eigen::Matrix3d r_pc = proj_view.cam_from_rig_rotation * rc.transpose();  // proj_from_cam
  const Eigen::Vector3d t_pc = proj_view.cam_from_rig_translation - r_pc * tc;
  const Eigen::Matrix3d r_cp = r_pc.transpose();
  const Eigen::Vector3d proj_center = -(r_cp * t_pc);  // in the camera frame
  const Eigen::Matrix3d rig_from_cam = rc.transpose();
  const double sin2_min = sin_min * sin_min;
  cv::parallel_for_(cv::Range(0, grid.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      const uint8_t* status = map.status.ptr<uint8_t>(v);
      const float* quality = map.quality.ptr<float>(v);
      for (int u = 0; u < grid.width; ++u) {
        const size_t i = grid.Index(u, v);
        grid.source_u[i] = static_cast<float>(u);
        grid.source_v[i] = static_cast<float>(v);
        if (status[u] != static_cast<uint8_t>(PixelStatus::kValid)) continue;  // kNotDecoded
        grid.quality[i] = quality[u];
        const double px = map.has_x ? ReadCoord(map.proj_x, u, v) : nan;
        const double py = map.has_y ? ReadCoord(map.proj_y, u, v) : nan;
        if ((map.has_x && !std::isfinite(px)) || (map.has_y && !std::isfinite(py))) continue;
        uint8_t& reason = grid.reason[i];
        if (quality[u] < options.min_quality) {
          reason = Code(RejectReason::kLowQuality);
          continue;
        }
        const Eigen::Vector2d& xy = rays->at(u, v);
        if (!std::isfinite(xy.x())) {
          reason = Code(RejectReason::kNoRay);
          continue;
        }
        Eigen::Vector3d point, in_cam, in_proj;
        double epipolar = nan;
        if (both) {
          Eigen::Vector2d pxy;
          if (!(*proj_undistort)(px, py, &pxy.x(), &pxy.y())) {
            reason = Code(RejectReason::kNoRay);
            continue;
          }
          if (midpoint) {
            // Rays c0 + s d0 (c0 = 0) and c1 + t d1 in the camera frame; the closest points'
            // midpoint (as TwoViewTriangulator::MidpointOfRays, whose denominator |d0 x d1|^2 also
            // gives the angle: sin^2 = denom / (|d0|^2 |d1|^2)).
            const double x = xy.x(), y = xy.y();
            const Eigen::Vector3d d1 = r_cp.col(0) * pxy.x() + r_cp.col(1) * pxy.y() + r_cp.col(2);
            const double a = x * x + y * y + 1, b = x * d1.x() + y * d1.y() + d1.z(),
                         c = d1.squaredNorm();
            const double d = -(x * proj_center.x() + y * proj_center.y() + proj_center.z());
            const double e = -d1.dot(proj_center);
            const double denom = a * c - b * b;
            if (!(denom >= sin2_min * a * c) || !(denom > 1e-24 * a * c)) {
              reason = Code(RejectReason::kParallelRays);
              continue;
            }
            const double s0 = (b * e - c * d) / denom, s1 = (a * e - b * d) / denom;
            in_cam = 0.5 * (Eigen::Vector3d(s0 * x, s0 * y, s0) + proj_center + s1 * d1);
            if (!in_cam.allFinite()) {
              reason = Code(RejectReason::kParallelRays);
              continue;
            }
            point = rig_from_cam * (in_cam - tc);
          } else {
            const Eigen::Vector3d d0 = cam_view.RayInRig(xy), d1 = proj_view.RayInRig(pxy);
            if (!(TwoViewTriangulator::SinAngleOfRays(d0, d1) >= sin_min)) {
              reason = Code(RejectReason::kParallelRays);
              continue;
            }
            const auto p = tri.Triangulate(xy, pxy, options.method);
            if (!p) {
              reason = Code(RejectReason::kParallelRays);
              continue;
            }
            point = *p;
            in_cam = cam_view.ToCam(point);
          }
          in_proj = r_pc * in_cam + t_pc;
          epipolar = tri.SignedEpipolarDistancePx(xy, pxy);
        } else {
          double sin_angle = 0;
          const auto p =
              TriangulateRayAxis(cam_view.center_in_rig, cam_view.RayInRig(xy), proj.model,
                                 proj_view, axis, axis == 0 ? px : py, &sin_angle);
          if (!(sin_angle >= sin_min)) {
            reason = Code(RejectReason::kParallelRays);
            continue;
          }
          if (!p) {
            reason = Code(RejectReason::kNoRay);
            continue;
          }
          point = *p;
          in_cam = cam_view.ToCam(point);
          in_proj = proj_view.ToCam(point);
        }
        if (!(in_cam.z() > 0 && in_proj.z() > 0) || !point.allFinite()) {
          reason = Code(RejectReason::kBehindDevice);
          continue;
        }
        if (in_cam.z() < options.min_depth_mm || in_cam.z() > options.max_depth_mm) {
          reason = Code(RejectReason::kOutOfDepthRange);
          continue;
        }
        double cam_px[2], proj_px[2];
        CameraModel::ImgFromCam(cam_params, in_cam.data(), cam_px);
        CameraModel::ImgFromCam(proj_params, in_proj.data(), proj_px);
        const double ec2 = (cam_px[0] - u) * (cam_px[0] - u) + (cam_px[1] - v) * (cam_px[1] - v);
        double ep2 = 0;
        if (map.has_x) ep2 += (proj_px[0] - px) * (proj_px[0] - px);
        if (map.has_y) ep2 += (proj_px[1] - py) * (proj_px[1] - py);
        grid.point_in_rig[i] = point;
        grid.reprojection_error_px[i] = static_cast<float>(std::sqrt(0.5 * (ec2 + ep2)));
        grid.epipolar_error_px[i] = static_cast<float>(epipolar);
        reason = Code(RejectReason::kAccepted);
      }
    }
  });
  t0.Elapsed(&s.triangulate_s, &s.triangulate_cpu_s);
  Finish(options, max_cloud_points, &out);
  RunCalibrationCheck(
      options, grid, grid.epipolar_error_px, cam.model, CheckSetup(options, rig, cam, proj, false),
      both ? ""
           : std::string("only projector ") + (map.has_x ? "columns" : "rows") +
                 " are coded: the one-axis triangulation meets the projector's plane exactly and "
                 "leaves no epipolar error to check, so this capture cannot reveal a wrong rig: a "
                 "projector turned about its " +
                 (map.has_x ? "y" : "x") +
                 " axis (parallel to the fringes), a projector focal length or principal point "
                 "off across the fringes, a camera bumped or a wrong baseline move the whole "
                 "cloud and leave no residual; to reveal them code projector " +
                 (map.has_x ? "rows" : "columns") +
                 " too (the epipolar error), or scan with a second camera (stereo then checks "
                 "the projector as a third view)",
      &s);
  start.Elapsed(&s.total_s, &s.total_cpu_s);
  return out;
}

StereoTriangulator::StereoTriangulator(const RigDevice& left, const RigDevice& right,
                                       const StereoRectification& rect,
                                       const ReconstructOptions& options)
    : rect_(rect),
      view0_(rect.RectCamFromRig(0), rect.focal_px),
      view1_(rect.RectCamFromRig(1), rect.focal_px),
      left_view_(left.cam_from_rig, FocalOf(left.model)),
      right_view_(right.cam_from_rig, FocalOf(right.model)),
      tri_(view0_, view1_, options.reference_noise_ratio, 1.0),
      right_from_rect_(right_view_.cam_from_rig_rotation * rect.rect_from_rig_rotation.transpose()),
      rig_from_rect_(rect.rect_from_rig_rotation.transpose()),
      left_params_(left.model.params),
      right_params_(right.model.params),
      method_(options.method),
      sin_min_(std::sin(options.min_triangulation_angle_deg * M_PI / 180.0)),
      min_depth_mm_(options.min_depth_mm),
      max_depth_mm_(options.max_depth_mm) {}

RejectReason StereoTriangulator::Triangulate(double u, double v, double ur,
                                             const Eigen::Vector2d& left_source_px,
                                             Eigen::Vector3d* point_in_rig,
                                             double* reprojection_error_px) const {
  const Eigen::Vector2d xy0 = rect_.Normalized(0, u, v);
  const Eigen::Vector2d xy1 = rect_.Normalized(1, ur, v);
  Eigen::Vector3d p, in_rect0;
  double z1 = 0;  // depth in the right rectified camera
  if (method_ == TriangulationMethod::kMidpoint) {
    // Both rectified cameras share their orientation, the baseline is their x axis and the two
    // observations share their row: the rays (x0, y, 1) and (x1, y, 1) lie in one epipolar plane
    // and meet, so the midpoint of their common perpendicular is their intersection,
    // z (x0, y, 1) in the left rectified frame with z = baseline / (x0 - x1). The angle between
    // them: |d0 x d1| = |x0 - x1| sqrt(1 + y^2).
    const double x0 = xy0.x(), x1 = xy1.x(), y = xy0.y();
    const double dx = x0 - x1;
    const double sin_angle = std::abs(dx) * std::sqrt(1 + y * y) /
                             std::sqrt((x0 * x0 + y * y + 1) * (x1 * x1 + y * y + 1));
    if (!(sin_angle >= sin_min_) || !(std::abs(dx) > 1e-12)) return RejectReason::kParallelRays;
    const double z = rect_.baseline_mm / dx;
    in_rect0 = Eigen::Vector3d(z * x0, z * y, z);
    if (!in_rect0.allFinite()) return RejectReason::kParallelRays;
    p = rig_from_rect_ * in_rect0 + rect_.center_in_rig[0];
    z1 = z;
  } else {
    const Eigen::Vector3d d0 = view0_.RayInRig(xy0), d1 = view1_.RayInRig(xy1);
    if (!(TwoViewTriangulator::SinAngleOfRays(d0, d1) >= sin_min_))
      return RejectReason::kParallelRays;
    const auto q = tri_.Triangulate(xy0, xy1, method_);
    if (!q) return RejectReason::kParallelRays;
    p = *q;
    in_rect0 = view0_.ToCam(p);
    z1 = view1_.ToCam(p).z();
  }
  const Eigen::Vector3d in_left = left_view_.ToCam(p);
  const Eigen::Vector3d in_right = right_view_.ToCam(p);
  if (!(in_rect0.z() > 0 && z1 > 0 && in_left.z() > 0 && in_right.z() > 0))
    return RejectReason::kBehindDevice;
  if (in_rect0.z() < min_depth_mm_ || in_rect0.z() > max_depth_mm_)
    return RejectReason::kOutOfDepthRange;
  // Observed positions in the original images: the left cell's source, the right match's.
  double left_px[2];
  CameraModel::ImgFromCam(left_params_.data(), in_left.data(), left_px);
  const double el2 =
      std::pow(left_px[0] - left_source_px.x(), 2) + std::pow(left_px[1] - left_source_px.y(), 2);
  double er2 = 0;  // the closed-form midpoint lies on the right ray (x1, y, 1) by construction
  if (method_ != TriangulationMethod::kMidpoint) {
    const Eigen::Vector3d right_ray = right_from_rect_ * Eigen::Vector3d(xy1.x(), xy1.y(), 1.0);
    double right_obs[2], right_px[2];
    CameraModel::ImgFromCam(right_params_.data(), right_ray.data(), right_obs);
    CameraModel::ImgFromCam(right_params_.data(), in_right.data(), right_px);
    er2 = std::pow(right_px[0] - right_obs[0], 2) + std::pow(right_px[1] - right_obs[1], 2);
  }
  *reprojection_error_px = std::sqrt(0.5 * (el2 + er2));
  *point_in_rig = p;
  return RejectReason::kAccepted;
}

double AutoCodeStepGate(const ProjectorMap& left, const ProjectorMap& right) {
  constexpr double kFloor = 4, kFactor = 3;  // 3 and 4 gave the same break points (docs/studies)
  const auto median_step = [](const ProjectorMap& map) {
    const cv::Mat* axes[2] = {map.has_x ? &map.proj_x : nullptr, map.has_y ? &map.proj_y : nullptr};
    const auto at = [](const cv::Mat& m, int y, int x) {
      return m.depth() == CV_64F ? m.at<double>(y, x) : static_cast<double>(m.at<float>(y, x));
    };
    std::vector<double> steps[2];  // to the right, below
    for (int y = 0; y + 1 < map.height(); y += 2) {
      for (int x = 0; x + 1 < map.width(); x += 2) {
        // The larger step over the coded axes; NaN when a pixel of the pair is not decoded (NaN
        // then stays, and fails the test below).
        double horizontal = 0, vertical = 0;
        for (const cv::Mat* m : axes) {
          if (!m) continue;
          const double c = at(*m, y, x);
          const double h = std::abs(at(*m, y, x + 1) - c), v = std::abs(at(*m, y + 1, x) - c);
          horizontal = std::isnan(h) ? h : std::max(horizontal, h);
          vertical = std::isnan(v) ? v : std::max(vertical, v);
        }
        if (horizontal >= 0) steps[0].push_back(horizontal);
        if (vertical >= 0) steps[1].push_back(vertical);
      }
    }
    double median = 0;  // the larger of the two directions' medians
    for (std::vector<double>& d : steps) {
      if (d.empty()) continue;
      std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(d.size() / 2), d.end());
      median = std::max(median, d[d.size() / 2]);
    }
    return median;
  };
  return std::max(kFloor, kFactor * std::max(median_step(left), median_step(right)));
}

Reconstruction ReconstructStereo(const Rig& rig, const std::string& left_name,
                                 const std::string& right_name, const ProjectorMap& left_map,
                                 const ProjectorMap& right_map, const ReconstructOptions& options,
                                 size_t max_cloud_points) {
  options.Check();
  const StageTimer start;
  const RigDevice& left = rig.Camera(left_name);
  const RigDevice& right = rig.Camera(right_name);
  SLSHADOW_THROW_IF(left.name == right.name,
                    "reconstruct: stereo needs two different cameras (got '", left.name,
                    "' twice)");
  CheckMap(left_map, left);
  CheckMap(right_map, right);
  Reconstruction out;
  ReconstructSummary& s = out.summary;
  s.mode = ReconstructMode::kStereo;
  s.method = options.method;
  s.camera = left.name;
  s.other_device = right.name;
  const auto dl = left_map.CountByStatus(), dr = right_map.CountByStatus();
  for (int k = 0; k < kNumPixelStatus; ++k)
    s.decode_status[static_cast<size_t>(k)] =
        dl[static_cast<size_t>(k)] + dr[static_cast<size_t>(k)];

  StageTimer t0;
  const StereoRectification rect = ComputeStereoRectification(left, right);
  // Per-thread buffers reused by the next stereo reconstruction (see reproj_buffer above).
  RectifiedMap& lm = left_buffer;
  RectifiedMap& rm = right_buffer;
  const bool cubic = options.stereo_interpolation == StereoInterpolation::kCubic ||
                     (options.stereo_interpolation == StereoInterpolation::kAuto &&
                      left_map.proj_x.depth() == CV_64F && right_map.proj_x.depth() == CV_64F);
  const double gate = options.max_code_step_px > 0 ? options.max_code_step_px
                                                   : AutoCodeStepGate(left_map, right_map);
  s.code_step_gate_px = gate;
  RectifyProjectorMap(rect, 0, left, left_map, gate, options.min_quality, cubic,
                      options.max_code_step_ratio, &lm);
  RectifyProjectorMap(rect, 1, right, right_map, gate, options.min_quality, cubic,
                      options.max_code_step_ratio, &rm);
  t0.Elapsed(&s.rays_s, &s.rays_cpu_s);

  t0.Restart();
  const double fb = rect.focal_px * rect.baseline_mm;
  StereoMatches& matches = matches_buffer;
  MatchRectifiedMaps(rect, lm, rm, fb / options.max_depth_mm, fb / options.min_depth_mm, gate,
                     cubic, &matches);
  t0.Elapsed(&s.match_s, &s.match_cpu_s);

  t0.Restart();
  const StereoTriangulator tri(left, right, rect, options);
  DenseGrid& grid = out.grid;
  grid.Allocate(lm.width, lm.height);
  grid.viewpoint_in_rig = rect.center_in_rig[0];
  grid.focal_px = rect.focal_px;
  const bool both_axes = lm.has_y && rm.has_y;
  // One coded axis leaves no epipolar error; a calibrated projector is then a third view: the
  // decoded projector column of the left cell minus the column the stereo point projects to.
  const bool third_view = !both_axes && rig.projector.has_value();
  // Without a projector in the rig, a 1-D projector is fitted to the stereo points and their
  // decoded columns instead (calibration_check.h, the fitted projector error).
  std::vector<float> projector_error;
  if (third_view)
    projector_error.assign(static_cast<size_t>(grid.width) * grid.height,
                           std::numeric_limits<float>::quiet_NaN());
  const double* proj_params = third_view ? rig.projector->model.params.data() : nullptr;
  cv::parallel_for_(cv::Range(0, grid.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < grid.width; ++u) {
        const size_t i = grid.Index(u, v);
        uint8_t& reason = grid.reason[i];
        reason = matches.reason[i];
        grid.quality[i] = lm.quality[i];
        grid.source_u[i] = lm.source_u[i];
        grid.source_v[i] = lm.source_v[i];
        if (reason != Code(RejectReason::kAccepted)) continue;
        const double ur = matches.right_u[i];
        Eigen::Vector3d point;
        double reprojection_error = 0;
        const RejectReason r = tri.Triangulate(
            u, v, ur, Eigen::Vector2d(lm.source_u[i], lm.source_v[i]), &point, &reprojection_error);
        if (r != RejectReason::kAccepted) {
          reason = Code(r);
          continue;
        }
        grid.reprojection_error_px[i] = static_cast<float>(reprojection_error);
        if (both_axes) {
          const double y =
              InterpolateRow(rm.proj_y.data() + rm.Index(0, v), rm.width, ur, gate, cubic);
          if (std::isfinite(y)) grid.epipolar_error_px[i] = static_cast<float>(lm.proj_y[i] - y);
        } else if (third_view) {
          const Eigen::Vector3d in_proj = rig.projector->cam_from_rig * point;
          if (in_proj.z() > 0) {
            double proj_px[2];
            CameraModel::ImgFromCam(proj_params, in_proj.data(), proj_px);
            projector_error[i] = static_cast<float>(lm.proj_x[i] - proj_px[0]);
          }
        }
        grid.point_in_rig[i] = point;
      }
    }
  });
  t0.Elapsed(&s.triangulate_s, &s.triangulate_cpu_s);
  const bool fitted_view = !both_axes && !third_view && options.report_residuals;
  OneAxisProjectorFit fit;
  if (fitted_view) {
    std::vector<Eigen::Vector3d> points;
    std::vector<double> columns;
    for (size_t i = 0; i < grid.point_in_rig.size(); ++i) {
      if (!grid.point_in_rig[i].allFinite() || !std::isfinite(lm.proj_x[i])) continue;
      points.push_back(grid.point_in_rig[i]);
      columns.push_back(lm.proj_x[i]);
    }
    fit = FitOneAxisProjector(points, columns);
    if (fit.ok) {
      projector_error.assign(grid.point_in_rig.size(), std::numeric_limits<float>::quiet_NaN());
      for (size_t i = 0; i < grid.point_in_rig.size(); ++i) {
        if (grid.point_in_rig[i].allFinite())
          projector_error[i] = static_cast<float>(lm.proj_x[i] - fit.Column(grid.point_in_rig[i]));
      }
    }
  }
  Finish(options, max_cloud_points, &out);
  CalibrationCheckSetup setup = CheckSetup(options, rig, left, right, true);
  if (third_view) {
    setup.residual = CalibrationResidual::kProjectorError;
    // The projector error's depth equivalent is along the left camera-projector baseline.
    setup.mm_per_px = 1.0 / (FocalOf(rig.projector->model) *
                             (left.CenterInRig() - rig.projector->CenterInRig()).norm());
  }
  if (fitted_view && fit.ok) {
    setup.residual = CalibrationResidual::kFittedProjectorError;
    setup.local_blocks = kFittedProjectorBlocks;
    setup.noise_factor *= kFittedProjectorNoiseFactor;
    setup.min_warning_px *= kFittedProjectorNoiseFactor;
    // The depth equivalent along the baseline of the left camera and the fitted projector.
    const double baseline_mm = fit.BaselineMm(left.CenterInRig());
    setup.mm_per_px = fit.fx > 0 && baseline_mm > 0 ? 1.0 / (fit.fx * baseline_mm) : 0;
  }
  RunCalibrationCheck(
      options, grid, !projector_error.empty() ? projector_error : grid.epipolar_error_px,
      left.model, setup,
      both_axes || third_view || fit.ok
          ? ""
          : "only projector columns are coded, the rig has no projector and no 1-D projector fits "
            "the stereo points (" +
                fit.reason +
                "): the stereo matches lie on the rectified epipolar lines by construction and "
                "leave no epipolar error to check (code projector rows, or calibrate the "
                "projector)",
      &s);
  if (fit.ok) s.calibration_check.fitted_projector = fit.Describe();
  out.projector_error_px = std::move(projector_error);
  start.Elapsed(&s.total_s, &s.total_cpu_s);
  return out;
}

void ReleaseReconstructionBuffers() {
  std::vector<float>().swap(reproj_buffer);
  std::vector<float>().swap(epi_buffer);
  std::vector<Eigen::Vector3f>().swap(normals_buffer);
  left_buffer = RectifiedMap();
  right_buffer = RectifiedMap();
  matches_buffer = StereoMatches();
  ReleaseFilterScratch();
  ClearRayCache();
  DenseGrid::ReleasePool();
}

}  // namespace slshadow
