// The geometry pass (DESIGN.md, sim/): camera rays and one trace per camera with Embree packets:
// hit point, normal, object, projector coordinate, shadow test and radiometric factor per pixel.
#include "sim/geometry_pass.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>
#include <optional>

#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include "core/error.h"
#include "sim/internal/lanes.h"
#include "sim/pooled_mats.h"

namespace slshadow {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();
constexpr int kBlock = 4;  // 4 x 4 pixels = one packet of 16 rays

using namespace lanes;  // NOLINT: the lane vector helpers of sim/internal/lanes.h

inline V4l Wide(V4i mask) { return __builtin_convertvector(mask, V4l); }
inline V4d ToDouble(V4f v) { return __builtin_convertvector(v, V4d); }
inline V4f ToFloat(const V4d& v) { return __builtin_convertvector(v, V4f); }

// Where the pass writes for one set of samples. Ground-truth maps are continuous, indexed
// y * width + x; pointers are null when the map shares its storage with a per-sample buffer.
struct GroundTruthTargets {
  float* depth = nullptr;
  float* point = nullptr;   // 3 per pixel
  float* normal = nullptr;  // 3 per pixel
  int32_t* object = nullptr;
  uint8_t* visibility = nullptr;
  uint8_t* status = nullptr;
  float* proj_x = nullptr;   // null: shared with SampleTargets::proj_x
  float* proj_y = nullptr;   // null: shared with SampleTargets::proj_y
  float* quality = nullptr;  // null: shared with SampleTargets::factor
};

struct SampleTargets {
  int samples = 1;  // per pixel in this set
  const std::vector<Eigen::Vector3f>* dirs = nullptr;
  // Per-sample outputs (may be null).
  float* proj_x = nullptr;
  float* proj_y = nullptr;
  float* factor = nullptr;
  float* albedo = nullptr;
  float* proj_sigma = nullptr;
  // Ground-truth outputs, per pixel (only when samples == 1; may be null).
  const GroundTruthTargets* gt = nullptr;
};

struct PassContext {
  const RayCaster* caster;
  const Scene* scene;
  TraceMode mode;
  int width, height;
  Eigen::Matrix3f rig_from_cam;
  Eigen::Vector3f cam_center;
  Eigen::Vector3d cam_center_d;
  Eigen::Vector3d
      cam_from_rig_row_z;  // third row of cam_from_rig's rotation: depth = row . p + t_z
  double cam_from_rig_tz;
  Eigen::Matrix3d proj_from_rig_rotation;
  Eigen::Vector3d proj_from_rig_translation;
  Eigen::Vector3d proj_center;
  const CameraModel* projector;
  double ref_distance_sq;
  const SceneLayers::Defocus* proj_defocus;
  std::vector<Rigid3d> object_from_rig;
  std::vector<double> uniform_albedo;  // per object; NaN when textured
  bool any_textured = false;
};

// The per-hit arithmetic of 16 lanes in structure-of-arrays form, without branches, so the
// compiler vectorises it (AVX2 clone where the CPU has it; no FMA, so every clone rounds alike
// and packet and single-ray renders stay bit-identical). Lanes without a hit carry harmless
// inputs and are ignored by the caller.
struct LaneInputs {
  alignas(64) double t[16];
  alignas(64) double dx[16], dy[16], dz[16];  // camera ray direction (rig frame)
  alignas(64) double nx[16], ny[16], nz[16];  // unit geometric normal
  alignas(64) double albedo[16];
};
struct LaneOutputs {
  alignas(64) double px[16], py[16], pz[16];  // hit point (rig frame)
  alignas(64) double nx[16], ny[16], nz[16];  // normal turned towards the camera
  alignas(64) double u[16], v[16];            // projector pixel
  alignas(64) double proj_depth[16];
  alignas(64) double factor[16];              // albedo * cos_p * (d_ref / d_p)^2
  alignas(64) double ox[16], oy[16], oz[16];  // shadow ray origin, slightly off the surface
  alignas(64) double lx[16], ly[16], lz[16];  // unit direction to the projector's centre
  alignas(64) double tfar[16];                // shadow ray length
  alignas(64) double lit[16];  // 1: faces the projector, in front of it, inside its image
};

SLSHADOW_LANE_CLONES void ShadeLanes(const PassContext& c, const LaneInputs& __restrict in,
                                     LaneOutputs& __restrict out) {
  const double cx = c.cam_center_d.x(), cy = c.cam_center_d.y(), cz = c.cam_center_d.z();
  const double qx0 = c.proj_center.x(), qy0 = c.proj_center.y(), qz0 = c.proj_center.z();
  const Eigen::Matrix3d& r = c.proj_from_rig_rotation;
  const double r00 = r(0, 0), r01 = r(0, 1), r02 = r(0, 2), r10 = r(1, 0), r11 = r(1, 1),
               r12 = r(1, 2);
  const double r20 = r(2, 0), r21 = r(2, 1), r22 = r(2, 2);
  const double t0 = c.proj_from_rig_translation.x(), t1 = c.proj_from_rig_translation.y(),
               t2 = c.proj_from_rig_translation.z();
  const double* k = c.projector->params.data();
  const double fx = k[CameraModel::kFx], fy = k[CameraModel::kFy], ppx = k[CameraModel::kCx],
               ppy = k[CameraModel::kCy];
  const double k1 = k[CameraModel::kK1], k2 = k[CameraModel::kK2], k3 = k[CameraModel::kK3];
  const double p1 = k[CameraModel::kP1], p2 = k[CameraModel::kP2];
  const double u_max = c.projector->width - 0.5, v_max = c.projector->height - 0.5;
  const double ref_sq = c.ref_distance_sq;
  for (int i = 0; i < 16; ++i) {
    const double dx = in.dx[i], dy = in.dy[i], dz = in.dz[i], t = in.t[i];
    const double X = cx + t * dx, Y = cy + t * dy, Z = cz + t * dz;
    const double facing = in.nx[i] * dx + in.ny[i] * dy + in.nz[i] * dz;
    const double sign = facing > 0 ? -1.0 : 1.0;
    const double nx = sign * in.nx[i], ny = sign * in.ny[i], nz = sign * in.nz[i];
    const double ax = qx0 - X, ay = qy0 - Y, az = qz0 - Z;
    const double dist = std::sqrt(ax * ax + ay * ay + az * az);
    const double lx = ax / dist, ly = ay / dist, lz = az / dist;
    const double cos_p = nx * lx + ny * ly + nz * lz;
    // Projector frame, then the projector model with its distortion (CameraModel::ImgFromCam).
    const double qx = r00 * X + r01 * Y + r02 * Z + t0;
    const double qy = r10 * X + r11 * Y + r12 * Z + t1;
    const double qz = r20 * X + r21 * Y + r22 * Z + t2;
    const double x = qx / qz, y = qy / qz;
    const double x2 = x * x, y2 = y * y, xy = x * y, r2 = x2 + y2;
    const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
    const double xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x2);
    const double yd = y * radial + p1 * (r2 + 2.0 * y2) + 2.0 * p2 * xy;
    const double u = fx * xd + ppx, v = fy * yd + ppy;
    // Non-short-circuit `&`: no branches in the loop.
    const bool lit = (cos_p > 0) & (qz > 0) & (u >= -0.5) & (v >= -0.5) & (u < u_max) & (v < v_max);
    const double eps = 1e-3 * (1.0 + dist / 100.0);
    out.px[i] = X;
    out.py[i] = Y;
    out.pz[i] = Z;
    out.nx[i] = nx;
    out.ny[i] = ny;
    out.nz[i] = nz;
    out.u[i] = u;
    out.v[i] = v;
    out.proj_depth[i] = qz;
    out.factor[i] = in.albedo[i] * cos_p * ref_sq / (dist * dist);
    out.ox[i] = X + eps * nx;
    out.oy[i] = Y + eps * ny;
    out.oz[i] = Z + eps * nz;
    out.lx[i] = lx;
    out.ly[i] = ly;
    out.lz[i] = lz;
    out.tfar[i] = dist - 2 * eps;
    out.lit[i] = lit ? 1.0 : 0.0;
  }
}

