#include "reconstruct/stereo_matcher.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <list>
#include <memory>
#include <mutex>

#include <opencv2/core.hpp>

#include "core/error.h"
#include "reconstruct/dense_grid.h"

namespace slshadow {

namespace {

constexpr uint8_t kAcceptedCode = static_cast<uint8_t>(RejectReason::kAccepted);

inline double ReadCoord(const cv::Mat& m, int x, int y) {
  return m.depth() == CV_64F ? m.at<double>(y, x) : static_cast<double>(m.at<float>(y, x));
}

// Weights of the 4-point Lagrange interpolant with nodes -1, 0, 1, 2 at t (in [0, 1] between the
// middle nodes).
inline void CubicWeights(double t, double w[4]) {
  constexpr double kSixth = 1.0 / 6;
  const double tm1 = t - 1, tm2 = t - 2, tp1 = t + 1;
  const double a = t * tm1, b = tp1 * tm2;  // the products shared by the outer and inner weights
  w[0] = -kSixth * a * tm2;
  w[1] = 0.5 * b * tm1;
  w[2] = -0.5 * b * t;
  w[3] = kSixth * a * tp1;
}

// True when the 4 samples are finite and neighbours differ by at most max_step.
inline bool SmoothRun(const double* s, double max_step) {
  for (int k = 0; k < 4; ++k) {
    if (!std::isfinite(s[k])) return false;
  }
  return std::abs(s[1] - s[0]) <= max_step && std::abs(s[2] - s[1]) <= max_step &&
         std::abs(s[3] - s[2]) <= max_step;
}

constexpr uint8_t kPairRight = 1, kPairDown = 2;

// A code jump between neighbours a and b on a line of pixels (a row or a column), p and n the
// pixels before a and after b (NaN where not decoded): the step |b - a| exceeds `floor_px` and
// `ratio` times the larger of the steps on either side of it (no side step: not a jump). A smooth
// surface changes its code step gradually from pixel to pixel, also where it turns away from the
// camera or meets another face at a crease (the step across the crease lies between those on its
// two sides); a surface behind an occluding edge, or the wall and the table at a wall's foot seen
// at grazing incidence, jumps in one step. Such a step below the code-step gate is interpolated
// across and matched otherwise: points between the two surfaces
// (docs/benchmarks/log/2026-12-07-ghost-points.md).
inline bool RelativeJump(double p, double a, double b, double n, double ratio, double floor_px) {
  const double step = std::abs(b - a);
  if (!(step > floor_px)) return false;
  const double before = std::abs(a - p), after = std::abs(n - b);
  double side = -1;
  if (std::isfinite(before)) side = before;
  if (std::isfinite(after)) side = std::max(side, after);
  return side >= 0 && step > ratio * side;
}

// Per source pixel (x, y): bit kPairRight when (x, y) and (x + 1, y) are fit neighbours to
// interpolate between, kPairDown for (x, y) and (x, y + 1): both decoded with finite
// coordinates, no coordinate differing by more than max_step, and (max_step_ratio > 0) no
// relative code jump between them (RelativeJump, floor kRelativeJumpFloorPx).
constexpr double kRelativeJumpFloorPx = 0.5;
template <typename T>
std::vector<uint8_t> FitPairs(const ProjectorMap& map, double max_step, double max_step_ratio) {
  const int w = map.width(), h = map.height();
  const size_t n = static_cast<size_t>(w) * h;
  std::vector<uint8_t> pairs(n, 0);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  constexpr auto kValid = static_cast<uint8_t>(PixelStatus::kValid);
  auto ok = [&](const uint8_t* status, const T* px, const T* py, int x) {
    return status[x] == kValid && std::isfinite(static_cast<double>(px[x])) &&
           (!py || std::isfinite(static_cast<double>(py[x])));
  };
  auto close = [&](const T* a, const T* b, int xa, int xb) {
    return !a || std::abs(static_cast<double>(a[xa]) - static_cast<double>(b[xb])) <= max_step;
  };
  // The coordinate `c` of pixel x of a row (status s), NaN where not decoded or outside.
  auto at = [&](const uint8_t* s, const T* c, int x) {
    return s && x >= 0 && x < w && s[x] == kValid ? static_cast<double>(c[x]) : nan;
  };
  const bool relative = max_step_ratio > 0;
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const uint8_t* s0 = map.status.ptr<uint8_t>(y);
      const T* x0 = map.proj_x.ptr<T>(y);
      const T* y0 = map.has_y ? map.proj_y.ptr<T>(y) : nullptr;
      const bool below = y + 1 < h;
      const uint8_t* s1 = below ? map.status.ptr<uint8_t>(y + 1) : nullptr;
      const T* x1 = below ? map.proj_x.ptr<T>(y + 1) : nullptr;
      const T* y1 = below && map.has_y ? map.proj_y.ptr<T>(y + 1) : nullptr;
      // The rows above and two below, for the vertical pairs' side steps.
      const uint8_t* sm = y > 0 ? map.status.ptr<uint8_t>(y - 1) : nullptr;
      const T* xm = y > 0 ? map.proj_x.ptr<T>(y - 1) : nullptr;
      const T* ym = y > 0 && map.has_y ? map.proj_y.ptr<T>(y - 1) : nullptr;
      const uint8_t* s2 = y + 2 < h ? map.status.ptr<uint8_t>(y + 2) : nullptr;
      const T* x2 = y + 2 < h ? map.proj_x.ptr<T>(y + 2) : nullptr;
      const T* y2 = y + 2 < h && map.has_y ? map.proj_y.ptr<T>(y + 2) : nullptr;
      uint8_t* out = pairs.data() + static_cast<size_t>(y) * w;
      for (int x = 0; x < w; ++x) {
        if (!ok(s0, x0, y0, x)) continue;
        uint8_t bits = 0;
        if (x + 1 < w && ok(s0, x0, y0, x + 1) && close(x0, x0, x, x + 1) &&
            close(y0, y0, x, x + 1)) {
          const bool jump =
              relative &&
              (RelativeJump(at(s0, x0, x - 1), x0[x], x0[x + 1], at(s0, x0, x + 2), max_step_ratio,
                            kRelativeJumpFloorPx) ||
               (y0 && RelativeJump(at(s0, y0, x - 1), y0[x], y0[x + 1], at(s0, y0, x + 2),
                                   max_step_ratio, kRelativeJumpFloorPx)));
          if (!jump) bits |= kPairRight;
        }
        if (below && ok(s1, x1, y1, x) && close(x0, x1, x, x) && close(y0, y1, x, x)) {
          const bool jump =
              relative && (RelativeJump(at(sm, xm, x), x0[x], x1[x], at(s2, x2, x), max_step_ratio,
                                        kRelativeJumpFloorPx) ||
                           (y0 && RelativeJump(at(sm, ym, x), y0[x], y1[x], at(s2, y2, x),
                                               max_step_ratio, kRelativeJumpFloorPx)));
          if (!jump) bits |= kPairDown;
        }
        out[x] = bits;
      }
    }
  });
  return pairs;
}

