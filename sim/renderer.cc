#include "sim/renderer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <optional>
#include <type_traits>


#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <cstdlib>
#include <new>

#include <opencv2/imgproc.hpp>
#include <tbb/blocked_range2d.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

namespace slshadow {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Large buffers (geometry buffers, rendered images) in page-aligned blocks rounded up to 2 MB
// size classes, recycled through a bounded process-wide pool: the geometry pass writes ~60 bytes
// per pixel into fresh buffers and the pattern pass ~2.3 MB per image, and the kernel's
// first-touch faults (page zeroing) cost about a fifth of a scan. Freed blocks are kept (up to kPoolCap bytes: a 2-camera 1920x1200 scan with 38 patterns
// recycles ~500 MB, exact size match) and handed to
// the next allocation of the same size, e.g. the next scan's buffers. Not zeroed: every user
// writes every element.
class BlockPool {
 public:
  static constexpr size_t kPage = 4096;
  static constexpr size_t kHuge = size_t{2} << 20;  // size classes (pages past the end are never touched)
  static constexpr size_t kPoolCap = size_t{640} << 20;
  static BlockPool& Get() {
    static BlockPool* pool = new BlockPool();  // never destroyed: buffers may outlive statics
    return *pool;
  }
  static size_t Rounded(size_t bytes) { return (bytes + kHuge - 1) / kHuge * kHuge; }
  void* Allocate(size_t bytes) {
    const size_t rounded = Rounded(std::max<size_t>(bytes, 1));
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      const auto it = free_.find(rounded);
      if (it != free_.end()) {
        void* p = it->second;
        free_.erase(it);
        cached_ -= rounded;
        return p;
      }
    }
    // Page-aligned, 4 kB pages: advising transparent huge pages (MADV_HUGEPAGE) made the first
    // scan of a process ~1 CPU s slower on this machine (2 MB zeroing and compaction per fault:
    // 2.2-2.6 vs 1.3-1.4 CPU s for the demo scan, same run), and recycling removes the faults of
    // later scans anyway.
    void* p = std::aligned_alloc(kPage, rounded);
    if (!p) throw std::bad_alloc();
    return p;
  }
  void Free(void* p, size_t bytes) {
    if (!p) return;
    const size_t rounded = Rounded(std::max<size_t>(bytes, 1));
    {
      const std::lock_guard<std::mutex> lock(mutex_);
      if (cached_ + rounded <= kPoolCap) {
        free_.emplace(rounded, p);
        cached_ += rounded;
        return;
      }
    }
    std::free(p);
  }

 private:
  std::mutex mutex_;
  std::multimap<size_t, void*> free_;
  size_t cached_ = 0;
};

// cv::Mat storage from the BlockPool. Same bookkeeping as OpenCV's standard allocator.
class PooledMatAllocator : public cv::MatAllocator {
 public:
  cv::UMatData* allocate(int dims, const int* sizes, int type, void* data0, size_t* step, cv::AccessFlag,
                         cv::UMatUsageFlags) const override {
    size_t total = CV_ELEM_SIZE(type);
    for (int i = dims - 1; i >= 0; i--) {
      if (step) {
        if (data0 && step[i] != cv::Mat::AUTO_STEP) {
          total = step[i];
        } else {
          step[i] = total;
        }
      }
      total *= static_cast<size_t>(sizes[i]);
    }
    uchar* data = static_cast<uchar*>(data0);
    if (!data) data = static_cast<uchar*>(BlockPool::Get().Allocate(total));
    auto* u = new cv::UMatData(this);
    u->data = u->origdata = data;
    u->size = total;
    if (data0) u->flags |= cv::UMatData::USER_ALLOCATED;
    return u;
  }
  bool allocate(cv::UMatData* u, cv::AccessFlag, cv::UMatUsageFlags) const override { return u != nullptr; }
  void deallocate(cv::UMatData* u) const override {
    if (!u) return;
    if (!(u->flags & cv::UMatData::USER_ALLOCATED)) BlockPool::Get().Free(u->origdata, u->size);
    delete u;
  }
};

}  // namespace

namespace {

cv::MatAllocator* PooledMats() {
  static PooledMatAllocator* allocator = new PooledMatAllocator();  // never destroyed: Mats may outlive statics
  return allocator;
}

void CreatePooled(cv::Mat& m, int rows, int cols, int type) {
  m.release();
  m.allocator = PooledMats();
  m.create(rows, cols, type);
}
constexpr int kBlock = 4;  // 4 x 4 pixels = one packet of 16 rays

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
  Eigen::Vector3d cam_from_rig_row_z;  // third row of cam_from_rig's rotation: depth = row . p + t_z
  double cam_from_rig_tz;
  Eigen::Matrix3d proj_from_rig_rotation;
  Eigen::Vector3d proj_from_rig_translation;
  Eigen::Vector3d proj_center;
  const CameraModel* projector;
  double ref_distance_sq;
  const SceneLayers::Defocus* proj_defocus;
  std::vector<Rigid3d> object_from_rig;
  std::vector<double> uniform_albedo;  // per object; NaN when textured
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
  alignas(64) double lit[16];                 // 1: faces the projector, in front of it, inside its image
};

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SLSHADOW_LANE_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define SLSHADOW_LANE_CLONES
#endif

