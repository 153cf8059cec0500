#include "sim/sensor_noise.h"

#include <algorithm>
#include <cmath>
#include <cstring>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"

// Eight-lane vectors passed between always-inlined helpers only (no calling convention involved).
#pragma GCC diagnostic ignored "-Wpsabi"

// Eight pixels per vector: the x86-64-v4 clone maps them to AVX-512 registers (64-bit multiplies
// in one instruction), the avx2 clone to pairs of AVX2 ones, the default clone to SSE2 ones:
// the same IEEE operations in the same order either way (no FMA: this file is compiled with
// -ffp-contract=off), hence the same bits on every x86-64 CPU and in the portable build.
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
typedef double V8d __attribute__((vector_size(64)));
typedef int64_t V8l __attribute__((vector_size(64)));
typedef uint64_t V8u __attribute__((vector_size(64)));

SLSHADOW_NOISE_INLINE V8u Mix(V8u x) {  // SplitMix64, lane by lane
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

SLSHADOW_NOISE_INLINE V8f SplatF(float v) { return V8f{v, v, v, v, v, v, v, v}; }
SLSHADOW_NOISE_INLINE V8d SplatD(double v) { return V8d{v, v, v, v, v, v, v, v}; }

SLSHADOW_NOISE_INLINE V8f Sqrt(V8f v) {
  V8f r;
  for (int j = 0; j < 8; ++j) r[j] = __builtin_sqrtf(v[j]);  // one sqrtps (-fno-math-errno)
  return r;
}

SLSHADOW_NOISE_INLINE V8d Sqrt(V8d v) {
  V8d r;
  for (int j = 0; j < 8; ++j) r[j] = __builtin_sqrt(v[j]);  // vsqrtpd / two sqrtpd
  return r;
}

// a where mask (all bits set), else b.
SLSHADOW_NOISE_INLINE V8f Select(V8i mask, V8f a, V8f b) {
  return (V8f)(((V8i)a & mask) | ((V8i)b & ~mask));
}
SLSHADOW_NOISE_INLINE V8d Select(V8l mask, V8d a, V8d b) {
  return (V8d)(((V8l)a & mask) | ((V8l)b & ~mask));
}

// ln x for x in (0, 1], Cephes' logf: x = m 2^e with m in [sqrt(1/2), sqrt(2)), ln(m) by a
// polynomial in m - 1.
SLSHADOW_NOISE_INLINE V8f Log(V8f v) {
  const V8i bits = (V8i)v;
  V8i e = (bits >> 23) - 126;
  const V8f m = (V8f)((bits & 0x007FFFFF) | 0x3F000000);  // [1/2, 1)
  const V8i small = m < 0.707106781186547524f;
  e += small;  // -1 where m is doubled
  const V8f x = (m + (V8f)((V8i)m & small)) - 1.0f;
  const V8f z = x * x;
  V8f p = SplatF(7.0376836292e-2f);
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
  return (x + y) + fe * 0.693359375f;
}

// Cosine and sine of a in [0, 2 pi]: quarter turns j = round(a / (pi/2)) taken off in three
// parts (Cody-Waite: exact products), Cephes' sinf / cosf polynomials on r in [-pi/4, pi/4],
// then rotated by j quarter turns.
SLSHADOW_NOISE_INLINE void CosSin(V8f a, V8f* cos_a, V8f* sin_a) {
  const V8i j = __builtin_convertvector(a * 0.636619772367581343f + 0.5f, V8i);
  const V8f fj = __builtin_convertvector(j, V8f);
  const V8f r =
      ((a - fj * 1.5703125f) - fj * 4.837512969970703125e-4f) - fj * 7.54978995489188216e-8f;
  const V8f z = r * r;
  const V8f s = ((-1.9515295891e-4f * z + 8.3321608736e-3f) * z - 1.6666654611e-1f) * z * r + r;
  const V8f c =
      ((2.443315711809948e-5f * z - 1.388731625493765e-3f) * z + 4.166664568298827e-2f) * z * z -
      0.5f * z + 1.0f;
  const V8i q = j & 3;
  const V8i swap = -(q & 1);
  *cos_a = (V8f)((V8i)Select(swap, s, c) ^ (((q + 1) & 2) << 30));
  *sin_a = (V8f)((V8i)Select(swap, c, s) ^ ((q & 2) << 30));
}

// Two independent standard normals per lane for pixel indices `index` of the image `stream`
// (Box-Muller on two 24-bit uniforms of SplitMix64(stream + index) and SplitMix64 of that).
SLSHADOW_NOISE_INLINE void Normals(V8u index, uint64_t stream, V8f* n1, V8f* n2) {
  const V8u r1 = Mix(index + stream);
  const V8u r2 = Mix(r1);
  const V8f u1 =
      (__builtin_convertvector(__builtin_convertvector(r1 >> 40, V8i), V8f) + 0.5f) * 0x1.0p-24f;
  const V8f u2 = __builtin_convertvector(__builtin_convertvector(r2 >> 40, V8i), V8f) * 0x1.0p-24f;
  const V8f rad = Sqrt(-2.0f * Log(u1));
  V8f c, s;
  CosSin(6.2831853f * u2, &c, &s);
  *n1 = rad * c;
  *n2 = rad * s;
}

struct NoiseParams {
  uint64_t stream;
  double k_dn_per_e, read_noise_e, full_well_e, full;
};

// One row: irradiance (DN) -> electrons mu (>= 0); + sqrt(mu) n1 (shot) + read_noise n2, clipped
// at the full well; back to DN, rounded (half away from zero) and clipped to [0, full].
template <typename Out>
SLSHADOW_NOISE_INLINE void NoiseRowBody(const float* src, int w, uint64_t first,
                                        const NoiseParams& params, Out* dst) {
  // Locals: the output row may alias anything (unsigned char), which would reload them per block.
  const NoiseParams p = params;
  const V8u lane = {0, 1, 2, 3, 4, 5, 6, 7};
  for (int x = 0; x < w; x += 8) {
    const int n = std::min(8, w - x);
    V8f dn = SplatF(0);
    if (n == 8) {
      std::memcpy(&dn, src + x, sizeof(dn));
    } else {
      for (int j = 0; j < n; ++j) dn[j] = src[x + j];
    }
    V8f n1, n2;
    Normals(lane + (first + static_cast<uint64_t>(x)), p.stream, &n1, &n2);
    V8d mu = __builtin_convertvector(dn, V8d) / p.k_dn_per_e;
    mu = Select(mu > 0.0, mu, SplatD(0));  // NaN and negatives: no signal
    V8d e = mu + Sqrt(mu) * __builtin_convertvector(n1, V8d) +
            p.read_noise_e * __builtin_convertvector(n2, V8d);
    e = Select(e < p.full_well_e, e, SplatD(p.full_well_e));
    V8d v = e * p.k_dn_per_e;
    v = Select(v > 0.0, v, SplatD(0));
    v = v + 0.5;
    v = Select(v < p.full, v, SplatD(p.full));
    const V8i q = __builtin_convertvector(v, V8i);  // <= 65535
    Out out[8];
    for (int j = 0; j < 8; ++j) out[j] = static_cast<Out>(q[j]);
    std::memcpy(dst + x, out, sizeof(Out) * static_cast<size_t>(n));
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

SLSHADOW_NOISE_CLONES void NormalsBlock(uint64_t first, int count, uint64_t stream, float* n1,
                                        float* n2) {
  const V8u lane = {0, 1, 2, 3, 4, 5, 6, 7};
  for (int i = 0; i < count; i += 8) {
    V8f a, b;
    Normals(lane + (first + static_cast<uint64_t>(i)), stream, &a, &b);
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
  p.stream = StreamOf(l.seed, camera_index, pattern_index);
  p.k_dn_per_e = full / l.full_well_e;
  p.read_noise_e = l.read_noise_e;
  p.full_well_e = l.full_well_e;
  p.full = full;
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
                        int count, float* n1, float* n2) {
  NormalsBlock(first, count, StreamOf(seed, camera_index, pattern_index), n1, n2);
}

}  // namespace slshadow