// Per source pixel (x0, y0), 1 when the 4x4 block x0 - 1 .. x0 + 2, y0 - 1 .. y0 + 2 is fit for
// bicubic interpolation: every horizontal and vertical pair of neighbours in it fit (FitPairs).
// Separable: runs of 3 pairs along rows and columns, then of 4 runs.
std::vector<uint8_t> SmoothBlocks(const std::vector<uint8_t>& pairs, int w, int h) {
  const size_t n = static_cast<size_t>(w) * h;
  constexpr uint8_t kRight = kPairRight, kDown = kPairDown;
  std::vector<uint8_t> runs(n, 0), blocks(n, 0);
  // runs: kRight when the 3 right-pairs from x - 1 (a row of 4) are fit, kDown when the 4
  // down-pairs of columns x - 1 .. x + 2 are.
  cv::parallel_for_(cv::Range(0, h), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const uint8_t* in = pairs.data() + static_cast<size_t>(y) * w;
      uint8_t* out = runs.data() + static_cast<size_t>(y) * w;
      for (int x = 1; x + 2 < w; ++x) {
        const uint8_t right = in[x - 1] & in[x] & in[x + 1] & kRight;
        const uint8_t down = in[x - 1] & in[x] & in[x + 1] & in[x + 2] & kDown;
        out[x] = right | down;
      }
    }
  });
  cv::parallel_for_(cv::Range(1, std::max(1, h - 2)), [&](const cv::Range& rows) {
    for (int y = rows.start; y < rows.end; ++y) {
      const uint8_t* r0 = runs.data() + static_cast<size_t>(y - 1) * w;
      const uint8_t* r1 = r0 + w;
      const uint8_t* r2 = r1 + w;
      const uint8_t* r3 = r2 + w;
      uint8_t* out = blocks.data() + static_cast<size_t>(y) * w;
      for (int x = 1; x + 2 < w; ++x) {
        out[x] =
            (r0[x] & r1[x] & r2[x] & r3[x] & kRight) && (r0[x] & r1[x] & r2[x] & kDown) ? 1 : 0;
      }
    }
  });
  return blocks;
}