SLSHADOW_LANE_CLONES void ShadeLanes(const PassContext& c, const LaneInputs& __restrict in, LaneOutputs& __restrict out) {
  const double cx = c.cam_center_d.x(), cy = c.cam_center_d.y(), cz = c.cam_center_d.z();
  const double qx0 = c.proj_center.x(), qy0 = c.proj_center.y(), qz0 = c.proj_center.z();
  const Eigen::Matrix3d& r = c.proj_from_rig_rotation;
  const double r00 = r(0, 0), r01 = r(0, 1), r02 = r(0, 2), r10 = r(1, 0), r11 = r(1, 1), r12 = r(1, 2);
  const double r20 = r(2, 0), r21 = r(2, 1), r22 = r(2, 2);
  const double t0 = c.proj_from_rig_translation.x(), t1 = c.proj_from_rig_translation.y(),
               t2 = c.proj_from_rig_translation.z();
  const double* k = c.projector->params.data();
  const double fx = k[CameraModel::kFx], fy = k[CameraModel::kFy], ppx = k[CameraModel::kCx], ppy = k[CameraModel::kCy];
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

SLSHADOW_LANE_CLONES void TracePacket(const PassContext& c, const SampleTargets& out, int bx, int by, int s, int64_t* primary,
                 int64_t* shadow) {
  RayPacket p;
  RayPacket sh;
  int64_t index[RayPacket::kSize];
  int px[RayPacket::kSize], py[RayPacket::kSize];
  for (int i = 0; i < RayPacket::kSize; ++i) {
    const int x = bx * kBlock + (i % kBlock), y = by * kBlock + (i / kBlock);
    px[i] = x;
    py[i] = y;
    p.active[i] = false;
    sh.active[i] = false;
    p.object[i] = -1;
    if (x >= c.width || y >= c.height) continue;
    index[i] = (static_cast<int64_t>(y) * c.width + x) * out.samples + s;
    const Eigen::Vector3f& d_cam = (*out.dirs)[static_cast<size_t>(index[i])];
    if (!d_cam.allFinite()) continue;
    const Eigen::Vector3f d = c.rig_from_cam * d_cam;
    p.org_x[i] = c.cam_center.x();
    p.org_y[i] = c.cam_center.y();
    p.org_z[i] = c.cam_center.z();
    p.dir_x[i] = d.x();
    p.dir_y[i] = d.y();
    p.dir_z[i] = d.z();
    p.tnear[i] = 0;
    p.tfar[i] = std::numeric_limits<float>::infinity();
    p.active[i] = true;
    ++*primary;
  }
  c.caster->Intersect(p, c.mode, /*coherent=*/true);

  bool hit[RayPacket::kSize];
  LaneInputs in;
  for (int i = 0; i < RayPacket::kSize; ++i) {
    hit[i] = p.active[i] && p.object[i] >= 0;
    if (!hit[i]) {
      in.t[i] = 1;
      in.dx[i] = in.dy[i] = in.nx[i] = in.ny[i] = 0;
      in.dz[i] = in.nz[i] = 1;
      in.albedo[i] = 0;
      continue;
    }
    in.t[i] = p.tfar[i];
    in.dx[i] = p.dir_x[i];
    in.dy[i] = p.dir_y[i];
    in.dz[i] = p.dir_z[i];
    in.nx[i] = p.ng_x[i];
    in.ny[i] = p.ng_y[i];
    in.nz[i] = p.ng_z[i];
    const size_t obj = static_cast<size_t>(p.object[i]);
    in.albedo[i] = c.uniform_albedo[obj];
    if (std::isnan(in.albedo[i])) {
      const SceneObject& o = c.scene->objects[obj];
      const Eigen::Vector3d point = c.cam_center_d + in.t[i] * Eigen::Vector3d(in.dx[i], in.dy[i], in.dz[i]);
      const Eigen::Vector3d local = c.object_from_rig[obj] * point;
      in.albedo[i] = o.albedo.Evaluate(local.x() + o.albedo_offset_mm.x(), local.y() + o.albedo_offset_mm.y());
    }
  }
  LaneOutputs sh_in;
  ShadeLanes(c, in, sh_in);
  for (int i = 0; i < RayPacket::kSize; ++i) {
    if (!hit[i] || sh_in.lit[i] == 0) continue;
    // Occlusion ray towards the projector's centre, started slightly off the surface.
    sh.org_x[i] = static_cast<float>(sh_in.ox[i]);
    sh.org_y[i] = static_cast<float>(sh_in.oy[i]);
    sh.org_z[i] = static_cast<float>(sh_in.oz[i]);
    sh.dir_x[i] = static_cast<float>(sh_in.lx[i]);
    sh.dir_y[i] = static_cast<float>(sh_in.ly[i]);
    sh.dir_z[i] = static_cast<float>(sh_in.lz[i]);
    sh.tnear[i] = 0;
    sh.tfar[i] = static_cast<float>(sh_in.tfar[i]);
    sh.active[i] = true;
    ++*shadow;
  }
  bool any_shadow = false;
  for (int i = 0; i < RayPacket::kSize; ++i) any_shadow |= sh.active[i];
  if (any_shadow) c.caster->Occluded(sh, c.mode);

  for (int i = 0; i < RayPacket::kSize; ++i) {
    if (px[i] >= c.width || py[i] >= c.height) continue;
    const bool lit = hit[i] && sh.active[i] && !sh.occluded[i];
    const size_t k = static_cast<size_t>(index[i]);
    const float proj_u = static_cast<float>(sh_in.u[i]), proj_v = static_cast<float>(sh_in.v[i]);
    const float factor = static_cast<float>(sh_in.factor[i]);
    if (out.proj_x) {
      out.proj_x[k] = lit ? proj_u : kNaN;
      out.proj_y[k] = lit ? proj_v : kNaN;
      out.factor[k] = lit ? factor : 0.0f;
      out.albedo[k] = hit[i] ? static_cast<float>(in.albedo[i]) : 0.0f;
      if (out.proj_sigma) {
        out.proj_sigma[k] = lit ? static_cast<float>(c.proj_defocus->SigmaPx(c.projector->fx(), sh_in.proj_depth[i])) : 0.0f;
      }
    }
    if (out.gt) {
      // Every pixel is written (no separate initialisation pass: first touch in parallel).
      const GroundTruthTargets& g = *out.gt;
      const size_t q = static_cast<size_t>(py[i]) * static_cast<size_t>(c.width) + static_cast<size_t>(px[i]);
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
        g.visibility[q] = lit ? 2 : 1;
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
        g.proj_x[q] = lit ? proj_u : kNaN;
        g.proj_y[q] = lit ? proj_v : kNaN;
        g.quality[q] = lit ? factor : 0.0f;
      }
      g.status[q] = static_cast<uint8_t>(lit ? PixelStatus::kValid : PixelStatus::kShadow);
    }
  }
}

void RunPass(const PassContext& c, const SampleTargets& out, int64_t* primary, int64_t* shadow) {
  const int blocks_x = (c.width + kBlock - 1) / kBlock, blocks_y = (c.height + kBlock - 1) / kBlock;
  std::atomic<int64_t> n_primary{0}, n_shadow{0};
  tbb::parallel_for(tbb::blocked_range2d<int>(0, blocks_y, 4, 0, blocks_x, 16), [&](const tbb::blocked_range2d<int>& r) {
    int64_t local_primary = 0, local_shadow = 0;
    for (int by = r.rows().begin(); by < r.rows().end(); ++by) {
      for (int bx = r.cols().begin(); bx < r.cols().end(); ++bx) {
        for (int s = 0; s < out.samples; ++s) TracePacket(c, out, bx, by, s, &local_primary, &local_shadow);
      }
    }
    n_primary += local_primary;
    n_shadow += local_shadow;
  });
  *primary += n_primary;
  *shadow += n_shadow;
}

