#include "sim/raycaster.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <embree3/rtcore.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"
#include "sim/internal/lanes.h"

namespace slshadow {

std::string ToString(TraceMode value) { return EnumToString(value, kTraceModeNames); }

TraceMode TraceModeFromString(const std::string& name) {
  return EnumFromString("trace_mode", name, kTraceModeNames);
}
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
// Up to this many analytic primitives are tested outside Embree by every ray.
constexpr std::ptrdiff_t kMaxDirectPrimitives = 8;

using namespace lanes;  // NOLINT: the lane vector helpers of sim/internal/lanes.h

// A packet's 16 float lanes as doubles (exact). A plain loop: GCC converts whole registers
// there, but one 4-float vector through two halves.
inline void Widen(const float* __restrict in, double* __restrict out) {
  for (int i = 0; i < RayPacket::kSize; ++i) out[i] = in[i];
}
// std::min / std::max lane by lane with their exact semantics (the first argument when the
// comparison is false, so NaN propagates as in the scalar code).
inline V4d Min(const V4d& a, const V4d& b) { return b < a ? b : a; }
inline V4d Max(const V4d& a, const V4d& b) { return a < b ? b : a; }
inline V4d Abs(const V4d& a) { return (V4d)((V4l)a & INT64_MAX); }
inline V4i Narrow(const V4l& mask) { return __builtin_convertvector(mask, V4i); }

// Data an Embree user geometry needs: the object and its transform.
struct PrimitiveData {
  const SceneObject* object = nullptr;
  int32_t object_index = -1;
  Eigen::Matrix3d object_from_rig_rotation;
  Eigen::Matrix3d rig_from_object_rotation;
  Eigen::Vector3d translation;  // rig_from_object translation
  // A plane's unit normal as a hit stores it (RayCaster::Intersect: made float, then normalised).
  Eigen::Vector3f plane_normal = Eigen::Vector3f::Zero();
};

bool Better(double t, double t_near, double t_far, double best) {
  return t > t_near && t < t_far && t < best;
}

void PrimitiveBounds(const struct RTCBoundsFunctionArguments* args) {
  const auto* data = static_cast<const PrimitiveData*>(args->geometryUserPtr);
  const SceneObject& o = *data->object;
  Eigen::Vector3d half;
  switch (o.type) {
    case ObjectType::kPlane:
      half = Eigen::Vector3d(o.size_mm.x() / 2, o.size_mm.y() / 2, 0);
      break;
    case ObjectType::kSphere:
      half = Eigen::Vector3d::Constant(o.radius_mm);
      break;
    case ObjectType::kCylinder:
      half = Eigen::Vector3d(o.radius_mm, o.radius_mm, o.height_mm / 2);
      break;
    case ObjectType::kBox:
      half = o.size_mm / 2;
      break;
    default:
      half = Eigen::Vector3d::Zero();
      break;
  }
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (int c = 0; c < 8; ++c) {
    const Eigen::Vector3d corner((c & 1) ? half.x() : -half.x(), (c & 2) ? half.y() : -half.y(),
                                 (c & 4) ? half.z() : -half.z());
    const Eigen::Vector3d p = data->rig_from_object_rotation * corner + data->translation;
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  const double pad = 1e-3 + 1e-6 * hi.cwiseAbs().maxCoeff();
  args->bounds_o->lower_x = static_cast<float>(lo.x() - pad);
  args->bounds_o->lower_y = static_cast<float>(lo.y() - pad);
  args->bounds_o->lower_z = static_cast<float>(lo.z() - pad);
  args->bounds_o->upper_x = static_cast<float>(hi.x() + pad);
  args->bounds_o->upper_y = static_cast<float>(hi.y() + pad);
  args->bounds_o->upper_z = static_cast<float>(hi.z() + pad);
}

bool IntersectInRig(const PrimitiveData& data, float ox, float oy, float oz, float dx, float dy,
                    float dz, float tnear, float tfar, PrimitiveHit* hit) {
  if (data.object->type == ObjectType::kPlane) {
    // The plane z = 0 of the object frame, as IntersectPrimitive does it but with only the rows
    // it needs (the table under a part is hit by nearly every ray: this is the hot case).
    const Eigen::Matrix3d& m = data.object_from_rig_rotation;
    const double rx = ox - data.translation.x(), ry = oy - data.translation.y(),
                 rz = oz - data.translation.z();
    const double o_z = m(2, 0) * rx + m(2, 1) * ry + m(2, 2) * rz;
    const double d_z = m(2, 0) * dx + m(2, 1) * dy + m(2, 2) * dz;
    if (d_z == 0) return false;
    const double t = -o_z / d_z;
    if (!(t > tnear && t < tfar)) return false;
    const double px = (m(0, 0) * rx + m(0, 1) * ry + m(0, 2) * rz) +
                      t * (m(0, 0) * dx + m(0, 1) * dy + m(0, 2) * dz);
    const double py = (m(1, 0) * rx + m(1, 1) * ry + m(1, 2) * rz) +
                      t * (m(1, 0) * dx + m(1, 1) * dy + m(1, 2) * dz);
    if (std::abs(px) > data.object->size_mm.x() / 2 || std::abs(py) > data.object->size_mm.y() / 2)
      return false;
    hit->t = t;
    hit->normal = data.rig_from_object_rotation.col(2);
    return true;
  }
  const Eigen::Vector3d o =
      data.object_from_rig_rotation * (Eigen::Vector3d(ox, oy, oz) - data.translation);
  const Eigen::Vector3d d = data.object_from_rig_rotation * Eigen::Vector3d(dx, dy, dz);
  if (!IntersectPrimitive(*data.object, o, d, tnear, tfar, hit)) return false;
  hit->normal = data.rig_from_object_rotation * hit->normal;
  return true;
}

void PrimitiveIntersect(const RTCIntersectFunctionNArguments* args) {
  const auto* data = static_cast<const PrimitiveData*>(args->geometryUserPtr);
  RTCRayN* ray = RTCRayHitN_RayN(args->rayhit, args->N);
  RTCHitN* h = RTCRayHitN_HitN(args->rayhit, args->N);
  const unsigned n = args->N;
  for (unsigned i = 0; i < n; ++i) {
    if (args->valid[i] == 0) continue;
    PrimitiveHit hit;
    if (!IntersectInRig(*data, RTCRayN_org_x(ray, n, i), RTCRayN_org_y(ray, n, i),
                        RTCRayN_org_z(ray, n, i), RTCRayN_dir_x(ray, n, i),
                        RTCRayN_dir_y(ray, n, i), RTCRayN_dir_z(ray, n, i),
                        RTCRayN_tnear(ray, n, i), RTCRayN_tfar(ray, n, i), &hit)) {
      continue;
    }
    RTCRayN_tfar(ray, n, i) = static_cast<float>(hit.t);
    RTCHitN_Ng_x(h, n, i) = static_cast<float>(hit.normal.x());
    RTCHitN_Ng_y(h, n, i) = static_cast<float>(hit.normal.y());
    RTCHitN_Ng_z(h, n, i) = static_cast<float>(hit.normal.z());
    RTCHitN_u(h, n, i) = 0;
    RTCHitN_v(h, n, i) = 0;
    RTCHitN_primID(h, n, i) = args->primID;
    RTCHitN_geomID(h, n, i) = args->geomID;
    RTCHitN_instID(h, n, i, 0) = args->context->instID[0];
  }
}

void PrimitiveOccluded(const RTCOccludedFunctionNArguments* args) {
  const auto* data = static_cast<const PrimitiveData*>(args->geometryUserPtr);
  RTCRayN* ray = args->ray;
  const unsigned n = args->N;
  for (unsigned i = 0; i < n; ++i) {
    if (args->valid[i] == 0) continue;
    PrimitiveHit hit;
    if (IntersectInRig(*data, RTCRayN_org_x(ray, n, i), RTCRayN_org_y(ray, n, i),
                       RTCRayN_org_z(ray, n, i), RTCRayN_dir_x(ray, n, i), RTCRayN_dir_y(ray, n, i),
                       RTCRayN_dir_z(ray, n, i), RTCRayN_tnear(ray, n, i), RTCRayN_tfar(ray, n, i),
                       &hit)) {
      RTCRayN_tfar(ray, n, i) = -kInf;
    }
  }
}

// Eigen's Vector3f::normalized() for 16 lanes (Embree's geometric normals), without branches:
// the same operations (x^2 + (y^2 + z^2), then a division by its square root; unchanged when
// that is not > 0), so the same bits.
SLSHADOW_LANE_CLONES void NormalizedLanes(const float* __restrict x, const float* __restrict y,
                                          const float* __restrict z, float* __restrict ox,
                                          float* __restrict oy, float* __restrict oz) {
  for (int i = 0; i < RayPacket::kSize; ++i) {
    const float n2 = x[i] * x[i] + (y[i] * y[i] + z[i] * z[i]);
    const float s = std::sqrt(n2);
    const bool positive = n2 > 0;
    ox[i] = positive ? x[i] / s : x[i];
    oy[i] = positive ? y[i] / s : y[i];
    oz[i] = positive ? z[i] / s : z[i];
  }
}

// IntersectInRig's plane case for the 16 lanes of a packet, four at a time, in the same
// operations (so the same results) and without branches: calls f(j, t, hit) for lanes
// 4j..4j+3 with their parameters t and hit masks. Inactive lanes compute garbage, ignored by
// the callers (a ray parallel to the plane gives d_z == 0: no hit, whatever t is).
template <class F>
__attribute__((always_inline)) inline void ForPlaneLanes(const PrimitiveData& data,
                                                         const RayPacket& p, F&& f) {
  constexpr int kN = RayPacket::kSize;
  alignas(32) double ox[kN], oy[kN], oz[kN], dx[kN], dy[kN], dz[kN], tnear[kN], tfar[kN];
  Widen(p.org_x, ox);
  Widen(p.org_y, oy);
  Widen(p.org_z, oz);
  Widen(p.dir_x, dx);
  Widen(p.dir_y, dy);
  Widen(p.dir_z, dz);
  Widen(p.tnear, tnear);
  Widen(p.tfar, tfar);
  const Eigen::Matrix3d& m = data.object_from_rig_rotation;
  const double m00 = m(0, 0), m01 = m(0, 1), m02 = m(0, 2), m10 = m(1, 0), m11 = m(1, 1),
               m12 = m(1, 2);
  const double m20 = m(2, 0), m21 = m(2, 1), m22 = m(2, 2);
  const double cx = data.translation.x(), cy = data.translation.y(), cz = data.translation.z();
  const double hx = data.object->size_mm.x() / 2, hy = data.object->size_mm.y() / 2;
  for (int j = 0; j < kN; j += 4) {
    const V4d rx = Load4<V4d>(ox + j) - cx, ry = Load4<V4d>(oy + j) - cy,
              rz = Load4<V4d>(oz + j) - cz;
    const V4d x = Load4<V4d>(dx + j), y = Load4<V4d>(dy + j), z = Load4<V4d>(dz + j);
    const V4d o_z = m20 * rx + m21 * ry + m22 * rz;
    const V4d d_z = m20 * x + m21 * y + m22 * z;
    const V4d t = -o_z / d_z;
    const V4d px = (m00 * rx + m01 * ry + m02 * rz) + t * (m00 * x + m01 * y + m02 * z);
    const V4d py = (m10 * rx + m11 * ry + m12 * rz) + t * (m10 * x + m11 * y + m12 * z);
    const V4l hit = (d_z != 0) & (t > Load4<V4d>(tnear + j)) & (t < Load4<V4d>(tfar + j)) &
                    ~(Abs(px) > hx) & ~(Abs(py) > hy);
    f(j, t, hit);
  }
}

// Closest hits with a plane for the active lanes (RayCaster::Intersect): as Embree's
// user-geometry route, tfar and the normal stored as floats (PrimitiveData::plane_normal).
SLSHADOW_LANE_CLONES void IntersectPlaneLanes(const PrimitiveData& data, RayPacket& p) {
  const V4f nx = Splat(data.plane_normal.x()), ny = Splat(data.plane_normal.y()),
            nz = Splat(data.plane_normal.z());
  ForPlaneLanes(data, p, [&](int j, const V4d& t, const V4l& hit) {
    const V4i take = MaskOf(p.active + j) & Narrow(hit);
    Store4(p.tfar + j, take ? __builtin_convertvector(t, V4f) : Load4<V4f>(p.tfar + j));
    Store4(p.ng_x + j, take ? nx : Load4<V4f>(p.ng_x + j));
    Store4(p.ng_y + j, take ? ny : Load4<V4f>(p.ng_y + j));
    Store4(p.ng_z + j, take ? nz : Load4<V4f>(p.ng_z + j));
    Store4(p.object + j, take ? Splat(data.object_index) : Load4<V4i>(p.object + j));
  });
}

// Any hit with a plane (RayCaster::Occluded): blocked lanes are marked occluded and deactivated.
SLSHADOW_LANE_CLONES void OccludePlaneLanes(const PrimitiveData& data, RayPacket& p) {
  ForPlaneLanes(data, p, [&](int j, const V4d&, const V4l& hit) {
    const V4i active = MaskOf(p.active + j);
    const V4i blocked = active & Narrow(hit);
    Store4(p.occluded + j, Load4<V4i>(p.occluded + j) | Flags(blocked));
    Store4(p.active + j, Flags(active & ~blocked));
  });
}

void ErrorCallback(void*, RTCError code, const char* message) {
  // Reported through rtcGetDeviceError checks below; keep the message for the exception.
  (void)code;
  (void)message;
}

}  // namespace

bool IntersectPrimitive(const SceneObject& object, const Eigen::Vector3d& o,
                        const Eigen::Vector3d& d, double t_near, double t_far, PrimitiveHit* hit) {
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
  switch (object.type) {
    case ObjectType::kPlane: {
      if (d.z() == 0) return false;
      const double t = -o.z() / d.z();
      if (!Better(t, t_near, t_far, best)) return false;
      const Eigen::Vector3d p = o + t * d;
      if (std::abs(p.x()) > object.size_mm.x() / 2 || std::abs(p.y()) > object.size_mm.y() / 2)
        return false;
      best = t;
      normal = Eigen::Vector3d::UnitZ();
      break;
    }
    case ObjectType::kSphere: {
      const double a = d.squaredNorm();
      const double b = o.dot(d);
      const double c = o.squaredNorm() - object.radius_mm * object.radius_mm;
      const double disc = b * b - a * c;
      if (disc < 0) return false;
      // Numerically stable roots.
      const double q = -(b + std::copysign(std::sqrt(disc), b));
      const double t1 = q / a, t2 = q != 0 ? c / q : t1;
      for (double t : {std::min(t1, t2), std::max(t1, t2)}) {
        if (Better(t, t_near, t_far, best)) {
          best = t;
          break;
        }
      }
      if (!std::isfinite(best)) return false;
      normal = (o + best * d) / object.radius_mm;
      break;
    }
    case ObjectType::kCylinder: {
      const double r = object.radius_mm, hh = object.height_mm / 2;
      const double a = d.x() * d.x() + d.y() * d.y();
      const double b = o.x() * d.x() + o.y() * d.y();
      const double c = o.x() * o.x() + o.y() * o.y() - r * r;
      const double disc = b * b - a * c;
      if (a > 0 && disc >= 0) {
        const double q = -(b + std::copysign(std::sqrt(disc), b));
        const double t1 = q / a, t2 = q != 0 ? c / q : t1;
        for (double t : {t1, t2}) {
          const double z = o.z() + t * d.z();
          if (std::abs(z) <= hh && Better(t, t_near, t_far, best)) {
            best = t;
            const Eigen::Vector3d p = o + t * d;
            normal = Eigen::Vector3d(p.x(), p.y(), 0) / r;
          }
        }
      }
      if (d.z() != 0) {
        for (double zc : {-hh, hh}) {
          const double t = (zc - o.z()) / d.z();
          const Eigen::Vector3d p = o + t * d;
          if (p.x() * p.x() + p.y() * p.y() <= r * r && Better(t, t_near, t_far, best)) {
            best = t;
            normal = Eigen::Vector3d(0, 0, zc > 0 ? 1 : -1);
          }
        }
      }
      if (!std::isfinite(best)) return false;
      break;
    }
    case ObjectType::kBox: {
      const Eigen::Vector3d half = object.size_mm / 2;
      double t_enter = -std::numeric_limits<double>::infinity(),
             t_exit = std::numeric_limits<double>::infinity();
      int axis_enter = 0, axis_exit = 0;
      double sign_enter = 1, sign_exit = 1;
      for (int k = 0; k < 3; ++k) {
        if (d[k] == 0) {
          if (std::abs(o[k]) > half[k]) return false;
          continue;
        }
        double ta = (-half[k] - o[k]) / d[k], tb = (half[k] - o[k]) / d[k];
        double sa = -1, sb = 1;
        if (ta > tb) {
          std::swap(ta, tb);
          std::swap(sa, sb);
        }
        if (ta > t_enter) {
          t_enter = ta;
          axis_enter = k;
          sign_enter = sa;
        }
        if (tb < t_exit) {
          t_exit = tb;
          axis_exit = k;
          sign_exit = sb;
        }
      }
      if (t_enter > t_exit) return false;
      if (Better(t_enter, t_near, t_far, best)) {
        best = t_enter;
        normal = Eigen::Vector3d::Zero();
        normal[axis_enter] = sign_enter;
      } else if (Better(t_exit, t_near, t_far, best)) {
        best = t_exit;
        normal = Eigen::Vector3d::Zero();
        normal[axis_exit] = sign_exit;
      } else {
        return false;
      }
      break;
    }
    default:
      return false;
  }
  hit->t = best;
  hit->normal = normal;
  return true;
}

struct RayCaster::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  std::vector<int32_t> geom_to_object;
  std::vector<std::unique_ptr<PrimitiveData>> primitives;
  // Analytic primitives tested by every ray outside Embree (when there are few: the table plane
  // under a part is hit by nearly every ray, and Embree's user-geometry callbacks cost more than
  // the test itself). Nearest hit / any hit combined with Embree's result.
  std::vector<const PrimitiveData*> direct;
  std::vector<std::vector<float>>
      disc_normals;  // shared with Embree; outlive the scene (released first)
  bool has_embree_geometry = false;
  // Embree's scene bounds, widened by a margin: a ray segment that misses this box cannot hit
  // anything Embree holds, so its lane skips the traversal (a packet of them skips the call).
  bool cull = false;
  double box_lo[3] = {0, 0, 0}, box_hi[3] = {0, 0, 0};
  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

namespace {
void ThrowIfDeviceError(RTCDevice device, const std::string& what) {
  const RTCError e = rtcGetDeviceError(device);
  SLSHADOW_THROW_IF(e != RTC_ERROR_NONE, "Embree: ", what, " failed (error code ",
                    static_cast<int>(e), ")");
}
}  // namespace

RayCaster::RayCaster(const Scene& scene, bool cull_by_bounds)
    : scene_(scene), impl_(std::make_unique<Impl>()) {
  const auto start = std::chrono::steady_clock::now();
  impl_->device = rtcNewDevice(nullptr);
  SLSHADOW_THROW_IF(impl_->device == nullptr, "Embree: cannot create a device (error code ",
                    static_cast<int>(rtcGetDeviceError(nullptr)), ")");
  rtcSetDeviceErrorFunction(impl_->device, ErrorCallback, nullptr);
  impl_->scene = rtcNewScene(impl_->device);
  // Fast (Morton) BVH build: Embree takes it for LOW quality only with the DYNAMIC flag (LOW
  // alone still builds SAH and was no faster). Measured on the 1 M-triangle demo part
  // (docs/benchmarks.md, Simulator): build 0.17 -> 0.07 s on 2 cores, and the geometry pass no
  // slower (the demo part is evenly tessellated; the table is an exact plane outside Embree), so
  // a scan from scratch is 0.52 -> 0.37 s. The scene is still built once and never updated.
  rtcSetSceneFlags(impl_->scene, RTC_SCENE_FLAG_DYNAMIC);
  rtcSetSceneBuildQuality(impl_->scene, RTC_BUILD_QUALITY_LOW);
  const auto is_primitive = [](const SceneObject& o) {
    return o.type != ObjectType::kMesh && o.type != ObjectType::kPointCloud;
  };
  const bool direct_primitives = std::count_if(scene.objects.begin(), scene.objects.end(),
                                               is_primitive) <= kMaxDirectPrimitives;
  for (size_t oi = 0; oi < scene.objects.size(); ++oi) {
    const SceneObject& o = scene.objects[oi];
    RTCGeometry geom = nullptr;
    const Eigen::Matrix3f rot = o.rig_from_object.rotation.toRotationMatrix().cast<float>();
    const Eigen::Matrix3d rotd = o.rig_from_object.rotation.toRotationMatrix();
    if (o.type == ObjectType::kMesh) {
      const TriangleMesh& m = *o.mesh;
      geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                            RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                            m.vertices.size()));
      auto* t = static_cast<uint32_t*>(
          rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                                  3 * sizeof(uint32_t), m.triangles.size()));
      SLSHADOW_THROW_IF(v == nullptr || t == nullptr,
                        "Embree: cannot allocate buffers for object '", o.name, "'");
      // In parallel: part of every scan from scratch (~10 ms serial for 1 M triangles).
      tbb::parallel_for(tbb::blocked_range<size_t>(0, m.vertices.size(), 4096),
                        [&](const tbb::blocked_range<size_t>& r) {
                          for (size_t i = r.begin(); i < r.end(); ++i) {
                            const Eigen::Vector3d p =
                                rotd * m.vertices[i] + o.rig_from_object.translation;
                            v[3 * i] = static_cast<float>(p.x());
                            v[3 * i + 1] = static_cast<float>(p.y());
                            v[3 * i + 2] = static_cast<float>(p.z());
                          }
                        });
      tbb::parallel_for(tbb::blocked_range<size_t>(0, m.triangles.size(), 8192),
                        [&](const tbb::blocked_range<size_t>& r) {
                          for (size_t i = r.begin(); i < r.end(); ++i) {
                            for (int k = 0; k < 3; ++k)
                              t[3 * i + k] = static_cast<uint32_t>(m.triangles[i][k]);
                          }
                        });
      num_triangles_ += static_cast<int64_t>(m.triangles.size());
    } else if (o.type == ObjectType::kPointCloud) {
      const PointCloud& c = *o.points;
      geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT);
      auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), c.size()));
      // Our own, padded normal buffer: Embree 3.13.5 reads 4 bytes past the end of a FLOAT3 normal
      // buffer it allocates itself (valgrind: invalid read in rtcSetNewGeometryBuffer).
      impl_->disc_normals.emplace_back(3 * c.size() + 4, 0.0f);
      float* n = impl_->disc_normals.back().data();
      rtcSetSharedGeometryBuffer(geom, RTC_BUFFER_TYPE_NORMAL, 0, RTC_FORMAT_FLOAT3, n, 0,
                                 3 * sizeof(float), c.size());
      SLSHADOW_THROW_IF(v == nullptr || n == nullptr,
                        "Embree: cannot allocate buffers for object '", o.name, "'");
      for (size_t i = 0; i < c.size(); ++i) {
        const Eigen::Vector3d p = rotd * c.points[i] + o.rig_from_object.translation;
        const Eigen::Vector3f nn = (rot * c.normals[i]).normalized();
        v[4 * i] = static_cast<float>(p.x());
        v[4 * i + 1] = static_cast<float>(p.y());
        v[4 * i + 2] = static_cast<float>(p.z());
        v[4 * i + 3] = o.disc_radii_mm[i];
        n[3 * i] = nn.x();
        n[3 * i + 1] = nn.y();
        n[3 * i + 2] = nn.z();
      }
    } else {
      auto data = std::make_unique<PrimitiveData>();
      data->object = &o;
      data->rig_from_object_rotation = rotd;
      data->object_from_rig_rotation = rotd.transpose();
      data->translation = o.rig_from_object.translation;
      data->object_index = static_cast<int32_t>(oi);
      data->plane_normal = rotd.col(2).cast<float>().normalized();
      if (direct_primitives) {
        impl_->direct.push_back(data.get());
        impl_->primitives.push_back(std::move(data));
        continue;
      }
      geom = rtcNewGeometry(impl_->device, RTC_GEOMETRY_TYPE_USER);
      rtcSetGeometryUserPrimitiveCount(geom, 1);
      rtcSetGeometryUserData(geom, data.get());
      rtcSetGeometryBoundsFunction(geom, PrimitiveBounds, nullptr);
      rtcSetGeometryIntersectFunction(geom, PrimitiveIntersect);
      rtcSetGeometryOccludedFunction(geom, PrimitiveOccluded);
      impl_->primitives.push_back(std::move(data));
    }
    rtcSetGeometryBuildQuality(geom, RTC_BUILD_QUALITY_LOW);
    rtcCommitGeometry(geom);
    impl_->has_embree_geometry = true;
    const unsigned id = rtcAttachGeometry(impl_->scene, geom);
    rtcReleaseGeometry(geom);
    if (impl_->geom_to_object.size() <= id) impl_->geom_to_object.resize(id + 1, -1);
    impl_->geom_to_object[id] = static_cast<int32_t>(oi);
  }
  rtcCommitScene(impl_->scene);
  ThrowIfDeviceError(impl_->device, "building the scene");
  impl_->cull = cull_by_bounds && impl_->has_embree_geometry;
  if (impl_->cull) {
    RTCBounds b;
    rtcGetSceneBounds(impl_->scene, &b);
    const double lo[3] = {b.lower_x, b.lower_y, b.lower_z},
                 hi[3] = {b.upper_x, b.upper_y, b.upper_z};
    // Margin: far above float rounding of hit points and ray parameters at these scales (a
    // float ulp is 6e-5 mm at 1 m).
    double size = 0;
    for (int a = 0; a < 3; ++a) size = std::max({size, std::abs(lo[a]), std::abs(hi[a])});
    const double margin = 1e-3 + 1e-5 * size;
    for (int a = 0; a < 3; ++a) {
      impl_->box_lo[a] = lo[a] - margin;
      impl_->box_hi[a] = hi[a] + margin;
    }
  }
  build_seconds_ = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