// One packet: 4 x 4 pixels (one sample each), traced, shaded and stored. Every per-lane step
// without branches, a packet row (4 lanes) per vector; the values are those of the scalar
// per-lane code it replaced, bit for bit (docs/benchmarks.md, Simulator).
SLSHADOW_LANE_CLONES void TracePacket(const PassContext& c, const SampleTargets& out, int bx,
                                      int by, int s, int64_t* primary, int64_t* shadow) {
  constexpr int kN = RayPacket::kSize;
  RayPacket p;
  RayPacket sh;
  const int x0 = bx * kBlock, y0 = by * kBlock;
  // Inside the image: every lane (a packet over the right or bottom edge has lanes outside).
  const bool full = x0 + kBlock <= c.width && y0 + kBlock <= c.height;
  int64_t index[kN];               // sample index; 0 outside the image
  alignas(16) int32_t inside[kN];  // lane masks
  for (int r = 0; r < kBlock; ++r) {
    const int y = y0 + r;
    const int64_t row = (static_cast<int64_t>(y) * c.width + x0) * out.samples + s;
    for (int k = 0; k < kBlock; ++k) {
      const bool in_image = (x0 + k < c.width) & (y < c.height);
      inside[r * kBlock + k] = in_image ? -1 : 0;
      index[r * kBlock + k] = in_image ? row + k * out.samples : 0;
    }
  }
  // Camera rays to the rig frame: rig_from_cam * d in the order Eigen evaluates a 3x3 float
  // product (m0 x + (m1 y + m2 z)); lanes outside the image or without a ray (NaN) inactive.
  const Eigen::Matrix3f& m = c.rig_from_cam;
  const float m00 = m(0, 0), m01 = m(0, 1), m02 = m(0, 2), m10 = m(1, 0), m11 = m(1, 1),
              m12 = m(1, 2);
  const float m20 = m(2, 0), m21 = m(2, 1), m22 = m(2, 2);
  const V4f ox = Splat(c.cam_center.x()), oy = Splat(c.cam_center.y()),
            oz = Splat(c.cam_center.z());
  V4i n_primary = {0, 0, 0, 0};
  for (int r = 0; r < kBlock; ++r) {
    const int i = r * kBlock;
    const Eigen::Vector3f* d[4];
    for (int k = 0; k < 4; ++k) d[k] = &(*out.dirs)[static_cast<size_t>(index[i + k])];
    const V4f x = {d[0]->x(), d[1]->x(), d[2]->x(), d[3]->x()};
    const V4f y = {d[0]->y(), d[1]->y(), d[2]->y(), d[3]->y()};
    const V4f z = {d[0]->z(), d[1]->z(), d[2]->z(), d[3]->z()};
    const V4i finite =
        Load4<V4i>(inside + i) & (x - x == 0) & (y - y == 0) & (z - z == 0);  // Eigen's allFinite()
    Store4(p.org_x + i, ox);
    Store4(p.org_y + i, oy);
    Store4(p.org_z + i, oz);
    Store4(p.dir_x + i, m00 * x + (m01 * y + m02 * z));
    Store4(p.dir_y + i, m10 * x + (m11 * y + m12 * z));
    Store4(p.dir_z + i, m20 * x + (m21 * y + m22 * z));
    Store4(p.tnear + i, Splat(0.0f));
    Store4(p.tfar + i, Splat(std::numeric_limits<float>::infinity()));
    Store4(p.object + i, V4i{-1, -1, -1, -1});
    Store4(p.active + i, Flags(finite));
    n_primary -= finite;
  }
  *primary += n_primary[0] + n_primary[1] + n_primary[2] + n_primary[3];
  c.caster->Intersect(p, c.mode, /*coherent=*/true);

  alignas(16) int32_t hit[kN];  // lane masks
  LaneInputs in;
  for (int r = 0; r < kBlock; ++r) {
    const int i = r * kBlock;
    const V4i object = Load4<V4i>(p.object + i);
    const V4i h = MaskOf(p.active + i) & (object >= 0);
    const V4l h2 = Wide(h);
    Store4(hit + i, h);
    // Lanes without a hit carry harmless inputs.
    Store4(in.t + i, h2 ? ToDouble(Load4<V4f>(p.tfar + i)) : Splat(1.0));
    Store4(in.dx + i, h2 ? ToDouble(Load4<V4f>(p.dir_x + i)) : Splat(0.0));
    Store4(in.dy + i, h2 ? ToDouble(Load4<V4f>(p.dir_y + i)) : Splat(0.0));
    Store4(in.dz + i, h2 ? ToDouble(Load4<V4f>(p.dir_z + i)) : Splat(1.0));
    Store4(in.nx + i, h2 ? ToDouble(Load4<V4f>(p.ng_x + i)) : Splat(0.0));
    Store4(in.ny + i, h2 ? ToDouble(Load4<V4f>(p.ng_y + i)) : Splat(0.0));
    Store4(in.nz + i, h2 ? ToDouble(Load4<V4f>(p.ng_z + i)) : Splat(1.0));
    const V4i obj = h ? object : V4i{0, 0, 0, 0};
    const double* ua = c.uniform_albedo.data();
    const V4d a = {ua[obj[0]], ua[obj[1]], ua[obj[2]], ua[obj[3]]};
    Store4(in.albedo + i, h2 ? a : Splat(0.0));
  }
  if (c.any_textured) {
    for (int i = 0; i < kN; ++i) {
      if (!hit[i] || !std::isnan(in.albedo[i])) continue;
      const size_t obj = static_cast<size_t>(p.object[i]);
      const SceneObject& o = c.scene->objects[obj];
      const Eigen::Vector3d point =
          c.cam_center_d + in.t[i] * Eigen::Vector3d(in.dx[i], in.dy[i], in.dz[i]);
      const Eigen::Vector3d local = c.object_from_rig[obj] * point;
      in.albedo[i] =
          o.albedo.Evaluate(local.x() + o.albedo_offset_mm.x(), local.y() + o.albedo_offset_mm.y());
    }
  }
  LaneOutputs sh_in;
  ShadeLanes(c, in, sh_in);
  // Occlusion rays towards the projector's centre, started slightly off the surface.
  V4i n_shadow = {0, 0, 0, 0};
  for (int r = 0; r < kBlock; ++r) {
    const int i = r * kBlock;
    const V4i a =
        Load4<V4i>(hit + i) & __builtin_convertvector(Load4<V4d>(sh_in.lit + i) != 0, V4i);
    Store4(sh.org_x + i, ToFloat(Load4<V4d>(sh_in.ox + i)));
    Store4(sh.org_y + i, ToFloat(Load4<V4d>(sh_in.oy + i)));
    Store4(sh.org_z + i, ToFloat(Load4<V4d>(sh_in.oz + i)));
    Store4(sh.dir_x + i, ToFloat(Load4<V4d>(sh_in.lx + i)));
    Store4(sh.dir_y + i, ToFloat(Load4<V4d>(sh_in.ly + i)));
    Store4(sh.dir_z + i, ToFloat(Load4<V4d>(sh_in.lz + i)));
    Store4(sh.tnear + i, Splat(0.0f));
    Store4(sh.tfar + i, ToFloat(Load4<V4d>(sh_in.tfar + i)));
    Store4(sh.active + i, Flags(a));
    Store4(sh.occluded + i, V4i{0, 0, 0, 0});
    n_shadow -= a;
  }
  const int shadow_rays = n_shadow[0] + n_shadow[1] + n_shadow[2] + n_shadow[3];
  *shadow += shadow_rays;
  if (shadow_rays > 0) c.caster->Occluded(sh, c.mode);

  alignas(16) int32_t lit[kN];  // lane masks
  alignas(64) float proj_u[kN], proj_v[kN], factor[kN], albedo[kN];
  for (int r = 0; r < kBlock; ++r) {
    const int i = r * kBlock;
    const V4i h = Load4<V4i>(hit + i);
    const V4i l = h & MaskOf(sh.active + i) & ~MaskOf(sh.occluded + i);
    Store4(lit + i, l);
    Store4(proj_u + i, l ? ToFloat(Load4<V4d>(sh_in.u + i)) : Splat(kNaN));
    Store4(proj_v + i, l ? ToFloat(Load4<V4d>(sh_in.v + i)) : Splat(kNaN));
    Store4(factor + i, l ? ToFloat(Load4<V4d>(sh_in.factor + i)) : Splat(0.0f));
    Store4(albedo + i, h ? ToFloat(Load4<V4d>(in.albedo + i)) : Splat(0.0f));
  }
  if (out.proj_x) {
    if (full && out.samples == 1) {
      // A row of the packet is 4 consecutive pixels.
      for (int r = 0; r < kBlock; ++r) {
        const size_t k = static_cast<size_t>(index[r * kBlock]);
        std::memcpy(out.proj_x + k, proj_u + r * kBlock, kBlock * sizeof(float));
        std::memcpy(out.proj_y + k, proj_v + r * kBlock, kBlock * sizeof(float));
        std::memcpy(out.factor + k, factor + r * kBlock, kBlock * sizeof(float));
        std::memcpy(out.albedo + k, albedo + r * kBlock, kBlock * sizeof(float));
      }
    } else {
      for (int i = 0; i < kN; ++i) {
        if (!inside[i]) continue;
        const size_t k = static_cast<size_t>(index[i]);
        out.proj_x[k] = proj_u[i];
        out.proj_y[k] = proj_v[i];
        out.factor[k] = factor[i];
        out.albedo[k] = albedo[i];
      }
    }
    if (out.proj_sigma) {
      for (int i = 0; i < kN; ++i) {
        if (!inside[i]) continue;
        out.proj_sigma[static_cast<size_t>(index[i])] =
            lit[i] ? static_cast<float>(
                         c.proj_defocus->SigmaPx(c.projector->fx(), sh_in.proj_depth[i]))
                   : 0.0f;
      }
    }
  }
  if (out.gt) {
    for (int i = 0; i < kN; ++i) {
      if (!inside[i]) continue;
      // Every pixel is written (no separate initialisation pass: first touch in parallel).
      const GroundTruthTargets& g = *out.gt;
      const size_t q = static_cast<size_t>(y0 + i / kBlock) * static_cast<size_t>(c.width) +
                       static_cast<size_t>(x0 + i % kBlock);
      if (hit[i]) {
        const Eigen::Vector3d point(sh_in.px[i], sh_in.py[i], sh_in.pz[i]);
        g.depth[q] = static_cast<float>(c.cam_from_rig_row_z.dot(point) + c.cam_from_rig_tz);
        g.point[3 * q] = static_cast<float>(sh_in.px[i]);
        g.point[3 * q + 1] = static_cast<float>(sh_in.py[i]);
        g.point[3 * q + 2] = static_cast<float>(sh_in.pz[i]);
        g.normal[3 * q] = static_cast<float>(sh_in.nx[i]);
        g.normal[3 * q + 1] = static_cast<float>(sh_in.ny[i]);
        g.normal[3 * q + 2] = static_cast<float>(sh_in.nz[i]);
        g.object[q] = p.object[i];
        g.visibility[q] = lit[i] ? 2 : 1;
      } else {
        g.depth[q] = kNaN;
        for (int a = 0; a < 3; ++a) {
          g.point[3 * q + static_cast<size_t>(a)] = kNaN;
          g.normal[3 * q + static_cast<size_t>(a)] = kNaN;
        }
        g.object[q] = -1;
        g.visibility[q] = 0;
      }
      if (g.proj_x) {
        g.proj_x[q] = proj_u[i];
        g.proj_y[q] = proj_v[i];
        g.quality[q] = factor[i];
      }
      g.status[q] = static_cast<uint8_t>(lit[i] ? PixelStatus::kValid : PixelStatus::kShadow);
    }
  }
}