// Bilinear lookup with clamping at the borders.
inline float Bilinear(const float* img, int w, int h, float x, float y) {
  const float fx0 = std::floor(x), fy0 = std::floor(y);
  const float fx = x - fx0, fy = y - fy0;
  const int x0 = std::clamp(static_cast<int>(fx0), 0, w - 1), x1 = std::clamp(static_cast<int>(fx0) + 1, 0, w - 1);
  const int y0 = std::clamp(static_cast<int>(fy0), 0, h - 1), y1 = std::clamp(static_cast<int>(fy0) + 1, 0, h - 1);
  const float* r0 = img + static_cast<size_t>(y0) * w;
  const float* r1 = img + static_cast<size_t>(y1) * w;
  return (1 - fy) * ((1 - fx) * r0[x0] + fx * r0[x1]) + fy * ((1 - fx) * r1[x0] + fx * r1[x1]);
}

inline float Nearest(const float* img, int w, int h, float x, float y) {
  const int xi = std::clamp(static_cast<int>(std::lround(x)), 0, w - 1);
  const int yi = std::clamp(static_cast<int>(std::lround(y)), 0, h - 1);
  return img[static_cast<size_t>(yi) * w + xi];
}

// Levels 0, s/(K-1), ..., s for a maximum sigma s (empty when s is negligible).
std::vector<double> SigmaLevels(double max_sigma) {
  if (!(max_sigma > 0.05)) return {};
  const int k = std::clamp(static_cast<int>(std::ceil(max_sigma / 0.5)) + 1, 2, 8);
  std::vector<double> levels(static_cast<size_t>(k));
  for (int i = 0; i < k; ++i) levels[static_cast<size_t>(i)] = max_sigma * i / (k - 1);
  return levels;
}

cv::Mat Blur(const cv::Mat& image, double sigma) {
  if (sigma <= 0) return image;
  cv::Mat out;
  cv::GaussianBlur(image, out, cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
  return out;
}

// Rounds and clips a non-negative float to [0, full] (the ADC). One definition for every path.
inline int QuantizeValue(float v, float full) {
  if (!(v > 0)) return 0;
  if (v >= full) return static_cast<int>(full);
  return static_cast<int>(v + 0.5f);
}

#if defined(__x86_64__)
// Transposes a 16 x 16 byte matrix held as 16 rows (SSE2): four rounds of interleaving rows i
// and i + 8.
inline void Transpose16x16(__m128i* a) {
  __m128i b[16];
  for (int round = 0; round < 4; ++round) {
    for (int i = 0; i < 8; ++i) {
      b[2 * i] = _mm_unpacklo_epi8(a[i], a[i + 8]);
      b[2 * i + 1] = _mm_unpackhi_epi8(a[i], a[i + 8]);
    }
    for (int i = 0; i < 16; ++i) a[i] = b[i];
  }
}
#endif

// Bilinear footprint of projector coordinate (u, t) in an interleaved batch of B projector
// images (B bytes per projector pixel): the four neighbours (edges clamped) and their weights.
// Shared by the AVX2 and the portable fused pattern pass so both sample identically.
struct BilinearTap {
  const uint8_t *p00, *p01, *p10, *p11;
  float w00, w01, w10, w11;
};

template <int B>
inline BilinearTap TapAt(const uint8_t* inter, int pw, int ph, float u, float t) {
  const float fx0 = std::floor(u), fy0 = std::floor(t);
  const float ax = u - fx0, ay = t - fy0;
  const int x0 = std::clamp(static_cast<int>(fx0), 0, pw - 1), x1 = std::clamp(static_cast<int>(fx0) + 1, 0, pw - 1);
  const int y0 = std::clamp(static_cast<int>(fy0), 0, ph - 1), y1 = std::clamp(static_cast<int>(fy0) + 1, 0, ph - 1);
  return {inter + (static_cast<size_t>(y0) * pw + x0) * B, inter + (static_cast<size_t>(y0) * pw + x1) * B,
          inter + (static_cast<size_t>(y1) * pw + x0) * B, inter + (static_cast<size_t>(y1) * pw + x1) * B,
          (1 - ax) * (1 - ay), ax * (1 - ay), (1 - ax) * ay, ax * ay};
}

// The common case in one fused sweep: linear response, bilinear lookup, no fill factor, one
// sample per pixel, no camera defocus, no noise: lookups, radiometry and quantisation of B
// interleaved projector images, written straight to the output images (no float copies).
#if defined(__x86_64__) && defined(__GNUC__)
#define SLSHADOW_SIM_AVX2 1
// One row of FusedDirectBilinear with AVX2: the B <= 16 images of the batch are the lanes of one
// or two vectors (the interleaved pattern bytes of one projector pixel are one 64- or 128-bit
// load; the interleaved buffer is padded by 16 bytes, lanes >= B are ignored). Same operations
// in the same order as the scalar code (mul and add kept separate: target "avx2" without "fma",
// so nothing gets contracted), hence bit-identical images. Quantisation as QuantizeValue:
// max(v, 0) maps NaN and negatives to 0; min(v + 0.5, full) then truncation.
// 16 pixels x 16 images of 8-bit values (tile[pixel][image]) stored as 16 bytes into each of the
// first `images` image rows at column x0: a 16 x 16 byte transpose (Transpose16x16).
__attribute__((target("avx2"))) inline void StoreTransposed16(const uint8_t (*tile)[16], uint8_t* const* rows, int x0,
                                                                int images) {
  __m128i a[16];
  for (int i = 0; i < 16; ++i) a[i] = _mm_load_si128(reinterpret_cast<const __m128i*>(tile[i]));
  Transpose16x16(a);
  for (int k = 0; k < images; ++k) _mm_storeu_si128(reinterpret_cast<__m128i*>(rows[k] + x0), a[k]);
}

template <int B, typename Out>
__attribute__((target("avx2"))) void FusedRowAvx2(const GeometryBuffer& g, size_t row_start, int w,
                                                     const uint8_t* inter, int pw, int ph, float ambient, float scale,
                                                     const float* vig, float full, Out* const* rows) {
  const __m256 zero = _mm256_setzero_ps(), half = _mm256_set1_ps(0.5f), vfull = _mm256_set1_ps(full);
  alignas(32) int32_t q[16];
  constexpr bool kTiled = std::is_same_v<Out, uint8_t>;  // any B <= 16; lanes >= B are not stored
  alignas(16) uint8_t tile[16][16];
  for (int x = 0; x < w; ++x) {
    const size_t i = row_start + static_cast<size_t>(x);
    const float f = g.factor[i];
    const __m256 base = _mm256_set1_ps(ambient * g.albedo[i]);
    __m256 acc = base, acc_hi = base;
    if (f > 0) {
      const BilinearTap tap = TapAt<B>(inter, pw, ph, g.proj_x[i], g.proj_y[i]);
      const __m256 w00 = _mm256_set1_ps(tap.w00), w01 = _mm256_set1_ps(tap.w01);
      const __m256 w10 = _mm256_set1_ps(tap.w10), w11 = _mm256_set1_ps(tap.w11);
      const __m256 gain = _mm256_set1_ps(f * (1.0f / 255));
      const uint8_t *p00 = tap.p00, *p01 = tap.p01, *p10 = tap.p10, *p11 = tap.p11;
      if constexpr (B <= 8) {
#define SLSHADOW_LOAD8(ptr) \
  _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(ptr))))
        __m256 sum = _mm256_mul_ps(w00, SLSHADOW_LOAD8(p00));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w01, SLSHADOW_LOAD8(p01)));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w10, SLSHADOW_LOAD8(p10)));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w11, SLSHADOW_LOAD8(p11)));