RayCaster::~RayCaster() = default;

namespace {
// Deactivates the lanes whose ray segment [tnear, tfar] misses the box; returns the number of
// lanes left active. Slab test in double, without branches, four lanes per vector. A
// direction component of 0 gives infinite slab parameters (a miss when the origin is outside
// that slab). Its one NaN case, an origin exactly on a face of the box with the ray running in
// that face's plane, may go either way: the box is widened beyond all geometry, so such a ray
// cannot hit anything.
SLSHADOW_LANE_CLONES int CullLanesToBox(const double* __restrict lo, const double* __restrict hi,
                                        RayPacket& p) {
  constexpr int kN = RayPacket::kSize;
  alignas(32) double o[3][kN], d[3][kN], tnear[kN], tfar[kN];
  Widen(p.org_x, o[0]);
  Widen(p.org_y, o[1]);
  Widen(p.org_z, o[2]);
  Widen(p.dir_x, d[0]);
  Widen(p.dir_y, d[1]);
  Widen(p.dir_z, d[2]);
  Widen(p.tnear, tnear);
  Widen(p.tfar, tfar);
  V4i left = Splat(0);
  for (int j = 0; j < kN; j += 4) {
    V4d t0 = Load4<V4d>(tnear + j), t1 = Load4<V4d>(tfar + j);
    for (int a = 0; a < 3; ++a) {
      const V4d oa = Load4<V4d>(o[a] + j);
      const V4d inv = 1.0 / Load4<V4d>(d[a] + j);
      const V4d ta = (lo[a] - oa) * inv, tb = (hi[a] - oa) * inv;
      t0 = Max(t0, Min(ta, tb));
      t1 = Min(t1, Max(ta, tb));
    }
    const V4i active = Flags(MaskOf(p.active + j) & ~Narrow(t0 > t1));
    Store4(p.active + j, active);
    left += active;
  }
  return left[0] + left[1] + left[2] + left[3];
}
}  // namespace

