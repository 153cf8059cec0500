#include "sim/sensor_noise.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

// Eight-lane vectors passed between always-inlined helpers only (no calling convention involved).
#pragma GCC diagnostic ignored "-Wpsabi"

// The avx2 clone maps the eight lanes to one AVX2 register, the default clone to two SSE2 ones:
// the same IEEE operations in the same order either way (no FMA: this file is compiled with
// -ffp-contract=off), hence the same bits on every x86-64 CPU and in the portable build.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SLSHADOW_NOISE_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define SLSHADOW_NOISE_CLONES
#endif
#define SLSHADOW_NOISE_INLINE inline __attribute__((always_inline))

namespace slshadow {
namespace {

typedef float V8f __attribute__((vector_size(32)));
typedef int32_t V8i __attribute__((vector_size(32)));
typedef uint32_t V8u __attribute__((vector_size(32)));

inline uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// The three 32-bit keys of one image's stream: SplitMix64 of (seed, camera, pattern).
struct StreamKeys {
  uint32_t k0, k1, k2;
};

StreamKeys KeysOf(uint64_t seed, int camera_index, int pattern_index) {
  const uint64_t stream =
      SplitMix64(seed ^ SplitMix64((static_cast<uint64_t>(camera_index) << 32) ^
                                   static_cast<uint64_t>(static_cast<uint32_t>(pattern_index))));
  const uint64_t more = SplitMix64(stream);
  return {static_cast<uint32_t>(stream), static_cast<uint32_t>(stream >> 32),
          static_cast<uint32_t>(more)};
}

SLSHADOW_NOISE_INLINE V8f Splat(float v) { return V8f{v, v, v, v, v, v, v, v}; }

SLSHADOW_NOISE_INLINE V8f Sqrt(V8f v) {
  V8f r;
  for (int j = 0; j < 8; ++j)
    r[j] = __builtin_sqrtf(v[j]);  // one sqrtps / vsqrtps (-fno-math-errno)
  return r;
}

// a where mask (all bits set), else b.
SLSHADOW_NOISE_INLINE V8f Select(V8i mask, V8f a, V8f b) {
  return (V8f)(((V8i)a & mask) | ((V8i)b & ~mask));
}

// A 32-bit integer hash with full avalanche (C. Wellons' "lowbias32"): a bijection.
SLSHADOW_NOISE_INLINE V8u Hash(V8u x) {
  x ^= x >> 16;
  x *= 0x7feb352dU;
  x ^= x >> 15;
  x *= 0x846ca68bU;
  x ^= x >> 16;
  return x;
}

// Two independent standard normals per lane for pixel indices `index` (Box-Muller).
SLSHADOW_NOISE_INLINE void Normals(V8u index, const StreamKeys& k, V8f* n1, V8f* n2) {
  const V8u h = Hash(index ^ k.k0);
  const V8u a = Hash(h + k.k1), b = Hash(h ^ k.k2);
  // u1 = (m + 1/2) 2^-23 in (0, 1) from 23 bits (exact in float): the radius sqrt(-2 ln u1).
  const V8f u1 = (__builtin_convertvector((V8i)(a >> 9), V8f) + 0.5f) * 0x1.0p-23f;
  // ln u1, Cephes' logf: u1 = m 2^e with m in [sqrt(1/2), sqrt(2)), ln(m) by a polynomial in m - 1.
  const V8i bits = (V8i)u1;
  V8i e = (bits >> 23) - 126;
  const V8f m = (V8f)((bits & 0x007FFFFF) | 0x3F000000);  // [1/2, 1)
  const V8i small = m < 0.707106781186547524f;
  e += small;  // -1 where m is doubled
  const V8f x = (m + (V8f)((V8i)m & small)) - 1.0f;
  const V8f z = x * x;
  V8f p = Splat(7.0376836292e-2f);
  p = p * x + -1.1514610310e-1f;
  p = p * x + 1.1676998740e-1f;
  p = p * x + -1.2420140846e-1f;
  p = p * x + 1.4249322787e-1f;
  p = p * x + -1.6668057665e-1f;
  p = p * x + 2.0000714765e-1f;
  p = p * x + -2.4999993993e-1f;
  p = p * x + 3.3333331174e-1f;
  const V8f fe = __builtin_convertvector(e, V8f);
  V8f y = p * x * z;
  y = y + fe * -2.12194440e-4f;
  y = y - 0.5f * z;
  const V8f ln = (x + y) + fe * 0.693359375f;
  const V8f rad = Sqrt(-2.0f * ln);
  // The angle 2 pi u2: quadrant q from the top 2 bits of b, then theta in (-pi/4, pi/4) from the
  // next 22 (exact in float); sine and cosine of theta by Cephes' sinf / cosf polynomials.
  const V8u q = b >> 30;
  const V8f t =
      (__builtin_convertvector((V8i)((b >> 8) & 0x3FFFFFu), V8f) + 0.5f) * 0x1.0p-22f - 0.5f;
  const V8f th = t * 1.57079632679489662f;
  const V8f zz = th * th;
  const V8f s =
      ((-1.9515295891e-4f * zz + 8.3321608736e-3f) * zz - 1.6666654611e-1f) * zz * th + th;
  const V8f c =
      ((2.443315711809948e-5f * zz - 1.388731625493765e-3f) * zz + 4.166664568298827e-2f) * zz *
          zz -
      0.5f * zz + 1.0f;
  // Rotate by q quarter turns: (cos, sin) of theta + q pi/2.
  const V8i swap = -(V8i)(q & 1u);
  const V8i cq = (V8i)Select(swap, s, c) ^ (V8i)(((q + 1u) & 2u) << 30);
  const V8i sq = (V8i)Select(swap, c, s) ^ (V8i)((q & 2u) << 30);
  *n1 = rad * (V8f)cq;
  *n2 = rad * (V8f)sq;
}

struct NoiseParams {
  StreamKeys keys;
  float e_per_dn, dn_per_e, read_noise_e, full_well_e, full;
};

// One row: irradiance (DN) -> electrons mu; + sqrt(mu) n1 (shot) + read_noise n2, clipped at
// the full well; back to DN, rounded half up and clipped to [0, full] (NaN and negatives to 0).
template <typename Out>
SLSHADOW_NOISE_INLINE void NoiseRowBody(const float* src, int w, uint32_t first,
                                        const NoiseParams& p, Out* dst) {
  const V8u lane = {0, 1, 2, 3, 4, 5, 6, 7};
  for (int x = 0; x < w; x += 8) {
    const int n = std::min(8, w - x);
    V8f dn = Splat(0);
    if (n == 8) {
      std::memcpy(&dn, src + x, sizeof(dn));
    } else {
      for (int j = 0; j < n; ++j) dn[j] = src[x + j];
    }
    V8f n1, n2;
    Normals(lane + (first + static_cast<uint32_t>(x)), p.keys, &n1, &n2);
    V8f mu = dn * p.e_per_dn;
    mu = (V8f)((V8i)mu & (mu > 0.0f));
    V8f e = mu + Sqrt(mu) * n1 + p.read_noise_e * n2;
    e = Select(e < p.full_well_e, e, Splat(p.full_well_e));
    V8f v = e * p.dn_per_e;
    v = (V8f)((V8i)v & (v > 0.0f));
    v = v + 0.5f;
    v = Select(v < p.full, v, Splat(p.full));
    const V8i qv = __builtin_convertvector(v, V8i);
    for (int j = 0; j < n; ++j) dst[x + j] = static_cast<Out>(qv[j]);
  }
}

SLSHADOW_NOISE_CLONES void NoiseRow8(const float* src, int w, uint32_t first, const NoiseParams& p,
                                     uint8_t* dst) {
  NoiseRowBody(src, w, first, p, dst);
}

SLSHADOW_NOISE_CLONES void NoiseRow16(const float* src, int w, uint32_t first, const NoiseParams& p,
                                      uint16_t* dst) {
  NoiseRowBody(src, w, first, p, dst);
}

SLSHADOW_NOISE_CLONES void NormalsBlock(uint32_t first, int count, const StreamKeys& keys,
                                        float* n1, float* n2) {
  const V8u lane = {0, 1, 2, 3, 4, 5, 6, 7};
  for (int i = 0; i < count; i += 8) {
    V8f a, b;
    Normals(lane + (first + static_cast<uint32_t>(i)), keys, &a, &b);
    for (int j = 0; j < 8 && i + j < count; ++j) n1[i + j] = a[j], n2[i + j] = b[j];
  }
}

// The noise-free ADC: rounds half up and clips a non-negative float to [0, full].
inline int QuantizeValue(float v, float full) {
  if (!(v > 0)) return 0;
  if (v >= full) return static_cast<int>(full);
  return static_cast<int>(v + 0.5f);
}

template <typename Out>
void QuantizeRows(const cv::Mat& irradiance, const Scene& scene, int camera_index,
                  int pattern_index, cv::Mat& out) {
  const SceneLayers& l = scene.layers;
  const int w = irradiance.cols, h = irradiance.rows;
  const double full = std::ldexp(1.0, scene.radiometry.adc_bits) - 1;
  NoiseParams p;
  p.keys = KeysOf(l.seed, camera_index, pattern_index);
  p.e_per_dn = static_cast<float>(l.full_well_e / full);
  p.dn_per_e = static_cast<float>(full / l.full_well_e);
  p.read_noise_e = static_cast<float>(l.read_noise_e);
  p.full_well_e = static_cast<float>(l.full_well_e);
  p.full = static_cast<float>(full);
  const bool noise = l.noise_enabled;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      const float* src = irradiance.ptr<float>(y);
      Out* dst = out.ptr<Out>(y);
      if (!noise) {
        for (int x = 0; x < w; ++x) dst[x] = static_cast<Out>(QuantizeValue(src[x], p.full));
        continue;
      }
      const uint32_t first = static_cast<uint32_t>(y) * static_cast<uint32_t>(w);
      if constexpr (sizeof(Out) == 1) {
        NoiseRow8(src, w, first, p, dst);
      } else {
        NoiseRow16(src, w, first, p, dst);
      }
    }
  });
}

}  // namespace

void QuantizeIrradiance(const cv::Mat& irradiance, const Scene& scene, int camera_index,
                        int pattern_index, cv::Mat* out) {
  SLSHADOW_THROW_IF(irradiance.type() != CV_32FC1,
                    "QuantizeIrradiance: irradiance must be CV_32FC1 (got type ", irradiance.type(),
                    ")");
  SLSHADOW_THROW_IF(irradiance.total() > 0xFFFFFFFFull, "QuantizeIrradiance: image of ",
                    irradiance.total(), " pixels: the noise layer indexes pixels with 32 bits");
  const bool wide = scene.radiometry.adc_bits > 8;
  out->create(irradiance.rows, irradiance.cols, wide ? CV_16UC1 : CV_8UC1);
  if (wide) {
    QuantizeRows<uint16_t>(irradiance, scene, camera_index, pattern_index, *out);
  } else {
    QuantizeRows<uint8_t>(irradiance, scene, camera_index, pattern_index, *out);
  }
}

void SensorNoiseNormals(uint64_t seed, int camera_index, int pattern_index, uint32_t first,
                        int count, float* n1, float* n2) {
  NormalsBlock(first, count, KeysOf(seed, camera_index, pattern_index), n1, n2);
}

}  // namespace slshadow