#undef SLSHADOW_LOAD8
        acc = _mm256_add_ps(base, _mm256_mul_ps(gain, sum));
      } else {
        const __m128i b00 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p00));
        const __m128i b01 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p01));
        const __m128i b10 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p10));
        const __m128i b11 = _mm_loadu_si128(reinterpret_cast<const __m128i*>(p11));
#define SLSHADOW_LO(b) _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(b))
#define SLSHADOW_HI(b) _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_srli_si128(b, 8)))
        __m256 sum = _mm256_mul_ps(w00, SLSHADOW_LO(b00));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w01, SLSHADOW_LO(b01)));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w10, SLSHADOW_LO(b10)));
        sum = _mm256_add_ps(sum, _mm256_mul_ps(w11, SLSHADOW_LO(b11)));
        acc = _mm256_add_ps(base, _mm256_mul_ps(gain, sum));
        __m256 sum_hi = _mm256_mul_ps(w00, SLSHADOW_HI(b00));
        sum_hi = _mm256_add_ps(sum_hi, _mm256_mul_ps(w01, SLSHADOW_HI(b01)));
        sum_hi = _mm256_add_ps(sum_hi, _mm256_mul_ps(w10, SLSHADOW_HI(b10)));
        sum_hi = _mm256_add_ps(sum_hi, _mm256_mul_ps(w11, SLSHADOW_HI(b11)));
#undef SLSHADOW_LO
#undef SLSHADOW_HI
        acc_hi = _mm256_add_ps(base, _mm256_mul_ps(gain, sum_hi));
      }
    }
    const __m256 m = _mm256_set1_ps(scale * (vig ? vig[x] : 1.0f));
    const __m256 c = _mm256_min_ps(_mm256_add_ps(_mm256_max_ps(_mm256_mul_ps(acc, m), zero), half), vfull);
    if constexpr (kTiled) {
      // 8-bit output: values 0..255, packed to the 16 bytes of this pixel (image order kept; bytes
      // >= B unused), written to the B images 16 pixels at a time (not B single-byte stores).
      const __m256 c_hi = _mm256_min_ps(_mm256_add_ps(_mm256_max_ps(_mm256_mul_ps(acc_hi, m), zero), half), vfull);
      const __m256i p16 = _mm256_permute4x64_epi64(
          _mm256_packus_epi32(_mm256_cvttps_epi32(c), _mm256_cvttps_epi32(c_hi)), 0xD8);
      _mm_store_si128(reinterpret_cast<__m128i*>(tile[x & 15]),
                      _mm_packus_epi16(_mm256_castsi256_si128(p16), _mm256_extracti128_si256(p16, 1)));
      if ((x & 15) == 15) StoreTransposed16(tile, rows, x - 15, B);
    } else {
      _mm256_store_si256(reinterpret_cast<__m256i*>(q), _mm256_cvttps_epi32(c));
      if constexpr (B > 8) {
        const __m256 c_hi = _mm256_min_ps(_mm256_add_ps(_mm256_max_ps(_mm256_mul_ps(acc_hi, m), zero), half), vfull);
        _mm256_store_si256(reinterpret_cast<__m256i*>(q + 8), _mm256_cvttps_epi32(c_hi));
      }
      for (int k = 0; k < B; ++k) rows[k][x] = static_cast<Out>(q[k]);
    }
  }
  if constexpr (kTiled) {
    for (int x = w & ~15; x < w; ++x) {
      for (int k = 0; k < B; ++k) rows[k][x] = tile[x & 15][k];
    }
  }
}

bool HaveAvx2() {
  static const bool have = __builtin_cpu_supports("avx2");
  return have;
}
#endif

template <int B, typename Out>
void FusedDirectBilinear(const GeometryBuffer& g, const uint8_t* inter, int pw, int ph, float ambient, float scale,
                         const cv::Mat& vignetting, float full, std::vector<cv::Mat>& out) {
  const int w = g.width, h = g.height;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 4), [&](const tbb::blocked_range<int>& r) {
    Out* rows[B];
    float acc[B];
    for (int y = r.begin(); y < r.end(); ++y) {
      for (int k = 0; k < B; ++k) rows[k] = out[static_cast<size_t>(k)].ptr<Out>(y);
      const float* vig = vignetting.empty() ? nullptr : vignetting.ptr<float>(y);
#ifdef SLSHADOW_SIM_AVX2
      if constexpr (B <= 16) {
        if (HaveAvx2()) {
          FusedRowAvx2<B, Out>(g, static_cast<size_t>(y) * w, w, inter, pw, ph, ambient, scale, vig, full, rows);
          continue;
        }
      }
#endif
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        const float f = g.factor[i];
        const float base = ambient * g.albedo[i];
        if (f > 0) {
          const BilinearTap t = TapAt<B>(inter, pw, ph, g.proj_x[i], g.proj_y[i]);
          const float gain = f * (1.0f / 255);
          for (int k = 0; k < B; ++k) {
            acc[k] = base + gain * (t.w00 * t.p00[k] + t.w01 * t.p01[k] + t.w10 * t.p10[k] + t.w11 * t.p11[k]);
          }
        } else {
          for (int k = 0; k < B; ++k) acc[k] = base;
        }
        const float m = scale * (vig ? vig[x] : 1.0f);
        for (int k = 0; k < B; ++k) rows[k][x] = static_cast<Out>(QuantizeValue(acc[k] * m, full));
      }
    }
  });
}