bool RayCaster::CullToEmbreeBounds(RayPacket& p) const {
  if (!impl_->cull) return true;
  return CullLanesToBox(impl_->box_lo, impl_->box_hi, p) > 0;
}

void RayCaster::Intersect(RayPacket& p, TraceMode mode, bool coherent) const {
  int32_t active[RayPacket::kSize];
  for (int i = 0; i < RayPacket::kSize; ++i) {
    active[i] = p.active[i];
    p.object[i] = p.active[i] ? -1 : p.object[i];
  }
  if (impl_->has_embree_geometry && CullToEmbreeBounds(p)) IntersectEmbree(p, mode, coherent);
  for (int i = 0; i < RayPacket::kSize; ++i) p.active[i] = active[i];
  // The same for both trace modes: packet and single-ray renders stay identical. Primitive by
  // primitive (lanes are independent, so this is the per-ray order of the Embree route).
  for (const PrimitiveData* d : impl_->direct) {
    if (d->object->type == ObjectType::kPlane) {
      IntersectPlaneLanes(*d, p);
      continue;
    }
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!p.active[i]) continue;
      PrimitiveHit hit;
      if (!IntersectInRig(*d, p.org_x[i], p.org_y[i], p.org_z[i], p.dir_x[i], p.dir_y[i],
                          p.dir_z[i], p.tnear[i], p.tfar[i], &hit)) {
        continue;
      }
      p.tfar[i] = static_cast<float>(hit.t);
      const Eigen::Vector3f n = hit.normal.cast<float>().normalized();
      p.ng_x[i] = n.x();
      p.ng_y[i] = n.y();
      p.ng_z[i] = n.z();
      p.object[i] = d->object_index;
    }
  }
}

