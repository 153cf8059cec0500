// Ray casting against a Scene with Embree 3 (kept out of this header): triangle meshes, point
// clouds as oriented discs (RTC_GEOMETRY_TYPE_ORIENTED_DISC_POINT) and analytic primitives
// (plane, sphere, cylinder, box) intersected exactly in double precision: up to 8 of them tested
// by every ray outside Embree, more as Embree user geometry (with their bounds).
//
// Rays are in the rig frame, mm. Queries come in packets of up to 16 rays (structure of arrays,
// floats as Embree stores them) and are traced either as one rtcIntersect16 / rtcOccluded16
// packet (fast path) or ray by ray with rtcIntersect1 / rtcOccluded1 (the brute-force reference
// the tests compare against). Both give the same hits: the same BVH and the same intersectors.
#pragma once

#include <cstdint>
#include <memory>

#include "core/enum_names.h"
#include "sim/scene.h"

namespace slshadow {

enum class TraceMode { kPacket16, kSingleRay };
std::string ToString(TraceMode mode);                    // "packet16", "single_ray"
TraceMode TraceModeFromString(const std::string& name);  // throws slshadow::Error
// The names (core/enum_names.h), for the simulate options' reader.
inline constexpr EnumName<TraceMode> kTraceModeNames[] = {{TraceMode::kPacket16, "packet16"},
                                                          {TraceMode::kSingleRay, "single_ray"}};

struct alignas(64) RayPacket {
  static constexpr int kSize = 16;
  // Inputs. Lanes with active[i] == 0 are ignored and left untouched. Lane flags are 32-bit
  // ints (0 or 1), as wide as the float lanes, so that lane masks vectorise with them.
  float org_x[kSize], org_y[kSize], org_z[kSize];
  float dir_x[kSize], dir_y[kSize], dir_z[kSize];
  float tnear[kSize], tfar[kSize];
  int32_t active[kSize];
  // Outputs of Intersect: tfar is the hit distance (in units of |dir|), ng the unit geometric
  // normal in the rig frame (orientation as the shape defines it, not flipped to the ray),
  // object the index into Scene::objects or -1 for a miss. Outputs of Occluded: occluded.
  float ng_x[kSize], ng_y[kSize], ng_z[kSize];
  int32_t object[kSize];
  int32_t occluded[kSize];  // 1 or 0
};

class RayCaster {
 public:
  // Builds the acceleration structure. Throws slshadow::Error when Embree fails (e.g. out of
  // memory). The scene must outlive the ray caster. `cull_by_bounds`: rays whose segment misses
  // the bounds of everything Embree holds skip its traversal (exact; off only to test that).
  explicit RayCaster(const Scene& scene, bool cull_by_bounds = true);
  ~RayCaster();
  RayCaster(const RayCaster&) = delete;
  RayCaster& operator=(const RayCaster&) = delete;

  // Closest hits of the active lanes. Thread-safe.
  void Intersect(RayPacket& packet, TraceMode mode, bool coherent) const;
  // Any hit within (tnear, tfar) of the active lanes. Thread-safe.
  void Occluded(RayPacket& packet, TraceMode mode) const;

  const Scene& scene() const { return scene_; }
  double build_seconds() const { return build_seconds_; }
  int64_t num_triangles() const { return num_triangles_; }

 private:
  struct Impl;
  void IntersectEmbree(RayPacket& packet, TraceMode mode, bool coherent) const;
  void OccludedEmbree(RayPacket& packet, TraceMode mode) const;
  // Deactivates the lanes whose segment misses Embree's scene bounds; false when none is left.
  bool CullToEmbreeBounds(RayPacket& packet) const;
  const Scene& scene_;
  std::unique_ptr<Impl> impl_;
  double build_seconds_ = 0;
  int64_t num_triangles_ = 0;
};

// Exact intersection of a ray with an analytic primitive (kPlane, kSphere, kCylinder, kBox)
// given in the object's frame: the smallest t in (t_near, t_far) with its unit normal (object
// frame, pointing out of the solid; +z for the plane). Exposed for tests.
struct PrimitiveHit {
  double t = 0;
  Eigen::Vector3d normal = Eigen::Vector3d::Zero();
};
bool IntersectPrimitive(const SceneObject& object, const Eigen::Vector3d& origin_in_object,
                        const Eigen::Vector3d& dir_in_object, double t_near, double t_far,
                        PrimitiveHit* hit);

}  // namespace slshadow
