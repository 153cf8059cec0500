#include "sim/sensor_noise.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

// Eight-lane vectors passed between always-inlined helpers only (no calling convention involved).
#pragma GCC diagnostic ignored "-Wpsabi"

// Eight lanes per vector: the x86-64-v4 clone maps them to AVX-512 registers (64-bit multiplies
// in one instruction), the avx2 clone to AVX2 ones, the default clone to SSE2 ones: the same IEEE
// operations in the same order either way (no FMA: this file is compiled with -ffp-contract=off),
// hence the same bits on every x86-64 CPU and in the portable build.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define SLSHADOW_NOISE_CLONES __attribute__((target_clones("arch=x86-64-v4", "avx2", "default")))
#else
#define SLSHADOW_NOISE_CLONES
#endif
#define SLSHADOW_NOISE_INLINE inline __attribute__((always_inline))

namespace slshadow {
namespace {

typedef float V8f __attribute__((vector_size(32)));
typedef int32_t V8i __attribute__((vector_size(32)));
typedef uint64_t V8u __attribute__((vector_size(64)));
typedef float V16f __attribute__((vector_size(64)));
typedef int32_t V16i __attribute__((vector_size(64)));
typedef uint64_t V16u __attribute__((vector_size(128)));
typedef uint8_t V16b __attribute__((vector_size(16)));
typedef uint16_t V16s __attribute__((vector_size(32)));

template <typename VU>
SLSHADOW_NOISE_INLINE VU Mix(VU x) {  // SplitMix64, lane by lane
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

inline uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

uint64_t StreamOf(uint64_t seed, int camera_index, int pattern_index) {
  return SplitMix64(seed ^ SplitMix64((static_cast<uint64_t>(camera_index) << 32) ^
                                      static_cast<uint64_t>(static_cast<uint32_t>(pattern_index))));
}

SLSHADOW_NOISE_INLINE V16f Splat16(float v) { return V16f{} + v; }

SLSHADOW_NOISE_INLINE V8f Sqrt(V8f v) {
  V8f r;
  for (int j = 0; j < 8; ++j) r[j] = __builtin_sqrtf(v[j]);  // one sqrtps (-fno-math-errno)
  return r;
}

SLSHADOW_NOISE_INLINE V16f Sqrt(V16f v) {
  V16f r;
  for (int j = 0; j < 16; ++j) r[j] = __builtin_sqrtf(v[j]);
  return r;
}

// a where mask (all bits set), else b.
SLSHADOW_NOISE_INLINE V8f Select(V8i mask, V8f a, V8f b) {
  return (V8f)(((V8i)a & mask) | ((V8i)b & ~mask));
}
SLSHADOW_NOISE_INLINE V16f Select(V16i mask, V16f a, V16f b) {
  return (V16f)(((V16i)a & mask) | ((V16i)b & ~mask));
}

// ln x for x in (0, 1], Cephes' logf: x = m 2^e with m in [sqrt(1/2), sqrt(2)), ln(m) by a
// polynomial in m - 1.
template <typename VF, typename VI>
SLSHADOW_NOISE_INLINE VF Log(VF v) {
  const VI bits = (VI)v;
  VI e = (bits >> 23) - 126;
  const VF m = (VF)((bits & 0x007FFFFF) | 0x3F000000);  // [1/2, 1)
  const VI small = m < 0.707106781186547524f;
  e += small;  // -1 where m is doubled
  const VF x = (m + (VF)((VI)m & small)) - 1.0f;
  const VF z = x * x;
  VF p = VF{} + 7.0376836292e-2f;
  p = p * x + -1.1514610310e-1f;
  p = p * x + 1.1676998740e-1f;
  p = p * x + -1.2420140846e-1f;
  p = p * x + 1.4249322787e-1f;
  p = p * x + -1.6668057665e-1f;
  p = p * x + 2.0000714765e-1f;
  p = p * x + -2.4999993993e-1f;
  p = p * x + 3.3333331174e-1f;
  const VF fe = __builtin_convertvector(e, VF);
  VF y = p * x * z;
  y = y + fe * -2.12194440e-4f;
  y = y - 0.5f * z;
  return (x + y) + fe * 0.693359375f;
}

// Cosine and sine of a in [0, 2 pi]: quarter turns j = round(a / (pi/2)) taken off in three
// parts (Cody-Waite: exact products), Cephes' sinf / cosf polynomials on r in [-pi/4, pi/4],
// then rotated by j quarter turns.
template <typename VF, typename VI>
SLSHADOW_NOISE_INLINE void CosSin(VF a, VF* cos_a, VF* sin_a) {
  const VI j = __builtin_convertvector(a * 0.636619772367581343f + 0.5f, VI);
  const VF fj = __builtin_convertvector(j, VF);
  const VF r =
      ((a - fj * 1.5703125f) - fj * 4.837512969970703125e-4f) - fj * 7.54978995489188216e-8f;
  const VF z = r * r;
  const VF s = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * r + r;
  const VF c =
      ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z -
      0.5f * z + 1.0f;
  const VI q = j & 3;
  const VI swap = -(q & 1);
  *cos_a = (VF)((VI)Select(swap, s, c) ^ (((q + 1) & 2) << 30));
  *sin_a = (VF)((VI)Select(swap, c, s) ^ ((q & 2) << 30));
}

// The standard normals of the 16 pixels of block `block` (pixel indices 16 block .. 16 block +
// 15) of the image `stream`: one SplitMix64 of (stream + 8 block + lane) per lane gives two 24-bit
// uniforms (bits 40-63 and 16-39), Box-Muller two independent normals: the cosine one for pixel
// 16 block + lane, the sine one for pixel 16 block + 8 + lane.
SLSHADOW_NOISE_INLINE V16f BlockNormals(uint64_t block, uint64_t stream) {
  const V8u lane = {0, 1, 2, 3, 4, 5, 6, 7};
  const V8u r = Mix(lane + (stream + 8 * block));
  const V8f u1 =
      (__builtin_convertvector(__builtin_convertvector(r >> 40, V8i), V8f) + 0.5f) * 0x1.0p-24f;
  const V8f u2 = __builtin_convertvector(__builtin_convertvector((r >> 16) & 0xFFFFFFu, V8i), V8f) *
                 0x1.0p-24f;
  const V8f rad = Sqrt(-2.0f * Log<V8f, V8i>(u1));
  V8f c, s;
  CosSin<V8f, V8i>(6.2831853f * u2, &c, &s);
  return __builtin_shufflevector(rad * c, rad * s, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14,
                                 15);
}

// BlockNormals(block, stream) into *n0 and BlockNormals(block + 1, stream) into *n1, the same
// values, with the lanes of both blocks in one sixteen-lane vector: lane l of block + 1 is lane
// 8 + l of (stream + 8 block + 0..15). Half the instructions where vectors hold sixteen floats.
SLSHADOW_NOISE_INLINE void BlockPairNormals(uint64_t block, uint64_t stream, V16f* n0, V16f* n1) {
  const V16u lane = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};
  const V16u r = Mix(lane + (stream + 8 * block));
  const V16f u1 =
      (__builtin_convertvector(__builtin_convertvector(r >> 40, V16i), V16f) + 0.5f) * 0x1.0p-24f;
  const V16f u2 =
      __builtin_convertvector(__builtin_convertvector((r >> 16) & 0xFFFFFFu, V16i), V16f) *
      0x1.0p-24f;
  const V16f rad = Sqrt(-2.0f * Log<V16f, V16i>(u1));
  V16f c, s;
  CosSin<V16f, V16i>(6.2831853f * u2, &c, &s);
  const V16f rc = rad * c, rs = rad * s;
  *n0 = __builtin_shufflevector(rc, rs, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
  *n1 =
      __builtin_shufflevector(rc, rs, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
}

struct NoiseParams {
  uint64_t stream;
  float dn_per_e, e_per_dn, read_var_e2, full_well_e, full;
};

// Sixteen pixels: irradiance (DN) -> electrons mu (>= 0); + sqrt(mu + read^2) n (shot and read
// noise, independent Gaussians, in one), clipped at the full well; back to DN, rounded half up
// and clipped to [0, full].
SLSHADOW_NOISE_INLINE V16i NoisyDn(V16f dn, V16f n, const NoiseParams& p) {
  V16f mu = dn * p.e_per_dn;
  mu = Select(mu > 0.0f, mu, Splat16(0));  // NaN and negatives: no signal
  V16f e = mu + Sqrt(mu + p.read_var_e2) * n;
  e = Select(e < p.full_well_e, e, Splat16(p.full_well_e));
  V16f v = e * p.dn_per_e;
  v = Select(v > 0.0f, v, Splat16(0));
  v = v + 0.5f;
  v = Select(v < p.full, v, Splat16(p.full));
  return __builtin_convertvector(v, V16i);  // <= 65535
}

template <typename Out>
struct OutVector;
template <>
struct OutVector<uint8_t> {
  using type = V16b;
};
template <>
struct OutVector<uint16_t> {
  using type = V16s;
};

// One row of `w` pixels whose first pixel has index `first`: whole blocks of 16 straight from
// the row, the partial blocks at its ends through a copy.
template <typename Out>
SLSHADOW_NOISE_INLINE void NoiseRowBody(const float* src, int w, uint64_t first,
                                        const NoiseParams& params, Out* dst) {
  using OutV = typename OutVector<Out>::type;
  // Locals: the output row may alias anything (unsigned char), which would reload them per block.
  const NoiseParams p = params;
  const uint64_t end = first + static_cast<uint64_t>(w);
  const uint64_t end_block = (end + 15) / 16;
  for (uint64_t block = first / 16; block < end_block;) {
    const uint64_t b0 = block * 16;
    if (b0 >= first && b0 + 32 <= end) {  // two whole blocks
      V16f dn0, dn1, n0, n1;
      std::memcpy(&dn0, src + (b0 - first), sizeof(dn0));
      std::memcpy(&dn1, src + (b0 + 16 - first), sizeof(dn1));
      BlockPairNormals(block, p.stream, &n0, &n1);
      const OutV out0 = __builtin_convertvector(NoisyDn(dn0, n0, p), OutV);
      const OutV out1 = __builtin_convertvector(NoisyDn(dn1, n1, p), OutV);
      std::memcpy(dst + (b0 - first), &out0, sizeof(out0));
      std::memcpy(dst + (b0 + 16 - first), &out1, sizeof(out1));
      block += 2;
      continue;
    }
    const uint64_t lo = std::max(b0, first), hi = std::min(b0 + 16, end);
    const bool whole = lo == b0 && hi == b0 + 16;
    V16f dn;
    if (whole) {
      std::memcpy(&dn, src + (b0 - first), sizeof(dn));
    } else {
      dn = Splat16(0);
      for (uint64_t i = lo; i < hi; ++i) dn[i - b0] = src[i - first];
    }
    const OutV out = __builtin_convertvector(NoisyDn(dn, BlockNormals(block, p.stream), p), OutV);
    if (whole) {
      std::memcpy(dst + (b0 - first), &out, sizeof(out));
    } else {
      for (uint64_t i = lo; i < hi; ++i) dst[i - first] = out[i - b0];
    }
    ++block;
  }
}

SLSHADOW_NOISE_CLONES void NoiseRow8(const float* src, int w, uint64_t first, const NoiseParams& p,
                                     uint8_t* dst) {
  NoiseRowBody(src, w, first, p, dst);
}

SLSHADOW_NOISE_CLONES void NoiseRow16(const float* src, int w, uint64_t first, const NoiseParams& p,
                                      uint16_t* dst) {
  NoiseRowBody(src, w, first, p, dst);
}

SLSHADOW_NOISE_CLONES void NormalsBlock(uint64_t first, int count, uint64_t stream, float* n) {
  const uint64_t end = first + static_cast<uint64_t>(count);
  for (uint64_t block = first / 16; block * 16 < end; ++block) {
    const V16f v = BlockNormals(block, stream);
    for (int j = 0; j < 16; ++j) {
      const uint64_t i = block * 16 + static_cast<uint64_t>(j);
      if (i >= first && i < end) n[i - first] = v[j];
    }
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
  p.stream = StreamOf(l.seed, camera_index, pattern_index);
  p.dn_per_e = static_cast<float>(full / l.full_well_e);
  p.e_per_dn = static_cast<float>(l.full_well_e / full);
  p.read_var_e2 = static_cast<float>(l.read_noise_e * l.read_noise_e);
  p.full_well_e = static_cast<float>(l.full_well_e);
  p.full = static_cast<float>(full);
  const float full_f = static_cast<float>(full);
  const bool noise = l.noise_enabled;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 8), [&](const tbb::blocked_range<int>& r) {
    for (int y = r.begin(); y < r.end(); ++y) {
      const float* src = irradiance.ptr<float>(y);
      Out* dst = out.ptr<Out>(y);
      if (!noise) {
        for (int x = 0; x < w; ++x) dst[x] = static_cast<Out>(QuantizeValue(src[x], full_f));
        continue;
      }
      const uint64_t first = static_cast<uint64_t>(y) * static_cast<uint64_t>(w);
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

void SensorNoiseNormals(uint64_t seed, int camera_index, int pattern_index, uint64_t first,
                        int count, float* n) {
  NormalsBlock(first, count, StreamOf(seed, camera_index, pattern_index), n);
}

}  // namespace slshadow