void RayCaster::Occluded(RayPacket& p, TraceMode mode) const {
  // Lanes blocked by a primitive need no Embree traversal. Planes (the table under a part: every
  // shadow ray) four lanes per vector (PlaneLanes: the same operations as IntersectInRig).
  int32_t active[RayPacket::kSize];
  for (int i = 0; i < RayPacket::kSize; ++i) {
    active[i] = p.active[i];
    p.occluded[i] = p.active[i] ? 0 : p.occluded[i];
  }
  for (const PrimitiveData* d : impl_->direct) {
    if (d->object->type == ObjectType::kPlane) {
      OccludePlaneLanes(*d, p);
      continue;
    }
    for (int i = 0; i < RayPacket::kSize; ++i) {
      if (!p.active[i]) continue;
      PrimitiveHit hit;
      if (IntersectInRig(*d, p.org_x[i], p.org_y[i], p.org_z[i], p.dir_x[i], p.dir_y[i], p.dir_z[i],
                         p.tnear[i], p.tfar[i], &hit)) {
        p.occluded[i] = 1;
        p.active[i] = 0;
      }
    }
  }
  int32_t any = 0;
  for (int i = 0; i < RayPacket::kSize; ++i) any |= p.active[i];
  if (any && impl_->has_embree_geometry && CullToEmbreeBounds(p)) OccludedEmbree(p, mode);
  for (int i = 0; i < RayPacket::kSize; ++i) p.active[i] = active[i];
}