void RunPass(const PassContext& c, const SampleTargets& out, int64_t* primary, int64_t* shadow) {
  const int blocks_x = (c.width + kBlock - 1) / kBlock, blocks_y = (c.height + kBlock - 1) / kBlock;
  std::atomic<int64_t> n_primary{0}, n_shadow{0};
  tbb::parallel_for(tbb::blocked_range2d<int>(0, blocks_y, 4, 0, blocks_x, 16),
                    [&](const tbb::blocked_range2d<int>& r) {
                      int64_t local_primary = 0, local_shadow = 0;
                      for (int by = r.rows().begin(); by < r.rows().end(); ++by) {
                        for (int bx = r.cols().begin(); bx < r.cols().end(); ++bx) {
                          for (int s = 0; s < out.samples; ++s)
                            TracePacket(c, out, bx, by, s, &local_primary, &local_shadow);
                        }
                      }
                      n_primary += local_primary;
                      n_shadow += local_shadow;
                    });
  *primary += n_primary;
  *shadow += n_shadow;
}

}  // namespace

namespace {

// r^2 of the radial distortion's fold: the smallest r^2 > 0 where d(r * radial(r)) / dr =
// 1 + 3 k1 r^2 + 5 k2 r^4 + 7 k3 r^6 reaches 0 (infinity when it never does). Beyond it a lens
// maps rays back inwards; Newton started from a neighbour's solution can converge there, on a
// solution no ray of the camera has, so such solutions are rejected.
double RadialFoldR2(const CameraModel& cam) {
  const auto& q = cam.params;
  const double k1 = q[CameraModel::kK1], k2 = q[CameraModel::kK2], k3 = q[CameraModel::kK3];
  const auto slope = [&](double s) { return 1 + s * (3 * k1 + s * (5 * k2 + s * 7 * k3)); };
  constexpr double kStep = 1e-3, kMax = 100;  // r up to 10 (84 deg off axis)
  for (double s = kStep; s <= kMax; s += kStep) {
    if (slope(s) > 0) continue;
    double lo = s - kStep, hi = s;
    for (int i = 0; i < 60; ++i) (slope(0.5 * (lo + hi)) > 0 ? lo : hi) = 0.5 * (lo + hi);
    return lo;
  }
  return std::numeric_limits<double>::infinity();
}

// Brown-Conrady coefficients as the Newton step reads them.
struct Distortion {
  double k1, k2, k3, p1, p2;
  explicit Distortion(const CameraModel& cam)
      : k1(cam.params[CameraModel::kK1]),
        k2(cam.params[CameraModel::kK2]),
        k3(cam.params[CameraModel::kK3]),
        p1(cam.params[CameraModel::kP1]),
        p2(cam.params[CameraModel::kP2]) {}
};

// One Newton step on distort(x, y) = (xd, yd) with the analytic Jacobian [a b; b d]: updates
// (x, y) and returns the Jacobian's determinant (the step is meaningless unless it is > 0) and
// |dx| + |dy| in `step`. Branch-free, so NewtonRow vectorises over it.
inline double NewtonStep(const Distortion& k, double xd, double yd, double& x, double& y,
                         double& step) {
  const double x2 = x * x, y2 = y * y, xy = x * y, r2 = x2 + y2;
  const double radial = 1 + r2 * (k.k1 + r2 * (k.k2 + r2 * k.k3));
  const double dradial = 2 * (k.k1 + r2 * (2 * k.k2 + 3 * k.k3 * r2));  // d radial / d r2 * 2
  const double fx = x * radial + 2 * k.p1 * xy + k.p2 * (r2 + 2 * x2) - xd;
  const double fy = y * radial + k.p1 * (r2 + 2 * y2) + 2 * k.p2 * xy - yd;
  const double a = radial + x * x * dradial + 2 * k.p1 * y + 6 * k.p2 * x;
  const double b = x * y * dradial + 2 * k.p1 * x + 2 * k.p2 * y;
  const double d = radial + y * y * dradial + 6 * k.p1 * y + 2 * k.p2 * x;
  const double det = a * d - b * b;
  const double inv_det = 1 / det;
  const double dx = (d * fx - b * fy) * inv_det, dy = (a * fy - b * fx) * inv_det;
  x -= dx;
  y -= dy;
  step = std::abs(dx) + std::abs(dy);
  return det;
}

// Undistortion by Newton's method on the Brown-Conrady model with an analytic Jacobian, started
// from `guess` (the neighbouring sample's solution, so 1-3 iterations). Returns false when it
// does not converge, the distortion folds over on the way, or the solution lies beyond the radial
// fold `fold_r2` (then the caller falls back to CameraModel::UndistortToNormalized, which decides).
bool UndistortFrom(const CameraModel& cam, double fold_r2, double xd_target, double yd_target,
                   Eigen::Vector2d& guess) {
  const Distortion k(cam);
  double x = guess.x(), y = guess.y(), step = 0;
  for (int it = 0; it < 20; ++it) {
    if (!(NewtonStep(k, xd_target, yd_target, x, y, step) > 0)) return false;
    // Quadratic convergence: after a step below 1e-10 the remaining error is ~1e-20, far below
    // double rounding of these O(1) coordinates (and the float rays made from them).
    if (step < 1e-10) {
      guess = Eigen::Vector2d(x, y);
      return x * x + y * y < fold_r2;
    }
  }
  return false;
}

// `Steps` Newton steps of UndistortFrom for a row of samples at once (targets xd[i], yd), without
// branches so the compiler vectorises it (AVX2 clone). Lane i starts from (x[i], y[i]) and is
// accepted when the Jacobian stayed positive, the last step was below 1e-10 (UndistortFrom's
// test: the error left is ~1e-20) and the solution lies inside the radial fold; other lanes are
// flagged for the scalar solver.
template <int Steps>
SLSHADOW_LANE_CLONES void NewtonRow(const CameraModel& cam, double fold_r2,
                                    const double* __restrict xd, double yd, double* __restrict x_io,
                                    double* __restrict y_io, uint8_t* __restrict ok, int n) {
  const Distortion k(cam);
  for (int i = 0; i < n; ++i) {
    double x = x_io[i], y = y_io[i], step = 0;
    bool good = true;
    for (int it = 0; it < Steps; ++it) good = good & (NewtonStep(k, xd[i], yd, x, y, step) > 0);
    ok[i] = good & (step < 1e-10) & (x * x + y * y < fold_r2);
    x_io[i] = x;
    y_io[i] = y;
  }
}

// Unit ray directions (x, y, 1) / |(x, y, 1)| of one sample row (width pixels x nn samples) into
// the sub-row that starts at `out` (float xyz; pixel px's samples are nn * nn directions apart).
SLSHADOW_LANE_CLONES void DirectionsRow(const double* __restrict x, const double* __restrict y,
                                        double* __restrict scratch, float* __restrict out,
                                        int width, int nn) {
  const int m = width * nn;
  for (int i = 0; i < m; ++i) scratch[i] = 1 / std::sqrt(x[i] * x[i] + y[i] * y[i] + 1);
  int start = 0;
  if (nn == 1) {
    // One sample per pixel: 4 rays (12 consecutive floats) per step, the same conversions.
    for (; start + 4 <= width; start += 4) {
      const V4d s = Load4<V4d>(scratch + start);
      const V4f fx = ToFloat(Load4<V4d>(x + start) * s), fy = ToFloat(Load4<V4d>(y + start) * s),
                fz = ToFloat(s);
      const float xyz[12] = {fx[0], fy[0], fz[0], fx[1], fy[1], fz[1],
                             fx[2], fy[2], fz[2], fx[3], fy[3], fz[3]};
      std::memcpy(out + 3 * static_cast<ptrdiff_t>(start), xyz, sizeof(xyz));
    }
  }
  for (int px = start, i = start * nn; px < width; ++px) {
    for (int a = 0; a < nn; ++a, ++i) {
      float* o = out + 3 * (static_cast<ptrdiff_t>(px) * nn * nn + a);
      o[0] = static_cast<float>(x[i] * scratch[i]);
      o[1] = static_cast<float>(y[i] * scratch[i]);
      o[2] = static_cast<float>(scratch[i]);
    }
  }
}

}  // namespace