inline uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
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
      : k1(cam.params[CameraModel::kK1]), k2(cam.params[CameraModel::kK2]), k3(cam.params[CameraModel::kK3]),
        p1(cam.params[CameraModel::kP1]), p2(cam.params[CameraModel::kP2]) {}
};

// One Newton step on distort(x, y) = (xd, yd) with the analytic Jacobian [a b; b d]: updates
// (x, y) and returns the Jacobian's determinant (the step is meaningless unless it is > 0) and
// |dx| + |dy| in `step`. Branch-free, so NewtonRow vectorises over it.
inline double NewtonStep(const Distortion& k, double xd, double yd, double& x, double& y, double& step) {
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
bool UndistortFrom(const CameraModel& cam, double fold_r2, double xd_target, double yd_target, Eigen::Vector2d& guess) {
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
SLSHADOW_LANE_CLONES void NewtonRow(const CameraModel& cam, double fold_r2, const double* __restrict xd, double yd,
                                    double* __restrict x_io, double* __restrict y_io, uint8_t* __restrict ok, int n) {
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
SLSHADOW_LANE_CLONES void DirectionsRow(const double* __restrict x, const double* __restrict y, double* __restrict scratch,
                                        float* __restrict out, int width, int nn) {
  const int m = width * nn;
  for (int i = 0; i < m; ++i) scratch[i] = 1 / std::sqrt(x[i] * x[i] + y[i] * y[i] + 1);
  for (int px = 0, i = 0; px < width; ++px) {
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
  SLSHADOW_THROW_IF(samples_per_axis < 1 || samples_per_axis > 16, "samples_per_axis must be in 1..16 (got ",
                    samples_per_axis, ")");
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
    std::vector<double> xd(m);  // normalised distorted x of every sample of a row (the same on each row)
    for (int px = 0, j = 0; px < camera.width; ++px) {
      for (int a = 0; a < nn; ++a, ++j) xd[static_cast<size_t>(j)] = (px + (a + 0.5) / nn - 0.5 - camera.cx()) / camera.fx();
    }
    tbb::parallel_for(tbb::blocked_range<int>(0, camera.height * nn, 32), [&](const tbb::blocked_range<int>& r) {
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
          NewtonRow<3>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(), row_samples);
          NewtonRow<2>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(), row_samples);
        } else if (k == 1) {
          x = x1;
          y = y1;
          NewtonRow<3>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(), row_samples);
        } else {
          for (size_t j = 0; j < m; ++j) {
            x[j] = 2 * x1[j] - x2[j];
            y[j] = 2 * y1[j] - y2[j];
          }
          NewtonRow<2>(camera, fold_r2, xd.data(), yd, x.data(), y.data(), ok.data(), row_samples);
        }
        // Lanes not yet solved: started from the left neighbours' solutions (extrapolated when
        // there are two), then the camera model's own solver, which decides (NaN: no solution
        // past the fold of the distortion).
        for (size_t j = 0; j < m; ++j) {
          if (ok[j]) continue;
          Eigen::Vector2d start(xd[j], yd);
          const bool left1 = j >= 1 && std::isfinite(x[j - 1]), left2 = left1 && j >= 2 && std::isfinite(x[j - 2]);
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
                             (static_cast<double>(j % static_cast<size_t>(nn)) + 0.5) / nn - 0.5;
            xy = camera.UndistortToNormalized(Eigen::Vector2d(u, v));
          }
          x[j] = xy ? xy->x() : kNaN;
          y[j] = xy ? xy->y() : kNaN;
        }
        // Sub-row b of pixel row py holds samples (px, a) at (py * width + px) * nn * nn + b * nn + a.
        float* out = dirs[static_cast<size_t>(py) * camera.width * nn * nn + static_cast<size_t>(b * nn)].data();
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

GeometryBuffer TraceGeometry(const RayCaster& caster, const Rig& rig, int camera_index, const CameraRays& rays,
                             TraceMode mode, bool ground_truth) {
  const auto start = std::chrono::steady_clock::now();
  const Scene& scene = caster.scene();
  SLSHADOW_THROW_IF(camera_index < 0 || camera_index >= static_cast<int>(rig.cameras.size()), "camera index ",
                    camera_index, " out of range (rig has ", rig.cameras.size(), " cameras)");
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name, "' has no projector: the simulator needs one");
  const RigDevice& cam = rig.cameras[static_cast<size_t>(camera_index)];
  SLSHADOW_THROW_IF(rays.width != cam.model.width || rays.height != cam.model.height ||
                        rays.samples_per_axis != scene.layers.supersampling,
                    "camera rays do not match camera '", cam.name, "' and the scene's supersampling");
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
  const double d_ref = scene.radiometry.reference_distance_mm > 0 ? scene.radiometry.reference_distance_mm : rig.working_distance_mm;
  c.ref_distance_sq = d_ref * d_ref;
  c.proj_defocus = &scene.layers.projector_defocus;
  for (const auto& o : scene.objects) {
    c.object_from_rig.push_back(o.rig_from_object.Inverse());
    c.uniform_albedo.push_back(o.albedo.IsTextured() ? std::numeric_limits<double>::quiet_NaN() : o.albedo.value);
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

PatternRenderer::PatternRenderer(const Scene& scene, const Rig& rig, int camera_index, const GeometryBuffer& geometry)
    : scene_(scene), geometry_(geometry), camera_index_(camera_index) {
  SLSHADOW_THROW_IF(!rig.projector, "rig '", rig.name, "' has no projector: the simulator needs one");
  projector_width_ = rig.projector->model.width;
  projector_height_ = rig.projector->model.height;
  full_scale_dn_ = std::ldexp(1.0, scene.radiometry.adc_bits) - 1;
  const SceneLayers& l = scene.layers;
  response_.resize(256);
  for (int v = 0; v < 256; ++v) {
    double r = v / 255.0;
    if (l.response_enabled) r = l.response_lut.empty() ? std::pow(r, l.gamma) : l.response_lut[static_cast<size_t>(v)];
    response_[static_cast<size_t>(v)] = static_cast<float>(r);
  }
  linear_response_ = !l.response_enabled;
  const CameraModel& model = rig.cameras[static_cast<size_t>(camera_index)].model;
  if (l.vignetting_enabled) {
    // Smooth in the image: evaluated on an 8-pixel grid and interpolated bilinearly.
    constexpr int kStep = 8;
    const int gw = model.width / kStep + 2, gh = model.height / kStep + 2;
    cv::Mat grid(gh, gw, CV_32FC1);
    for (int j = 0; j < gh; ++j) {
      for (int i = 0; i < gw; ++i) {
        const auto xy = model.UndistortToNormalized(Eigen::Vector2d(i * kStep, j * kStep));
        // Outside the region where undistortion converges: treat as the image corner's value.
        const double r2 = xy ? xy->squaredNorm() : 0.0;
        double v;
        if (l.vignetting_cos4) {
          v = 1.0 / ((1 + r2) * (1 + r2));
        } else {
          const auto& a = l.vignetting_coefficients;
          v = 1 + a[0] * r2 + a[1] * r2 * r2 + a[2] * r2 * r2 * r2;
        }
        grid.at<float>(j, i) = static_cast<float>(std::max(0.0, v));
      }
    }
    vignetting_ = cv::Mat(model.height, model.width, CV_32FC1);
    for (int y = 0; y < model.height; ++y) {
      for (int x = 0; x < model.width; ++x) {
        vignetting_.at<float>(y, x) = Bilinear(grid.ptr<float>(), gw, gh, static_cast<float>(x) / kStep, static_cast<float>(y) / kStep);
      }
    }
  }
  if (l.camera_defocus.enabled) {
    cv::Mat sigma(model.height, model.width, CV_32FC1, cv::Scalar(0));
    double max_sigma = 0;
    for (int y = 0; y < model.height; ++y) {
      for (int x = 0; x < model.width; ++x) {
        const float d = geometry.depth_mm.at<float>(y, x);
        const double s = std::isfinite(d) ? l.camera_defocus.SigmaPx(model.fx(), d) : 0.0;
        sigma.at<float>(y, x) = static_cast<float>(s);
        max_sigma = std::max(max_sigma, s);
      }
    }
    camera_sigmas_ = SigmaLevels(max_sigma);
    if (!camera_sigmas_.empty()) {
      // Background pixels (no surface) stay sharp: sigma 0.
      camera_level_ = sigma * ((camera_sigmas_.size() - 1) / max_sigma);
    }
  }
  if (l.projector_defocus.enabled && !geometry.proj_sigma_px.empty()) {
    const float max_sigma = *std::max_element(geometry.proj_sigma_px.begin(), geometry.proj_sigma_px.end());
    projector_sigmas_ = SigmaLevels(max_sigma);
  }
}

cv::Mat PatternRenderer::RenderIrradiance(const cv::Mat& projector_image) const {
  return RenderIrradianceBatch({projector_image})[0];
}

std::vector<cv::Mat> PatternRenderer::RenderIrradianceBatch(const std::vector<cv::Mat>& images) const {
  const int batch = static_cast<int>(images.size());
  SLSHADOW_THROW_IF(batch < 1 || batch > kMaxBatch, "pattern batch must hold 1..", kMaxBatch, " images (got ", batch, ")");
  for (const cv::Mat& projector_image : images) {
    SLSHADOW_THROW_IF(projector_image.type() != CV_8UC1 || projector_image.cols != projector_width_ ||
                          projector_image.rows != projector_height_ || !projector_image.isContinuous(),
                      "projector image must be 8-bit single-channel ", projector_width_, "x", projector_height_,
                      " (got type ", projector_image.type(), ", ", projector_image.cols, "x", projector_image.rows, ")");
  }
  const SceneLayers& l = scene_.layers;
  const int pw = projector_width_, ph = projector_height_;
  // Float intensity images through the response curve, unless the response is linear and no
  // projector blur is needed (then lookups read the 8-bit images directly).
  const bool direct = linear_response_ && projector_sigmas_.empty();
  // The batch is interleaved per projector pixel ([pixel][image]) so one lookup reads all images
  // of the batch from the same cache lines.
  const size_t n_proj = static_cast<size_t>(pw) * ph;
  std::vector<uint8_t> inter8;                 // direct path
  std::vector<std::vector<float>> inter_f;    // [blur level][pixel * batch + image]
  if (direct) {
    inter8.resize(n_proj * batch);
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_proj, 4096), [&](const tbb::blocked_range<size_t>& r) {
      for (int k = 0; k < batch; ++k) {
        const uint8_t* src = images[static_cast<size_t>(k)].ptr<uint8_t>();
        for (size_t i = r.begin(); i < r.end(); ++i) inter8[i * batch + k] = src[i];
      }
    });
  } else {
    const size_t n_levels = std::max<size_t>(1, projector_sigmas_.size());
    inter_f.assign(n_levels, std::vector<float>(n_proj * batch));
    tbb::parallel_for(0, batch, [&](int k) {
      cv::Mat intensity(ph, pw, CV_32FC1);
      for (int y = 0; y < ph; ++y) {
        const uint8_t* src = images[static_cast<size_t>(k)].ptr<uint8_t>(y);
        float* dst = intensity.ptr<float>(y);
        for (int x = 0; x < pw; ++x) dst[x] = response_[src[x]];
      }
      for (size_t lv = 0; lv < n_levels; ++lv) {
        const cv::Mat level = projector_sigmas_.empty() ? intensity : Blur(intensity, projector_sigmas_[lv]);
        const float* src = level.ptr<float>();
        float* dst = inter_f[lv].data();
        for (size_t i = 0; i < n_proj; ++i) dst[i * batch + k] = src[i];
      }
    });
  }
  const int w = geometry_.width, h = geometry_.height;
  const int spp = geometry_.samples_per_axis * geometry_.samples_per_axis;
  const float scale = static_cast<float>(scene_.radiometry.exposure * full_scale_dn_ / spp);
  const float ambient = static_cast<float>(l.ambient);
  const bool bilinear = scene_.radiometry.bilinear_lookup;
  const bool fill = l.fill_factor < 1;
  const float half_side = static_cast<float>(std::sqrt(l.fill_factor) / 2);
  const int top_level = projector_sigmas_.empty() ? 0 : static_cast<int>(projector_sigmas_.size()) - 1;
  const float level_scale = projector_sigmas_.empty() ? 0.0f : static_cast<float>(top_level / projector_sigmas_.back());
  std::vector<cv::Mat> out(static_cast<size_t>(batch));
  for (auto& m : out) m.create(h, w, CV_32FC1);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 4), [&](const tbb::blocked_range<int>& r) {
    float acc[kMaxBatch];
    for (int y = r.begin(); y < r.end(); ++y) {
      const float* vig = vignetting_.empty() ? nullptr : vignetting_.ptr<float>(y);
      for (int x = 0; x < w; ++x) {
        for (int k = 0; k < batch; ++k) acc[k] = 0;
        const size_t i0 = (static_cast<size_t>(y) * w + x) * spp;
        for (int s = 0; s < spp; ++s) {
          const size_t i = i0 + s;
          const float f = geometry_.factor[i];
          const float base = ambient * geometry_.albedo[i];
          if (!(f > 0)) {
            for (int k = 0; k < batch; ++k) acc[k] += base;
            continue;
          }
          const float u = geometry_.proj_x[i], t = geometry_.proj_y[i];
          if (fill || !bilinear) {
            // Pixel-exact: the projector pixel containing the point (dark in the fill gaps).
            const int xi = std::clamp(static_cast<int>(std::lround(u)), 0, pw - 1);
            const int yi = std::clamp(static_cast<int>(std::lround(t)), 0, ph - 1);
            const bool lit = !fill || (std::abs(u - std::round(u)) <= half_side && std::abs(t - std::round(t)) <= half_side);
            const size_t idx = (static_cast<size_t>(yi) * pw + xi) * batch;
            const float g = lit ? f : 0.0f;
            if (direct) {
              for (int k = 0; k < batch; ++k) acc[k] += base + g * (1.0f / 255) * inter8[idx + k];
            } else {
              const float* p = inter_f[0].data() + idx;
              for (int k = 0; k < batch; ++k) acc[k] += base + g * p[k];
            }
            continue;
          }
          // Bilinear weights, shared by every image of the batch; clamped at the borders.
          const float fx0 = std::floor(u), fy0 = std::floor(t);
          const float ax = u - fx0, ay = t - fy0;
          const int x0 = std::clamp(static_cast<int>(fx0), 0, pw - 1), x1 = std::clamp(static_cast<int>(fx0) + 1, 0, pw - 1);
          const int y0 = std::clamp(static_cast<int>(fy0), 0, ph - 1), y1 = std::clamp(static_cast<int>(fy0) + 1, 0, ph - 1);
          const size_t i00 = (static_cast<size_t>(y0) * pw + x0) * batch, i01 = (static_cast<size_t>(y0) * pw + x1) * batch;
          const size_t i10 = (static_cast<size_t>(y1) * pw + x0) * batch, i11 = (static_cast<size_t>(y1) * pw + x1) * batch;
          const float w00 = (1 - ax) * (1 - ay), w01 = ax * (1 - ay), w10 = (1 - ax) * ay, w11 = ax * ay;
          if (direct) {
            const float g = f * (1.0f / 255);
            const uint8_t* p = inter8.data();
            for (int k = 0; k < batch; ++k) {
              acc[k] += base + g * (w00 * p[i00 + k] + w01 * p[i01 + k] + w10 * p[i10 + k] + w11 * p[i11 + k]);
            }
          } else {
            int l0 = 0, l1 = 0;
            float a = 0;
            if (top_level > 0) {
              const float lv = geometry_.proj_sigma_px[i] * level_scale;
              l0 = std::min(static_cast<int>(lv), top_level);
              l1 = std::min(l0 + 1, top_level);
              a = lv - l0;
            }
            const float* p0 = inter_f[static_cast<size_t>(l0)].data();
            const float* p1 = inter_f[static_cast<size_t>(l1)].data();
            for (int k = 0; k < batch; ++k) {
              const float v0 = w00 * p0[i00 + k] + w01 * p0[i01 + k] + w10 * p0[i10 + k] + w11 * p0[i11 + k];
              const float v1 = w00 * p1[i00 + k] + w01 * p1[i01 + k] + w10 * p1[i10 + k] + w11 * p1[i11 + k];
              acc[k] += base + f * ((1 - a) * v0 + a * v1);
            }
          }
        }
        const float m = scale * (vig ? vig[x] : 1.0f);
        for (int k = 0; k < batch; ++k) out[static_cast<size_t>(k)].ptr<float>(y)[x] = acc[k] * m;
      }
    }
  });
  if (!camera_sigmas_.empty()) {
    tbb::parallel_for(0, batch, [&](int k) { out[static_cast<size_t>(k)] = ApplyCameraDefocus(out[static_cast<size_t>(k)]); });
  }
  return out;
}