void RayCaster::IntersectEmbree(RayPacket& p, TraceMode mode, bool coherent) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  if (coherent) context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  if (mode == TraceMode::kPacket16) {
    alignas(64) RTCRayHit16 rh;
    alignas(64) int valid[RayPacket::kSize];
    // Without branches (vectorised): every lane defined, Embree reads all 16 (masked by
    // `valid`); inactive lanes get InactiveLane's empty ray, never the caller's unset inputs.
    for (int i = 0; i < RayPacket::kSize; ++i) {
      const bool a = p.active[i] != 0;
      valid[i] = a ? -1 : 0;
      rh.ray.org_x[i] = a ? p.org_x[i] : 0.0f;
      rh.ray.org_y[i] = a ? p.org_y[i] : 0.0f;
      rh.ray.org_z[i] = a ? p.org_z[i] : 0.0f;
      rh.ray.dir_x[i] = a ? p.dir_x[i] : 0.0f;
      rh.ray.dir_y[i] = a ? p.dir_y[i] : 0.0f;
      rh.ray.dir_z[i] = a ? p.dir_z[i] : 1.0f;
      rh.ray.tnear[i] = a ? p.tnear[i] : 0.0f;
      rh.ray.tfar[i] = a ? p.tfar[i] : -kInf;
      rh.ray.time[i] = 0;
      rh.ray.mask[i] = 0xFFFFFFFFu;
      rh.ray.id[i] = static_cast<unsigned>(i);
      rh.ray.flags[i] = 0;
      rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    }
    rtcIntersect16(valid, impl_->scene, &context, &rh);
    alignas(64) float nx[RayPacket::kSize], ny[RayPacket::kSize], nz[RayPacket::kSize];
    NormalizedLanes(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z, nx, ny, nz);
    const int32_t* geom_to_object = impl_->geom_to_object.data();
    for (int i = 0; i < RayPacket::kSize; ++i) {
      const bool hit = (p.active[i] != 0) & (rh.hit.geomID[i] != RTC_INVALID_GEOMETRY_ID);
      p.tfar[i] = hit ? rh.ray.tfar[i] : p.tfar[i];
      p.ng_x[i] = hit ? nx[i] : p.ng_x[i];
      p.ng_y[i] = hit ? ny[i] : p.ng_y[i];
      p.ng_z[i] = hit ? nz[i] : p.ng_z[i];
      p.object[i] = hit           ? geom_to_object[hit ? rh.hit.geomID[i] : 0]
                    : p.active[i] ? -1
                                  : p.object[i];
    }
    return;
  }
  for (int i = 0; i < RayPacket::kSize; ++i) {
    if (!p.active[i]) continue;
    RTCRayHit rh;
    rh.ray.org_x = p.org_x[i];
    rh.ray.org_y = p.org_y[i];
    rh.ray.org_z = p.org_z[i];
    rh.ray.dir_x = p.dir_x[i];
    rh.ray.dir_y = p.dir_y[i];
    rh.ray.dir_z = p.dir_z[i];
    rh.ray.tnear = p.tnear[i];
    rh.ray.tfar = p.tfar[i];
    rh.ray.time = 0;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.ray.id = 0;
    rh.ray.flags = 0;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    rtcIntersect1(impl_->scene, &context, &rh);
    if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) {
      p.object[i] = -1;
      continue;
    }
    p.tfar[i] = rh.ray.tfar;
    const Eigen::Vector3f n = Eigen::Vector3f(rh.hit.Ng_x, rh.hit.Ng_y, rh.hit.Ng_z).normalized();
    p.ng_x[i] = n.x();
    p.ng_y[i] = n.y();
    p.ng_z[i] = n.z();
    p.object[i] = impl_->geom_to_object[rh.hit.geomID];
  }
}