// The 4x4 block of coordinate `m` around (x0, y0), row-major.
template <typename T>
void GatherBlock(const cv::Mat& m, int x0, int y0, double b[16]) {
  for (int j = 0; j < 4; ++j) {
    const T* p = m.ptr<T>(y0 - 1 + j) + (x0 - 1);
    for (int i = 0; i < 4; ++i) b[4 * j + i] = static_cast<double>(p[i]);
  }
}

inline double Bicubic(const double b[16], const double wx[4], const double wy[4]) {
  double sum = 0;
  for (int j = 0; j < 4; ++j)
    sum += wy[j] *
           (wx[0] * b[4 * j] + wx[1] * b[4 * j + 1] + wx[2] * b[4 * j + 2] + wx[3] * b[4 * j + 3]);
  return sum;
}

// The crossing of `value` by the cubic through s[0..3] (nodes -1, 0, 1, 2), started at t, the
// linear crossing between s[1] and s[2] (off by O(h^2), ~1e-3 px); t itself when the cubic is not
// monotone like the segment there or the iteration does not converge in 6 steps.
double RefineCrossing(const double s[4], double value, double t) {
  constexpr double kThird = 1.0 / 3, kSixth = 1.0 / 6;
  const double c1 = -kThird * s[0] - 0.5 * s[1] + s[2] - kSixth * s[3];
  const double c2 = 0.5 * (s[0] + s[2]) - s[1];
  const double c3 = kSixth * (s[3] - s[0]) + 0.5 * (s[1] - s[2]);
  const double slope = s[2] - s[1];
  // Newton's steps with the derivative taken once, at t (a chord iteration: one division; each
  // step shrinks the error by ~|p''/p'| times the distance from t, ~1e-5 on smooth codes).
  const double df = c1 + t * (2 * c2 + 3 * t * c3);
  if (!(df * slope > 0)) return t;  // not monotone like the segment here
  const double inv_df = 1.0 / df;
  double x = t;
  for (int it = 0; it < 6; ++it) {
    const double step = (s[1] + x * (c1 + x * (c2 + x * c3)) - value) * inv_df;
    x -= step;
    if (!(x > -0.5 && x < 1.5)) return t;
    if (std::abs(step) < 1e-11) return x;
  }
  return t;
}

// Where every rectified cell of one camera falls in its original image (the camera's distortion
// applied to the rectified ray), NaN outside the image or behind the camera. Geometry only, so it
// is computed once per rectification and camera and kept (at most kMaxCachedSourceGrids, least
// recently used first out; keyed by every number it depends on).
constexpr size_t kMaxCachedSourceGrids = 4;

std::vector<double> SourceGridKey(const StereoRectification& rect, int camera,
                                  const RigDevice& device) {
  std::vector<double> key(rect.rect_from_rig_rotation.data(),
                          rect.rect_from_rig_rotation.data() + 9);
  const Eigen::Quaterniond& q = device.cam_from_rig.rotation;
  const Eigen::Vector3d& t = device.cam_from_rig.translation;
  for (double v : {rect.focal_px, rect.cy, rect.cx[camera], static_cast<double>(rect.width[camera]),
                   static_cast<double>(rect.height), static_cast<double>(device.model.width),
                   static_cast<double>(device.model.height), q.w(), q.x(), q.y(), q.z(), t.x(),
                   t.y(), t.z()}) {
    key.push_back(v);
  }
  key.insert(key.end(), device.model.params.begin(), device.model.params.end());
  return key;
}

std::vector<Eigen::Vector2d> ComputeSourceGrid(const StereoRectification& rect, int camera,
                                               const RigDevice& device) {
  const int width = rect.width[camera], height = rect.height;
  std::vector<Eigen::Vector2d> grid(static_cast<size_t>(width) * height);
  const Eigen::Matrix3d cam_from_rect =
      device.cam_from_rig.rotation.toRotationMatrix() * rect.rect_from_rig_rotation.transpose();
  const int w = device.model.width, h = device.model.height;
  const double* params = device.model.params.data();
  const double inv_f = 1.0 / rect.focal_px;
  const double nan = std::numeric_limits<double>::quiet_NaN();
  cv::parallel_for_(cv::Range(0, height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      const double yn = (v - rect.cy) * inv_f;
      Eigen::Vector2d* out = grid.data() + static_cast<size_t>(v) * width;
      for (int u = 0; u < width; ++u) {
        out[u] = Eigen::Vector2d(nan, nan);
        const Eigen::Vector3d ray =
            cam_from_rect * Eigen::Vector3d((u - rect.cx[camera]) * inv_f, yn, 1.0);
        if (!(ray.z() > 0)) continue;
        double pixel[2];
        CameraModel::ImgFromCam(params, ray.data(), pixel);
        if (!(pixel[0] >= 0 && pixel[1] >= 0 && pixel[0] <= w - 1 && pixel[1] <= h - 1)) continue;
        out[u] = Eigen::Vector2d(pixel[0], pixel[1]);
      }
    }
  });
  return grid;
}