CameraRays ComputeCameraRays(const CameraModel& camera, int samples_per_axis, CameraRays storage) {
  SLSHADOW_THROW_IF(samples_per_axis < 1 || samples_per_axis > 16,
                    "samples_per_axis must be in 1..16 (got ", samples_per_axis, ")");
  CameraRays rays = std::move(storage);
  rays.width = camera.width;
  rays.height = camera.height;
  rays.samples_per_axis = samples_per_axis;
  const int n = samples_per_axis, spp = n * n;
  const bool distorted = camera.HasDistortion();
  const double fold_r2 = RadialFoldR2(camera);
  // Sample rows (height * nn of them, equally spaced in v) in bands, solved a row at a time by
  // Newton steps vectorised along the row (NewtonRow). A band's first row starts from the
  // distorted positions (five steps), its second from the first row's solutions (three), every
  // later one from the two rows above extrapolated (two). Only the lanes NewtonRow flags go
  // through the scalar solvers.
  auto fill = [&](std::vector<Eigen::Vector3f>& dirs, int nn) {
    const int row_samples = camera.width * nn;
    const size_t m = static_cast<size_t>(row_samples);
    dirs.resize(m * camera.height * nn);
    std::vector<double> xd(
        m);  // normalised distorted x of every sample of a row (the same on each row)
    for (int px = 0, j = 0; px < camera.width; ++px) {
      for (int a = 0; a < nn; ++a, ++j)
        xd[static_cast<size_t>(j)] = (px + (a + 0.5) / nn - 0.5 - camera.cx()) / camera.fx();
    }
    tbb::parallel_for(
        tbb::blocked_range<int>(0, camera.height * nn, 32), [&](const tbb::blocked_range<int>& r) {
          std::vector<double> x(m), y(m), x1(m), y1(m), x2(m), y2(m), scratch(m);
          std::vector<uint8_t> ok(m);
          for (int row = r.begin(); row < r.end(); ++row) {
            const int py = row / nn, b = row % nn;
            const double v = py + (b + 0.5) / nn - 0.5;
            const double yd = (v - camera.cy()) / camera.fy();
            const int k = row - r.begin();  // rows of this band already solved
            if (!distorted) {
              x = xd;
              std::fill(y.begin(), y.end(), yd);
              std::fill(ok.begin(), ok.end(), uint8_t{1});
            } else if (k == 0) {
              // From the distorted position: mild lens distortion moves points by ~1e-2, so five
              // quadratically converging steps end below 1e-10 (3 + 2: GCC vectorises those).
              x = xd;
              std::fill(y.begin(), y.end(), yd);
              NewtonRow<3>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(),
                           row_samples);
              NewtonRow<2>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(),
                           row_samples);
            } else if (k == 1) {
              x = x1;
              y = y1;
              NewtonRow<3>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(),
                           row_samples);
            } else {
              for (size_t j = 0; j < m; ++j) {
                x[j] = 2 * x1[j] - x2[j];
                y[j] = 2 * y1[j] - y2[j];
              }
              NewtonRow<2>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(),
                           row_samples);
            }
            // Lanes not yet solved: started from the left neighbours' solutions (extrapolated when
            // there are two), then the camera model's own solver, which decides (NaN: no solution
            // past the fold of the distortion).
            for (size_t j = 0; j < m; ++j) {
              if (ok[j]) continue;
              Eigen::Vector2d start(xd[j], yd);
              const bool left1 = j >= 1 && std::isfinite(x[j - 1]),
                         left2 = left1 && j >= 2 && std::isfinite(x[j - 2]);
              if (left2) {
                start = Eigen::Vector2d(2 * x[j - 1] - x[j - 2], 2 * y[j - 1] - y[j - 2]);
              } else if (left1) {
                start = Eigen::Vector2d(x[j - 1], y[j - 1]);
              }
              std::optional<Eigen::Vector2d> xy;
              if (UndistortFrom(camera, fold_r2, xd[j], yd, start)) {
                xy = start;
              } else {
                const double u = static_cast<double>(j / static_cast<size_t>(nn)) +
                                 (static_cast<double>(j % static_cast<size_t>(nn)) + 0.5) / nn -
                                 0.5;
                xy = camera.UndistortToNormalized(Eigen::Vector2d(u, v));
              }
              x[j] = xy ? xy->x() : kNaN;
              y[j] = xy ? xy->y() : kNaN;
            }
            // Sub-row b of pixel row py holds samples (px, a) at (py * width + px) * nn * nn + b *
            // nn + a.
            float* out =
                dirs[static_cast<size_t>(py) * camera.width * nn * nn + static_cast<size_t>(b * nn)]
                    .data();
            DirectionsRow(x.data(), y.data(), scratch.data(), out, camera.width, nn);
            std::swap(x2, x1);
            std::swap(y2, y1);
            std::swap(x1, x);
            std::swap(y1, y);
          }
        });
  };
  fill(rays.samples, n);
  if (spp > 1) {
    fill(rays.centers, 1);
  } else {
    rays.centers.clear();
  }
  return rays;
}

