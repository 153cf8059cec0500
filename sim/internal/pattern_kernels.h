// Internal to sim/ (sim/internal/: not part of the public API): the fused pattern-pass kernels
// of PatternRenderer (sim/renderer.h): the ADC rounding, bilinear taps into an interleaved batch
// of projector images, the AVX2 row kernel (8 images per vector, chosen at run time) and its
// portable twin, which sample identically. Included by sim/renderer.cc only: its definitions
// have internal linkage there, as before they had their own file.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <opencv2/core.hpp>

#include "sim/geometry_pass.h"

namespace slshadow {
namespace {  // NOLINT: one includer (sim/renderer.cc)

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

inline BilinearTap TapAt(const uint8_t* inter, int pw, int ph, float u, float t, int B) {
  const float fx0 = std::floor(u), fy0 = std::floor(t);
  const float ax = u - fx0, ay = t - fy0;
  const int x0 = std::clamp(static_cast<int>(fx0), 0, pw - 1),
            x1 = std::clamp(static_cast<int>(fx0) + 1, 0, pw - 1);
  const int y0 = std::clamp(static_cast<int>(fy0), 0, ph - 1),
            y1 = std::clamp(static_cast<int>(fy0) + 1, 0, ph - 1);
  return {inter + (static_cast<size_t>(y0) * pw + x0) * B,
          inter + (static_cast<size_t>(y0) * pw + x1) * B,
          inter + (static_cast<size_t>(y1) * pw + x0) * B,
          inter + (static_cast<size_t>(y1) * pw + x1) * B,
          (1 - ax) * (1 - ay),
          ax * (1 - ay),
          (1 - ax) * ay,
          ax * ay};
}

// The common case in one fused sweep: linear response, bilinear lookup, no fill factor, one
// sample per pixel, no camera defocus, no noise: lookups, radiometry and quantisation of B
// interleaved projector images, written straight to the output images (no float copies).
#if defined(__x86_64__) && defined(__GNUC__)
#define SLSHADOW_SIM_AVX2 1
// 16 pixels x 16 images of 8-bit values (pixel i's bytes at tile + i * stride) stored as 16
// bytes into each of the first `images` image rows at column x0: a 16 x 16 byte transpose.
__attribute__((target("avx2"))) inline void StoreTransposed16(const uint8_t* tile, size_t stride,
                                                              uint8_t* const* rows, int x0,
                                                              int images) {
  __m128i a[16];
  for (int i = 0; i < 16; ++i)
    a[i] = _mm_load_si128(reinterpret_cast<const __m128i*>(tile + i * stride));
  Transpose16x16(a);
  for (int k = 0; k < images; ++k) _mm_storeu_si128(reinterpret_cast<__m128i*>(rows[k] + x0), a[k]);
}

// The same for 16 pixels x up to 32 images (tile[pixel][image]): both 16 x 16 transposes at once,
// one per 128-bit half (the AVX2 byte unpacks work per half).
__attribute__((target("avx2"))) inline void StoreTransposed32(const uint8_t (*tile)[32],
                                                              uint8_t* const* rows, int x0,
                                                              int images) {
  __m256i a[16], b[16];
  for (int i = 0; i < 16; ++i) a[i] = _mm256_load_si256(reinterpret_cast<const __m256i*>(tile[i]));
  for (int round = 0; round < 4; ++round) {
    for (int i = 0; i < 8; ++i) {
      b[2 * i] = _mm256_unpacklo_epi8(a[i], a[i + 8]);
      b[2 * i + 1] = _mm256_unpackhi_epi8(a[i], a[i + 8]);
    }
    for (int i = 0; i < 16; ++i) a[i] = b[i];
  }
  for (int k = 0; k < 16; ++k)
    _mm_storeu_si128(reinterpret_cast<__m128i*>(rows[k] + x0), _mm256_castsi256_si128(a[k]));
  for (int k = 16; k < images; ++k) {
    _mm_storeu_si128(reinterpret_cast<__m128i*>(rows[k] + x0),
                     _mm256_extracti128_si256(a[k - 16], 1));
  }
}

// One row of FusedDirectBilinear with AVX2: the B <= 32 images of the batch are the lanes of
// kV = (B + 7) / 8 vectors of 8 floats (templated on kV; B is a run-time argument). The
// interleaved pattern bytes of one projector pixel are read 8 at a time (the interleaved buffer
// is padded; lanes >= B are computed and not stored). Same operations in the same order as the
// scalar code (mul and add kept separate: target "avx2" without "fma", so nothing gets
// contracted), hence bit-identical images. Quantisation as QuantizeValue: max(v, 0) maps NaN and
// negatives to 0; min(v + 0.5, full) then truncation.
template <int kV, typename Out>
__attribute__((target("avx2"))) void FusedRowAvx2(const GeometryBuffer& g, size_t row_start, int w,
                                                  const uint8_t* inter, int pw, int ph,
                                                  float ambient, float scale, const float* vig,
                                                  float full, int B, Out* const* rows) {
  static_assert(kV >= 1 && kV <= 4);
  const __m256 zero = _mm256_setzero_ps(), half = _mm256_set1_ps(0.5f),
               vfull = _mm256_set1_ps(full);
  constexpr bool kTiled = std::is_same_v<Out, uint8_t>;
  // 8-bit output: each pixel's B values packed to the bytes of one tile row (image order), the
  // images written 16 pixels at a time through byte transposes (not B single-byte stores).
  alignas(32) uint8_t tile[16][32];
  alignas(32) int32_t q[32];
  const __m256i order = _mm256_setr_epi32(0, 4, 1, 5, 2, 6, 3, 7);
  // Bilinear footprints (TapAt) of 8 pixels at a time: byte offsets of the four neighbours in
  // `inter` and their weights, the same float operations lane by lane (floor, subtract, 1 - a,
  // products), the same integer clamps. Lanes of unlit pixels (NaN coordinates) are not used.
  alignas(32) int32_t off[4][8];
  alignas(32) float wt[4][8];
  const __m256i izero = _mm256_setzero_si256(), ione = _mm256_set1_epi32(1);
  const __m256i pw_max = _mm256_set1_epi32(pw - 1), ph_max = _mm256_set1_epi32(ph - 1),
                vpw = _mm256_set1_epi32(pw);
  const __m256i vb = _mm256_set1_epi32(B);
  const __m256 one = _mm256_set1_ps(1.0f);
  for (int xb = 0; xb < w; xb += 8) {
    const int nb = std::min(8, w - xb);
    const size_t ib = row_start + static_cast<size_t>(xb);
    if (nb == 8) {
      const __m256 u = _mm256_loadu_ps(g.proj_x.data() + ib),
                   t = _mm256_loadu_ps(g.proj_y.data() + ib);
      const __m256 fx0 = _mm256_floor_ps(u), fy0 = _mm256_floor_ps(t);
      const __m256 ax = _mm256_sub_ps(u, fx0), ay = _mm256_sub_ps(t, fy0);
      const __m256i ix = _mm256_cvttps_epi32(fx0), iy = _mm256_cvttps_epi32(fy0);
      const __m256i x0 = _mm256_min_epi32(_mm256_max_epi32(ix, izero), pw_max);
      const __m256i x1 =
          _mm256_min_epi32(_mm256_max_epi32(_mm256_add_epi32(ix, ione), izero), pw_max);
      const __m256i y0 =
          _mm256_mullo_epi32(_mm256_min_epi32(_mm256_max_epi32(iy, izero), ph_max), vpw);
      const __m256i y1 = _mm256_mullo_epi32(
          _mm256_min_epi32(_mm256_max_epi32(_mm256_add_epi32(iy, ione), izero), ph_max), vpw);
      _mm256_store_si256(reinterpret_cast<__m256i*>(off[0]),
                         _mm256_mullo_epi32(_mm256_add_epi32(y0, x0), vb));
      _mm256_store_si256(reinterpret_cast<__m256i*>(off[1]),
                         _mm256_mullo_epi32(_mm256_add_epi32(y0, x1), vb));
      _mm256_store_si256(reinterpret_cast<__m256i*>(off[2]),
                         _mm256_mullo_epi32(_mm256_add_epi32(y1, x0), vb));
      _mm256_store_si256(reinterpret_cast<__m256i*>(off[3]),
                         _mm256_mullo_epi32(_mm256_add_epi32(y1, x1), vb));
      const __m256 bx = _mm256_sub_ps(one, ax), by = _mm256_sub_ps(one, ay);
      _mm256_store_ps(wt[0], _mm256_mul_ps(bx, by));
      _mm256_store_ps(wt[1], _mm256_mul_ps(ax, by));
      _mm256_store_ps(wt[2], _mm256_mul_ps(bx, ay));
      _mm256_store_ps(wt[3], _mm256_mul_ps(ax, ay));
    } else {
      for (int p = 0; p < nb; ++p) {
        const size_t i = ib + static_cast<size_t>(p);
        if (!(g.factor[i] > 0)) continue;
        const BilinearTap tap = TapAt(inter, pw, ph, g.proj_x[i], g.proj_y[i], B);
        off[0][p] = static_cast<int32_t>(tap.p00 - inter),
        off[1][p] = static_cast<int32_t>(tap.p01 - inter);
        off[2][p] = static_cast<int32_t>(tap.p10 - inter),
        off[3][p] = static_cast<int32_t>(tap.p11 - inter);
        wt[0][p] = tap.w00, wt[1][p] = tap.w01, wt[2][p] = tap.w10, wt[3][p] = tap.w11;
      }
    }
    for (int p = 0; p < nb; ++p) {
      const int x = xb + p;
      const size_t i = ib + static_cast<size_t>(p);
      const float f = g.factor[i];
      const __m256 base = _mm256_set1_ps(ambient * g.albedo[i]);
      __m256 acc[kV];
      for (int j = 0; j < kV; ++j) acc[j] = base;
      if (f > 0) {
        const uint8_t *p00 = inter + off[0][p], *p01 = inter + off[1][p], *p10 = inter + off[2][p],
                      *p11 = inter + off[3][p];
        const __m256 w00 = _mm256_set1_ps(wt[0][p]), w01 = _mm256_set1_ps(wt[1][p]);
        const __m256 w10 = _mm256_set1_ps(wt[2][p]), w11 = _mm256_set1_ps(wt[3][p]);
        const __m256 gain = _mm256_set1_ps(f * (1.0f / 255));
#define SLSHADOW_LOAD8(ptr) \
  _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(ptr))))
        for (int j = 0; j < kV; ++j) {
          __m256 sum = _mm256_mul_ps(w00, SLSHADOW_LOAD8(p00 + 8 * j));
          sum = _mm256_add_ps(sum, _mm256_mul_ps(w01, SLSHADOW_LOAD8(p01 + 8 * j)));
          sum = _mm256_add_ps(sum, _mm256_mul_ps(w10, SLSHADOW_LOAD8(p10 + 8 * j)));
          sum = _mm256_add_ps(sum, _mm256_mul_ps(w11, SLSHADOW_LOAD8(p11 + 8 * j)));
          acc[j] = _mm256_add_ps(base, _mm256_mul_ps(gain, sum));
        }
#undef SLSHADOW_LOAD8
      }
      const __m256 m = _mm256_set1_ps(scale * (vig ? vig[x] : 1.0f));
      __m256i c[4] = {_mm256_setzero_si256(), _mm256_setzero_si256(), _mm256_setzero_si256(),
                      _mm256_setzero_si256()};
      for (int j = 0; j < kV; ++j) {
        c[j] = _mm256_cvttps_epi32(_mm256_min_ps(
            _mm256_add_ps(_mm256_max_ps(_mm256_mul_ps(acc[j], m), zero), half), vfull));
      }
      if constexpr (kTiled) {
        // Values 0..255: packed to 32 bytes in lane order (the packs work per 128-bit half; the
        // permutation puts the 4-byte groups back in image order).
        const __m256i bytes = _mm256_permutevar8x32_epi32(
            _mm256_packus_epi16(_mm256_packus_epi32(c[0], c[1]), _mm256_packus_epi32(c[2], c[3])),
            order);
        if constexpr (kV <= 2) {
          _mm_store_si128(reinterpret_cast<__m128i*>(tile[x & 15]), _mm256_castsi256_si128(bytes));
        } else {
          _mm256_store_si256(reinterpret_cast<__m256i*>(tile[x & 15]), bytes);
        }
        if ((x & 15) == 15) {
          if constexpr (kV <= 2) {
            StoreTransposed16(&tile[0][0], 32, rows, x - 15, B);
          } else {
            StoreTransposed32(tile, rows, x - 15, B);
          }
        }
      } else {
        for (int j = 0; j < kV; ++j)
          _mm256_store_si256(reinterpret_cast<__m256i*>(q + 8 * j), c[j]);
        for (int k = 0; k < B; ++k) rows[k][x] = static_cast<Out>(q[k]);
      }
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

template <typename Out>
void FusedDirectBilinear(const GeometryBuffer& g, const uint8_t* inter, int B, int pw, int ph,
                         float ambient, float scale, const cv::Mat& vignetting, float full,
                         std::vector<cv::Mat>& out) {
  const int w = g.width, h = g.height;
  tbb::parallel_for(tbb::blocked_range<int>(0, h, 4), [&](const tbb::blocked_range<int>& r) {
    Out* rows[32];
    float acc[32];
    for (int y = r.begin(); y < r.end(); ++y) {
      for (int k = 0; k < B; ++k) rows[k] = out[static_cast<size_t>(k)].ptr<Out>(y);
      const float* vig = vignetting.empty() ? nullptr : vignetting.ptr<float>(y);
#ifdef SLSHADOW_SIM_AVX2
      if (HaveAvx2()) {
        // Templated on the number of 8-lane vectors; the batch size is a run-time argument.
        const size_t row = static_cast<size_t>(y) * w;
        switch ((B + 7) / 8) {
          case 1:
            FusedRowAvx2<1, Out>(g, row, w, inter, pw, ph, ambient, scale, vig, full, B, rows);
            break;
          case 2:
            FusedRowAvx2<2, Out>(g, row, w, inter, pw, ph, ambient, scale, vig, full, B, rows);
            break;
          case 3:
            FusedRowAvx2<3, Out>(g, row, w, inter, pw, ph, ambient, scale, vig, full, B, rows);
            break;
          default:
            FusedRowAvx2<4, Out>(g, row, w, inter, pw, ph, ambient, scale, vig, full, B, rows);
            break;
        }
        continue;
      }
#endif
      for (int x = 0; x < w; ++x) {
        const size_t i = static_cast<size_t>(y) * w + x;
        const float f = g.factor[i];
        const float base = ambient * g.albedo[i];
        if (f > 0) {
          const BilinearTap t = TapAt(inter, pw, ph, g.proj_x[i], g.proj_y[i], B);
          const float gain = f * (1.0f / 255);
          for (int k = 0; k < B; ++k) {
            acc[k] = base + gain * (t.w00 * t.p00[k] + t.w01 * t.p01[k] + t.w10 * t.p10[k] +
                                    t.w11 * t.p11[k]);
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

}  // namespace
}  // namespace slshadow