std::shared_ptr<const std::vector<Eigen::Vector2d>> CachedSourceGrid(
    const StereoRectification& rect, int camera, const RigDevice& device) {
  using Entry = std::pair<std::vector<double>, std::shared_ptr<const std::vector<Eigen::Vector2d>>>;
  static std::mutex mutex;
  static std::list<Entry> entries;  // most recent first
  const std::vector<double> key = SourceGridKey(rect, camera, device);
  auto same = [&](const std::vector<double>& k) {
    return k.size() == key.size() &&
           std::memcmp(k.data(), key.data(), sizeof(double) * key.size()) == 0;
  };
  {
    std::lock_guard<std::mutex> lock(mutex);
    for (auto it = entries.begin(); it != entries.end(); ++it) {
      if (same(it->first)) {
        entries.splice(entries.begin(), entries, it);
        return entries.front().second;
      }
    }
  }
  auto grid =
      std::make_shared<const std::vector<Eigen::Vector2d>>(ComputeSourceGrid(rect, camera, device));
  std::lock_guard<std::mutex> lock(mutex);
  entries.emplace_front(key, grid);
  while (entries.size() > kMaxCachedSourceGrids) entries.pop_back();
  return grid;
}

// The rows of RectifyProjectorMap for projector coordinates of type T (float or double): every
// cell of `out` (sized) from the camera pixel `sources` gives for it. Pointers and sizes in
// locals: the byte-wide `reason` writes may alias anything, which would reload them per cell.
template <typename T>
void RectifyRows(const ProjectorMap& map, const std::vector<Eigen::Vector2d>& sources,
                 double max_step_px, float min_quality, bool cubic,
                 const std::vector<uint8_t>& pairs, const std::vector<uint8_t>& blocks,
                 RectifiedMap* out_map) {
  const double nan = std::numeric_limits<double>::quiet_NaN();
  const float nanf = std::numeric_limits<float>::quiet_NaN();
  const int w = map.width(), h = map.height();
  const bool has_y = map.has_y;
  const uint8_t* const status = map.status.ptr<uint8_t>(0);
  const size_t status_step = map.status.step1();
  const T* const coord_x = map.proj_x.ptr<T>(0);
  const size_t x_step = map.proj_x.step1();
  const T* const coord_y = has_y ? map.proj_y.ptr<T>(0) : nullptr;
  const size_t y_step = has_y ? map.proj_y.step1() : 0;
  const float* const quality = map.quality.ptr<float>(0);
  const size_t q_step = map.quality.step1();
  const Eigen::Vector2d* const source_of = sources.data();
  const uint8_t* const smooth = blocks.data();
  const uint8_t* const fit = pairs.data();
  RectifiedMap& out = *out_map;
  const int out_w = out.width;
  double* const out_x = out.proj_x.data();
  double* const out_y = out.proj_y.data();
  float* const out_q = out.quality.data();
  float* const out_u = out.source_u.data();
  float* const out_v = out.source_v.data();
  uint8_t* const out_reason = out.reason.data();
  constexpr auto kValid = static_cast<uint8_t>(PixelStatus::kValid);
  cv::parallel_for_(cv::Range(0, out.height), [&](const cv::Range& rows) {
    for (int v = rows.start; v < rows.end; ++v) {
      for (int u = 0; u < out_w; ++u) {
        const size_t o = static_cast<size_t>(v) * out_w + u;
        out_x[o] = nan;
        out_y[o] = nan;
        out_q[o] = 0.0f;
        out_u[o] = nanf;
        out_v[o] = nanf;
        out_reason[o] = static_cast<uint8_t>(RejectReason::kOutsideImage);
        const Eigen::Vector2d& source = source_of[o];
        const double x = source.x(), y = source.y();
        if (!(x >= 0 && y >= 0 && x <= w - 1 && y <= h - 1)) continue;  // NaN: outside the image
        out_u[o] = static_cast<float>(x);
        out_v[o] = static_cast<float>(y);
        int x0 = static_cast<int>(x), y0 = static_cast<int>(y);
        if (x0 >= w - 1) x0 = w - 2;
        if (y0 >= h - 1) y0 = h - 2;
        const double ax = x - x0, ay = y - y0;
        const double wts[4] = {(1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
        const int xs[4] = {x0, x0 + 1, x0, x0 + 1};
        const int ys[4] = {y0, y0, y0 + 1, y0 + 1};
        RejectReason reason = RejectReason::kAccepted;
        double px = 0, py = 0, q = 0;
        double xmin = std::numeric_limits<double>::infinity(), xmax = -xmin, ymin = xmin,
               ymax = -xmin;
        for (int k = 0; k < 4; ++k) {
          const auto yk = static_cast<size_t>(ys[k]);
          const auto xk = static_cast<size_t>(xs[k]);
          if (status[yk * status_step + xk] != kValid) {
            reason = RejectReason::kNotDecoded;
            break;
          }
          const double cx = static_cast<double>(coord_x[yk * x_step + xk]);
          const double cy = has_y ? static_cast<double>(coord_y[yk * y_step + xk]) : 0.0;
          if (!std::isfinite(cx) || !std::isfinite(cy)) {
            reason = RejectReason::kNotDecoded;
            break;
          }
          const float qk = quality[yk * q_step + xk];
          if (qk < min_quality) reason = RejectReason::kLowQuality;
          xmin = std::min(xmin, cx);
          xmax = std::max(xmax, cx);
          ymin = std::min(ymin, cy);
          ymax = std::max(ymax, cy);
          px += wts[k] * cx;
          py += wts[k] * cy;
          q += wts[k] * qk;
        }
        if (reason == RejectReason::kAccepted &&
            (xmax - xmin > max_step_px || ymax - ymin > max_step_px)) {
          reason = RejectReason::kDepthDiscontinuity;
        }
        // The 4 pairs of neighbours around the position: a code jump between two of them (a
        // relative jump below the gate) is not interpolated across either.
        if (reason == RejectReason::kAccepted) {
          const size_t i0 = static_cast<size_t>(y0) * w + x0;
          if ((fit[i0] & (kPairRight | kPairDown)) != (kPairRight | kPairDown) ||
              !(fit[i0 + 1] & kPairDown) || !(fit[i0 + w] & kPairRight))
            reason = RejectReason::kDepthDiscontinuity;
        }
        out_reason[o] = static_cast<uint8_t>(reason);
        if (reason != RejectReason::kAccepted) continue;
        if (cubic && smooth[static_cast<size_t>(y0) * w + x0]) {
          double b[16], wx[4], wy[4];
          CubicWeights(ax, wx);
          CubicWeights(ay, wy);
          GatherBlock<T>(map.proj_x, x0, y0, b);
          px = Bicubic(b, wx, wy);
          if (has_y) {
            GatherBlock<T>(map.proj_y, x0, y0, b);
            py = Bicubic(b, wx, wy);
          }
        }
        out_x[o] = px;
        if (has_y) out_y[o] = py;
        out_q[o] = static_cast<float>(q);
      }
    }
  });
}

}  // namespace

double InterpolateRow(const double* row, int width, double u, double max_step_px, bool cubic) {
  if (!(u >= 0 && u <= width - 1) || width < 2) return std::numeric_limits<double>::quiet_NaN();
  const int k = std::min(static_cast<int>(u), width - 2);
  const double t = u - k;
  if (cubic && k >= 1 && k + 2 < width && SmoothRun(row + k - 1, max_step_px)) {
    double w[4];
    CubicWeights(t, w);
    return w[0] * row[k - 1] + w[1] * row[k] + w[2] * row[k + 1] + w[3] * row[k + 2];
  }
  const double y0 = row[k], y1 = row[k + 1];
  if (!std::isfinite(y0) || !std::isfinite(y1)) return std::numeric_limits<double>::quiet_NaN();
  return (1 - t) * y0 + t * y1;
}

Rigid3d StereoRectification::RectCamFromRig(int camera) const {
  const Eigen::Quaterniond q(rect_from_rig_rotation);
  return Rigid3d(q, -(rect_from_rig_rotation * center_in_rig[camera]));
}

StereoRectification ComputeStereoRectification(const RigDevice& left, const RigDevice& right,
                                               double max_size_factor) {
  StereoRectification rect;
  rect.center_in_rig[0] = left.CenterInRig();
  rect.center_in_rig[1] = right.CenterInRig();
  const Eigen::Vector3d baseline = rect.center_in_rig[1] - rect.center_in_rig[0];
  rect.baseline_mm = baseline.norm();
  SLSHADOW_THROW_IF(!(rect.baseline_mm > 1e-9), "stereo: cameras '", left.name, "' and '",
                    right.name, "' have the same optical centre (baseline ", rect.baseline_mm,
                    " mm)");
  const Eigen::Vector3d e1 = baseline / rect.baseline_mm;
  const Eigen::Vector3d axis = 0.5 * (left.AxisInRig() + right.AxisInRig());
  Eigen::Vector3d e3 = axis - axis.dot(e1) * e1;
  SLSHADOW_THROW_IF(!(e3.norm() > 1e-6), "stereo: the optical axes of '", left.name, "' and '",
                    right.name, "' are along the baseline; cannot rectify");
  e3.normalize();
  const Eigen::Vector3d e2 = e3.cross(e1);
  rect.rect_from_rig_rotation.row(0) = e1;
  rect.rect_from_rig_rotation.row(1) = e2;
  rect.rect_from_rig_rotation.row(2) = e3;
  rect.focal_px = 0.5 * (left.model.fx() + left.model.fy());

  double vmin = -std::numeric_limits<double>::infinity(),
         vmax = std::numeric_limits<double>::infinity();
  const RigDevice* devices[2] = {&left, &right};
  for (int c = 0; c < 2; ++c) {
    const RigDevice& dev = *devices[c];
    const Eigen::Matrix3d rect_from_cam =
        rect.rect_from_rig_rotation * dev.cam_from_rig.rotation.toRotationMatrix().transpose();
    double umin_c = std::numeric_limits<double>::infinity(), umax_c = -umin_c;
    double vmin_c = umin_c, vmax_c = -umin_c;
    const int w = dev.model.width, h = dev.model.height;
    auto add = [&](double x, double y) {
      const auto xy = dev.model.UndistortToNormalized(Eigen::Vector2d(x, y));
      if (!xy) return;
      const Eigen::Vector3d r = rect_from_cam * Eigen::Vector3d(xy->x(), xy->y(), 1.0);
      if (!(r.z() > 1e-6)) return;
      const double u = rect.focal_px * r.x() / r.z(), v = rect.focal_px * r.y() / r.z();
      umin_c = std::min(umin_c, u);
      umax_c = std::max(umax_c, u);
      vmin_c = std::min(vmin_c, v);
      vmax_c = std::max(vmax_c, v);
    };
    const int step = 8;
    for (int x = 0; x <= w; x += step) {
      add(std::min(x, w - 1), 0);
      add(std::min(x, w - 1), h - 1);
    }
    for (int y = 0; y <= h; y += step) {
      add(0, std::min(y, h - 1));
      add(w - 1, std::min(y, h - 1));
    }
    SLSHADOW_THROW_IF(!std::isfinite(umin_c), "stereo: camera '", dev.name,
                      "' sees nothing in front of the rectified plane: wrong rig file? (the "
                      "cameras of a stereo rig look the same way, at the scene in front of both)");
    const double max_w = max_size_factor * w;
    if (umax_c - umin_c > max_w) {
      const double mid = 0.5 * (umin_c + umax_c);
      umin_c = mid - 0.5 * max_w;
      umax_c = mid + 0.5 * max_w;
    }
    rect.cx[c] = -std::floor(umin_c);
    rect.width[c] = static_cast<int>(std::ceil(umax_c) - std::floor(umin_c)) + 1;
    vmin = std::max(vmin, vmin_c);  // rows both cameras see
    vmax = std::min(vmax, vmax_c);
  }
  const double max_h = max_size_factor * left.model.height;
  if (vmax - vmin > max_h) {
    const double mid = 0.5 * (vmin + vmax);
    vmin = mid - 0.5 * max_h;
    vmax = mid + 0.5 * max_h;
  }
  SLSHADOW_THROW_IF(!(vmax > vmin), "stereo: cameras '", left.name, "' and '", right.name,
                    "' share no epipolar lines (no common rectified rows)");
  rect.cy = -std::floor(vmin);
  rect.height = static_cast<int>(std::ceil(vmax) - std::floor(vmin)) + 1;
  return rect;
}

RectifiedMap RectifyProjectorMap(const StereoRectification& rect, int camera,
                                 const RigDevice& device, const ProjectorMap& map,
                                 double max_step_px, float min_quality, bool cubic,
                                 double max_step_ratio) {
  RectifiedMap out;
  RectifyProjectorMap(rect, camera, device, map, max_step_px, min_quality, cubic, max_step_ratio,
                      &out);
  return out;
}

void RectifyProjectorMap(const StereoRectification& rect, int camera, const RigDevice& device,
                         const ProjectorMap& map, double max_step_px, float min_quality, bool cubic,
                         double max_step_ratio, RectifiedMap* out_map) {
  SLSHADOW_THROW_IF(!map.has_x, "stereo: camera '", device.name,
                    "': the pattern does not code projector columns; stereo matching needs them");
  SLSHADOW_THROW_IF(map.width() != device.model.width || map.height() != device.model.height,
                    "stereo: camera '", device.name, "': projector map is ", map.width(), "x",
                    map.height(), " but the camera is ", device.model.width, "x",
                    device.model.height);
  RectifiedMap& out = *out_map;
  out.width = rect.width[camera];
  out.height = rect.height;
  out.has_y = map.has_y;
  const size_t n = static_cast<size_t>(out.width) * out.height;
  // Sized only (kept buffers are not refilled here): the loop below writes every cell.
  out.proj_x.resize(n);
  out.proj_y.resize(n);
  out.quality.resize(n);
  out.source_u.resize(n);
  out.source_v.resize(n);
  out.reason.resize(n);
  const std::shared_ptr<const std::vector<Eigen::Vector2d>> sources =
      CachedSourceGrid(rect, camera, device);
  // Mixed coordinate types: both as double (exactly the values read as double).
  ProjectorMap wide;
  const bool mixed = map.has_y && map.proj_y.depth() != map.proj_x.depth();
  if (mixed) {
    wide = map;
    map.proj_x.convertTo(wide.proj_x, CV_64F);
    map.proj_y.convertTo(wide.proj_y, CV_64F);
  }
  const ProjectorMap& src = mixed ? wide : map;
  const bool is_double = src.proj_x.depth() == CV_64F;
  const std::vector<uint8_t> pairs = is_double ? FitPairs<double>(src, max_step_px, max_step_ratio)
                                               : FitPairs<float>(src, max_step_px, max_step_ratio);
  const std::vector<uint8_t> blocks =
      cubic ? SmoothBlocks(pairs, src.width(), src.height()) : std::vector<uint8_t>();
  if (is_double) {
    RectifyRows<double>(src, *sources, max_step_px, min_quality, cubic, pairs, blocks, &out);
  } else {
    RectifyRows<float>(src, *sources, max_step_px, min_quality, cubic, pairs, blocks, &out);
  }
}

StereoMatches MatchRectifiedMaps(const StereoRectification& rect, const RectifiedMap& left,
                                 const RectifiedMap& right, double min_disparity_px,
                                 double max_disparity_px, double max_step_px, bool cubic) {
  StereoMatches matches;
  MatchRectifiedMaps(rect, left, right, min_disparity_px, max_disparity_px, max_step_px, cubic,
                     &matches);
  return matches;
}

void MatchRectifiedMaps(const StereoRectification& rect, const RectifiedMap& left,
                        const RectifiedMap& right, double min_disparity_px, double max_disparity_px,
                        double max_step_px, bool cubic, StereoMatches* out) {
  SLSHADOW_CHECK(left.height == right.height);
  StereoMatches& matches = *out;
  const size_t n = left.proj_x.size();
  matches.right_u.resize(n);
  matches.reason.resize(n);
  const int wr = right.width;
  cv::parallel_for_(cv::Range(0, left.height), [&](const cv::Range& rows) {
    // Per-thread scratch, reused across rows: the right row's segments bucketed by the integer
    // part of the projector column they span (CSR layout).
    std::vector<int> offsets, cursor, bucket;
    for (int v = rows.start; v < rows.end; ++v) {
      {
        const size_t a = left.Index(0, v), b = a + static_cast<size_t>(left.width);
        std::fill(matches.right_u.begin() + static_cast<std::ptrdiff_t>(a),
                  matches.right_u.begin() + static_cast<std::ptrdiff_t>(b),
                  std::numeric_limits<double>::quiet_NaN());
        std::copy(left.reason.begin() + static_cast<std::ptrdiff_t>(a),
                  left.reason.begin() + static_cast<std::ptrdiff_t>(b),
                  matches.reason.begin() + static_cast<std::ptrdiff_t>(a));
      }
      const double* r = right.proj_x.data() + right.Index(0, v);
      double lo = std::numeric_limits<double>::infinity(), hi = -lo;
      for (int k = 0; k + 1 < wr; ++k) {
        if (std::isfinite(r[k]) && std::isfinite(r[k + 1]) &&
            std::abs(r[k + 1] - r[k]) <= max_step_px) {
          lo = std::min(lo, std::min(r[k], r[k + 1]));
          hi = std::max(hi, std::max(r[k], r[k + 1]));
        }
      }
      const bool any = std::isfinite(lo);
      const long base = any ? static_cast<long>(std::floor(lo)) : 0;
      const int nb = any ? static_cast<int>(static_cast<long>(std::floor(hi)) - base + 1) : 0;
      offsets.assign(static_cast<size_t>(nb) + 1, 0);
      auto for_bins = [&](int k, auto&& fn) {
        const double a = std::min(r[k], r[k + 1]), b = std::max(r[k], r[k + 1]);
        const int b0 = static_cast<int>(static_cast<long>(std::floor(a)) - base);
        const int b1 = static_cast<int>(static_cast<long>(std::floor(b)) - base);
        for (int bin = b0; bin <= b1; ++bin) fn(bin);
      };
      if (any) {
        for (int k = 0; k + 1 < wr; ++k) {
          if (std::isfinite(r[k]) && std::isfinite(r[k + 1]) &&
              std::abs(r[k + 1] - r[k]) <= max_step_px) {
            for_bins(k, [&](int bin) { ++offsets[static_cast<size_t>(bin) + 1]; });
          }
        }
        for (int b = 0; b < nb; ++b)
          offsets[static_cast<size_t>(b) + 1] += offsets[static_cast<size_t>(b)];
        bucket.resize(static_cast<size_t>(offsets[static_cast<size_t>(nb)]));
        cursor.assign(offsets.begin(), offsets.end() - 1);
        for (int k = 0; k + 1 < wr; ++k) {
          if (std::isfinite(r[k]) && std::isfinite(r[k + 1]) &&
              std::abs(r[k + 1] - r[k]) <= max_step_px) {
            for_bins(k, [&](int bin) {
              bucket[static_cast<size_t>(cursor[static_cast<size_t>(bin)]++)] = k;
            });
          }
        }
      }
      for (int u = 0; u < left.width; ++u) {
        const size_t i = left.Index(u, v);
        if (left.reason[i] != kAcceptedCode) continue;
        const double value = left.proj_x[i];
        const long bin = any ? static_cast<long>(std::floor(value)) - base : -1;
        if (bin < 0 || bin >= nb) {
          matches.reason[i] = static_cast<uint8_t>(RejectReason::kNoMatch);
          continue;
        }
        // Bin b holds the segments bucket[offsets[b] .. offsets[b + 1]).
        const int begin = offsets[static_cast<size_t>(bin)];
        const int end = offsets[static_cast<size_t>(bin) + 1];
        int found = 0;
        double best = 0, best_t = 0;
        int best_k = 0;
        for (int e = begin; e < end; ++e) {
          const int k = bucket[static_cast<size_t>(e)];
          const double r0 = r[k], r1 = r[k + 1];
          double t;
          if (r1 == r0) {
            if (value != r0) continue;
            t = 0.5;
          } else {
            t = (value - r0) / (r1 - r0);
          }
          if (t < 0 || t > 1) continue;
          const double ur = k + t;
          const double disparity = (u - rect.cx[0]) - (ur - rect.cx[1]);
          if (disparity < min_disparity_px || disparity > max_disparity_px) continue;
          if (found > 0 && std::abs(ur - best) < 1e-9) continue;  // shared sample of two segments
          ++found;
          best = ur;
          best_k = k;
          best_t = t;
        }
        if (found == 0) {
          matches.reason[i] = static_cast<uint8_t>(RejectReason::kNoMatch);
        } else if (found > 1) {
          matches.reason[i] = static_cast<uint8_t>(RejectReason::kAmbiguousMatch);
        } else {
          if (cubic && best_k >= 1 && best_k + 2 < wr && SmoothRun(r + best_k - 1, max_step_px) &&
              r[best_k + 1] != r[best_k]) {
            best = best_k + RefineCrossing(r + best_k - 1, value, best_t);
          }
          matches.right_u[i] = best;
        }
      }
    }
  });
}

}  // namespace slshadow
