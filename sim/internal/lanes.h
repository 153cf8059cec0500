// Internal to sim/: four ray lanes per vector (GCC vector extensions), shared by the geometry
// pass (sim/geometry_pass.cc) and the ray caster (sim/raycaster.cc). The avx2 clones of the
// functions marked SLSHADOW_LANE_CLONES map these vectors to AVX2 registers, the default clones
// to pairs of SSE2 operations: the same IEEE operations either way and no FMA, so every clone
// gives the same bits as the scalar per-lane code they replace (GCC kept those per-lane loops
// over 16 lanes scalar: mixed bool / int / float / double lanes). Comparisons give lane masks
// (all bits set = true).
#pragma once

#include <cstdint>
#include <cstring>

// The helpers pass these vectors by value; they are internal and inlined, so GCC's note on the
// calling convention of 32-byte vectors without AVX (-Wpsabi) does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"

#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SLSHADOW_LANE_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define SLSHADOW_LANE_CLONES
#endif

namespace slshadow {
namespace lanes {

typedef float V4f __attribute__((vector_size(16)));
typedef int32_t V4i __attribute__((vector_size(16)));
typedef double V4d __attribute__((vector_size(32)));
typedef int64_t V4l __attribute__((vector_size(32)));

template <class V, class T>
inline V Load4(const T* p) {
  V v;
  std::memcpy(&v, p, sizeof(v));
  return v;
}
template <class V, class T>
inline void Store4(T* p, const V& v) {
  std::memcpy(p, &v, sizeof(v));
}
// RayPacket lane flags (0 / 1) <-> lane masks.
inline V4i MaskOf(const int32_t* flags) { return Load4<V4i>(flags) != 0; }
inline V4i Flags(const V4i& mask) { return mask & 1; }
inline V4d Splat(double v) { return V4d{v, v, v, v}; }
inline V4f Splat(float v) { return V4f{v, v, v, v}; }
inline V4i Splat(int32_t v) { return V4i{v, v, v, v}; }

}  // namespace lanes
}  // namespace slshadow