cv::Mat PatternRenderer::ApplyCameraDefocus(const cv::Mat& image) const {
  const int w = image.cols, h = image.rows;
  std::vector<cv::Mat> blurred;
  for (double sgm : camera_sigmas_) blurred.push_back(Blur(image, sgm));
  cv::Mat mixed(h, w, CV_32FC1);
  const int top = static_cast<int>(blurred.size()) - 1;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      for (int x = 0; x < w; ++x) {
        const float lv = camera_level_.at<float>(y, x);
        const int l0 = std::min(static_cast<int>(lv), top), l1 = std::min(l0 + 1, top);
        const float a = lv - l0;
        mixed.at<float>(y, x) = (1 - a) * blurred[static_cast<size_t>(l0)].at<float>(y, x) + a * blurred[static_cast<size_t>(l1)].at<float>(y, x);
      }
    }
  });
  return mixed;
}

std::vector<cv::Mat> PatternRenderer::RenderBatch(const std::vector<cv::Mat>& images, int first_pattern_index) const {
  const SceneLayers& l = scene_.layers;
  const int batch = static_cast<int>(images.size());
  const bool fused = !l.response_enabled && projector_sigmas_.empty() && scene_.radiometry.bilinear_lookup && l.fill_factor >= 1 &&
                     geometry_.samples_per_axis == 1 && camera_sigmas_.empty() && !l.noise_enabled && batch <= 16;
  if (fused) {
    const int pw = projector_width_, ph = projector_height_;
    for (const cv::Mat& m : images) {
      SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.cols != pw || m.rows != ph || !m.isContinuous(),
                        "projector image must be 8-bit single-channel ", pw, "x", ph, " (got type ", m.type(), ", ", m.cols,
                        "x", m.rows, ")");
    }
    const size_t n_proj = static_cast<size_t>(pw) * ph;
    // + 16: the vector kernel reads 8 or 16 bytes per projector pixel whatever the batch size.
    // Pooled (no page faults after the first batch), every byte written below.
    cv::Mat inter_block;
    CreatePooled(inter_block, 1, static_cast<int>(n_proj * batch + 16), CV_8UC1);
    uint8_t* const inter_data = inter_block.ptr<uint8_t>();
    std::fill(inter_data + n_proj * batch, inter_data + n_proj * batch + 16, uint8_t{0});
    tbb::parallel_for(tbb::blocked_range<size_t>(0, n_proj, 16384), [&](const tbb::blocked_range<size_t>& r) {
      const uint8_t* src[kMaxBatch];
      for (int k = 0; k < batch; ++k) src[k] = images[static_cast<size_t>(k)].ptr<uint8_t>();
      size_t i = r.begin();
#if defined(__x86_64__)
      if (batch == 16) {
        // 16 projector pixels of the 16 images at a time: one byte transpose.
        for (; i + 16 <= r.end(); i += 16) {
          __m128i a[16];
          for (int k = 0; k < 16; ++k) a[k] = _mm_loadu_si128(reinterpret_cast<const __m128i*>(src[k] + i));
          Transpose16x16(a);
          for (int j = 0; j < 16; ++j) _mm_storeu_si128(reinterpret_cast<__m128i*>(inter_data + (i + static_cast<size_t>(j)) * 16), a[j]);
        }
      }
#endif
      uint8_t* dst = inter_data + i * batch;
      for (; i < r.end(); ++i) {
        for (int k = 0; k < batch; ++k) *dst++ = src[k][i];
      }
    });
    const bool wide = scene_.radiometry.adc_bits > 8;
    // The batch's images as row bands of one pooled block (recycled across scans: no first-touch
    // faults after the first); each image is a continuous sub-matrix that keeps the block alive.
    cv::Mat block;
    CreatePooled(block, geometry_.height * batch, geometry_.width, wide ? CV_16UC1 : CV_8UC1);
    std::vector<cv::Mat> out(static_cast<size_t>(batch));
    for (int k = 0; k < batch; ++k) out[static_cast<size_t>(k)] = block.rowRange(k * geometry_.height, (k + 1) * geometry_.height);
    const float scale = static_cast<float>(scene_.radiometry.exposure * full_scale_dn_);
    const float ambient = static_cast<float>(l.ambient);
    const float full = static_cast<float>(full_scale_dn_);
    auto run = [&](auto batch_tag) {
      constexpr int kB = decltype(batch_tag)::value;
      if (wide) {
        FusedDirectBilinear<kB, uint16_t>(geometry_, inter_data, pw, ph, ambient, scale, vignetting_, full, out);
      } else {
        FusedDirectBilinear<kB, uint8_t>(geometry_, inter_data, pw, ph, ambient, scale, vignetting_, full, out);
      }
    };
    switch (batch) {
      case 1: run(std::integral_constant<int, 1>()); break;
      case 2: run(std::integral_constant<int, 2>()); break;
      case 3: run(std::integral_constant<int, 3>()); break;
      case 4: run(std::integral_constant<int, 4>()); break;
      case 5: run(std::integral_constant<int, 5>()); break;
      case 6: run(std::integral_constant<int, 6>()); break;
      case 7: run(std::integral_constant<int, 7>()); break;
      case 8: run(std::integral_constant<int, 8>()); break;
      case 9: run(std::integral_constant<int, 9>()); break;
      case 10: run(std::integral_constant<int, 10>()); break;
      case 11: run(std::integral_constant<int, 11>()); break;
      case 12: run(std::integral_constant<int, 12>()); break;
      case 13: run(std::integral_constant<int, 13>()); break;
      case 14: run(std::integral_constant<int, 14>()); break;
      case 15: run(std::integral_constant<int, 15>()); break;
      default: run(std::integral_constant<int, 16>()); break;
    }
    return out;
  }
  std::vector<cv::Mat> irradiance = RenderIrradianceBatch(images);
  std::vector<cv::Mat> out(irradiance.size());
  tbb::parallel_for(size_t{0}, out.size(), [&](size_t k) {
    out[k] = Quantize(irradiance[k], first_pattern_index + static_cast<int>(k));
  });
  return out;
}