GeometryBuffer TraceGeometry(const RayCaster& caster, const Rig& rig, int camera_index,
                             const CameraRays& rays, TraceMode mode, bool ground_truth) {
  const auto start = std::chrono::steady_clock::now();
  const Scene& scene = caster.scene();
  SLSHADOW_THROW_IF(camera_index < 0 || camera_index >= static_cast<int>(rig.cameras.size()),
                    "camera index ", camera_index, " out of range (rig has ", rig.cameras.size(),
                    " cameras)");
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name,
                    "' has no projector: the simulator needs one");
  const RigDevice& cam = rig.cameras[static_cast<size_t>(camera_index)];
  SLSHADOW_THROW_IF(rays.width != cam.model.width || rays.height != cam.model.height ||
                        rays.samples_per_axis != scene.layers.supersampling,
                    "camera rays do not match camera '", cam.name,
                    "' and the scene's supersampling");
  PassContext c;
  c.caster = &caster;
  c.scene = &scene;
  c.mode = mode;
  c.width = cam.model.width;
  c.height = cam.model.height;
  c.rig_from_cam = cam.cam_from_rig.rotation.conjugate().toRotationMatrix().cast<float>();
  c.cam_center_d = cam.CenterInRig();
  c.cam_center = c.cam_center_d.cast<float>();
  c.cam_from_rig_row_z = cam.cam_from_rig.rotation.toRotationMatrix().row(2).transpose();
  c.cam_from_rig_tz = cam.cam_from_rig.translation.z();
  c.proj_from_rig_rotation = rig.projector->cam_from_rig.rotation.toRotationMatrix();
  c.proj_from_rig_translation = rig.projector->cam_from_rig.translation;
  c.proj_center = rig.projector->CenterInRig();
  c.projector = &rig.projector->model;
  const double d_ref = scene.radiometry.reference_distance_mm > 0
                           ? scene.radiometry.reference_distance_mm
                           : rig.working_distance_mm;
  c.ref_distance_sq = d_ref * d_ref;
  c.proj_defocus = &scene.layers.projector_defocus;
  for (const auto& o : scene.objects) {
    c.object_from_rig.push_back(o.rig_from_object.Inverse());
    c.uniform_albedo.push_back(o.albedo.IsTextured() ? std::numeric_limits<double>::quiet_NaN()
                                                     : o.albedo.value);
    c.any_textured = c.any_textured || o.albedo.IsTextured();
  }

  GeometryBuffer g;
  g.width = c.width;
  g.height = c.height;
  g.samples_per_axis = rays.samples_per_axis;
  const int spp = rays.samples_per_axis * rays.samples_per_axis;
  const size_t n = static_cast<size_t>(c.width) * c.height * spp;
  const bool with_gt = ground_truth || scene.layers.camera_defocus.enabled;
  // Not initialised here: the passes write every element (in parallel).
  if (with_gt) {
    CreatePooled(g.depth_mm, c.height, c.width, CV_32FC1);
    CreatePooled(g.point_in_rig, c.height, c.width, CV_32FC3);
    CreatePooled(g.normal_in_rig, c.height, c.width, CV_32FC3);
    CreatePooled(g.visibility, c.height, c.width, CV_8UC1);
    CreatePooled(g.object_id, c.height, c.width, CV_32SC1);
    CreatePooled(g.projector.proj_x, c.height, c.width, CV_32FC1);
    CreatePooled(g.projector.proj_y, c.height, c.width, CV_32FC1);
    CreatePooled(g.projector.status, c.height, c.width, CV_8UC1);
    CreatePooled(g.projector.quality, c.height, c.width, CV_32FC1);
    g.projector.has_x = g.projector.has_y = true;
  }
  const auto samples_mat = [&] {
    cv::Mat m;
    CreatePooled(m, c.height, c.width * spp, CV_32FC1);
    return SampleBuffer(m);
  };
  if (spp == 1 && with_gt) {
    // The same values as the ground truth's projector map: one store each.
    g.proj_x = SampleBuffer(g.projector.proj_x);
    g.proj_y = SampleBuffer(g.projector.proj_y);
    g.factor = SampleBuffer(g.projector.quality);
  } else {
    g.proj_x = samples_mat();
    g.proj_y = samples_mat();
    g.factor = samples_mat();
  }
  g.albedo = samples_mat();
  if (scene.layers.projector_defocus.enabled) g.proj_sigma_px = samples_mat();
  SLSHADOW_CHECK(g.proj_x.size() == n && g.albedo.size() == n);

  GroundTruthTargets gt;
  if (with_gt) {
    gt.depth = g.depth_mm.ptr<float>();
    gt.point = g.point_in_rig.ptr<float>();
    gt.normal = g.normal_in_rig.ptr<float>();
    gt.object = g.object_id.ptr<int32_t>();
    gt.visibility = g.visibility.ptr<uint8_t>();
    gt.status = g.projector.status.ptr<uint8_t>();
    if (spp > 1) {
      gt.proj_x = g.projector.proj_x.ptr<float>();
      gt.proj_y = g.projector.proj_y.ptr<float>();
      gt.quality = g.projector.quality.ptr<float>();
    }
  }

  SampleTargets samples;
  samples.samples = spp;
  samples.dirs = &rays.samples;
  samples.proj_x = g.proj_x.data();
  samples.proj_y = g.proj_y.data();
  samples.factor = g.factor.data();
  samples.albedo = g.albedo.data();
  samples.proj_sigma = g.proj_sigma_px.empty() ? nullptr : g.proj_sigma_px.data();
  if (spp == 1 && with_gt) samples.gt = &gt;
  RunPass(c, samples, &g.primary_rays, &g.shadow_rays);
  if (spp > 1 && with_gt) {
    SampleTargets centers;
    centers.samples = 1;
    centers.dirs = &rays.centers;
    centers.gt = &gt;
    RunPass(c, centers, &g.primary_rays, &g.shadow_rays);
  }
  g.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return g;
}

}  // namespace slshadow