void RayCaster::OccludedEmbree(RayPacket& p, TraceMode mode) const {
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  // Shadow rays of neighbouring pixels start close together and all end at the projector's centre.
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  if (mode == TraceMode::kPacket16) {
    alignas(64) RTCRay16 r;
    alignas(64) int valid[RayPacket::kSize];
    for (int i = 0; i < RayPacket::kSize; ++i) {  // as in IntersectEmbree
      const bool a = p.active[i] != 0;
      valid[i] = a ? -1 : 0;
      r.org_x[i] = a ? p.org_x[i] : 0.0f;
      r.org_y[i] = a ? p.org_y[i] : 0.0f;
      r.org_z[i] = a ? p.org_z[i] : 0.0f;
      r.dir_x[i] = a ? p.dir_x[i] : 0.0f;
      r.dir_y[i] = a ? p.dir_y[i] : 0.0f;
      r.dir_z[i] = a ? p.dir_z[i] : 1.0f;
      r.tnear[i] = a ? p.tnear[i] : 0.0f;
      r.tfar[i] = a ? p.tfar[i] : -kInf;
      r.time[i] = 0;
      r.mask[i] = 0xFFFFFFFFu;
      r.id[i] = static_cast<unsigned>(i);
      r.flags[i] = 0;
    }
    rtcOccluded16(valid, impl_->scene, &context, &r);
    for (int i = 0; i < RayPacket::kSize; ++i)
      p.occluded[i] = p.active[i] ? r.tfar[i] == -kInf : p.occluded[i];
    return;
  }
  for (int i = 0; i < RayPacket::kSize; ++i) {
    if (!p.active[i]) continue;
    RTCRay r;
    r.org_x = p.org_x[i];
    r.org_y = p.org_y[i];
    r.org_z = p.org_z[i];
    r.dir_x = p.dir_x[i];
    r.dir_y = p.dir_y[i];
    r.dir_z = p.dir_z[i];
    r.tnear = p.tnear[i];
    r.tfar = p.tfar[i];
    r.time = 0;
    r.mask = 0xFFFFFFFFu;
    r.id = 0;
    r.flags = 0;
    rtcOccluded1(impl_->scene, &context, &r);
    p.occluded[i] = r.tfar == -kInf;
  }
}

}  // namespace slshadow