cv::Mat PatternRenderer::Render(const cv::Mat& projector_image, int pattern_index) const {
  return RenderBatch({projector_image}, pattern_index)[0];
}

cv::Mat PatternRenderer::Quantize(const cv::Mat& irradiance, int pattern_index) const {
  const SceneLayers& l = scene_.layers;
  const int w = geometry_.width, h = geometry_.height;
  const bool wide = scene_.radiometry.adc_bits > 8;
  cv::Mat out(h, w, wide ? CV_16UC1 : CV_8UC1);
  const double full = full_scale_dn_;
  const double k_dn_per_e = full / l.full_well_e;
  const uint64_t stream = SplitMix64(l.seed ^ SplitMix64((static_cast<uint64_t>(camera_index_) << 32) ^
                                                          static_cast<uint64_t>(static_cast<uint32_t>(pattern_index))));
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      const float* src = irradiance.ptr<float>(y);
      for (int x = 0; x < w; ++x) {
        double dn = src[x];
        if (l.noise_enabled) {
          const double mu_e = std::max(0.0, dn / k_dn_per_e);
          const uint64_t r1 = SplitMix64(stream + static_cast<uint64_t>(y) * w + x);
          const uint64_t r2 = SplitMix64(r1);
          // Box-Muller: two independent standard normals.
          // (single precision: 24-bit uniforms are plenty for sensor noise, and ~2x faster)
          const float u1 = (static_cast<float>(r1 >> 40) + 0.5f) * 0x1.0p-24f;
          const float u2 = static_cast<float>(r2 >> 40) * 0x1.0p-24f;
          const float rad = std::sqrt(-2.0f * std::log(u1));
          const float angle = 6.2831853f * u2;
          const double n1 = rad * std::cos(angle), n2 = rad * std::sin(angle);
          const double e = std::min(mu_e + std::sqrt(mu_e) * n1 + l.read_noise_e * n2, l.full_well_e);
          dn = e * k_dn_per_e;
        }
        const int q = l.noise_enabled ? static_cast<int>(std::clamp(std::round(dn), 0.0, full))
                                      : QuantizeValue(src[x], static_cast<float>(full));
        if (wide) {
          out.ptr<uint16_t>(y)[x] = static_cast<uint16_t>(q);
        } else {
          out.ptr<uint8_t>(y)[x] = static_cast<uint8_t>(q);
        }
      }
    }
  });
  return out;
}

}  // namespace slshadow
