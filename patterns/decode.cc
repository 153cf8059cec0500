// Row-parallel decoding. Each stripe of rows owns its scratch rows (allocated once per stripe).
// Per row: the Gray and phase kernels read all frames of a block of 8 or 16 pixels with OpenCV's
// universal intrinsics (SSE2 baseline) and keep the running state in registers; the per-pixel
// unwrapping and status loops are branch-free (selects) under `#pragma omp simd`
// (-fopenmp-simd, -fno-trapping-math let GCC if-convert the float compares).
#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <numbers>
#include <type_traits>
#include <utility>

#include <opencv2/core/hal/intrin.hpp>

#include "core/config.h"
#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {
namespace {

constexpr uint8_t kFlagSaturated = 1, kFlagShadow = 2, kFlagLowContrast = 4, kFlagCodeError = 8;

// The first reason by priority: saturated, shadow, low contrast, code error; indexed by flags.
constexpr uint8_t kStatusOfFlags[16] = {0, 3, 1, 3, 2, 3, 1, 3, 4, 3, 1, 3, 2, 3, 1, 3};
static_assert(static_cast<int>(PixelStatus::kSaturated) == 3 &&
              static_cast<int>(PixelStatus::kShadow) == 1 &&
              static_cast<int>(PixelStatus::kLowContrast) == 2 &&
              static_cast<int>(PixelStatus::kCodeError) == 4);

// floor and round-to-nearest for |v| < 2^23 without libm calls (SSE2 has no roundps).
inline float Floor(float v) {
  const float t = static_cast<float>(static_cast<int32_t>(v));
  return t > v ? t - 1.0f : t;
}
inline float Round(float v) { return Floor(v + 0.5f); }

// atan2(y, x) / (2 pi) in [0, 1). Octant reduction, then Hastings' odd polynomial for atan on
// [0, 1] (max error 1e-5 rad).
inline float Atan2CyclesInline(float y, float x) {
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float mx = ax > ay ? ax : ay, mn = ax > ay ? ay : ax;
  const float a = mn / (mx > 1e-30f ? mx : 1e-30f);
  const float s = a * a;
  float r =
      a * (0.9998660f + s * (-0.3302995f + s * (0.1801410f + s * (-0.0851330f + s * 0.0208351f))));
  r = ay > ax ? 1.57079632679f - r : r;
  r = x < 0 ? 3.14159265359f - r : r;
  r = y < 0 ? -r : r;
  float f = r * 0.159154943092f;
  f = f < 0 ? f + 1.0f : f;
  return f >= 1.0f ? 0.0f : f;
}

struct Levels {
  float shadow;        // minimum lit range
  int32_t contrast;    // minimum bit contrast (integer grey levels, rounded up)
  int32_t saturation;  // saturation level
  float unwrap_tol;    // cycles
  bool gray_edges;     // Gray code: a single unreadable bit at a code edge gives the edge position
};

// Gray-code bits of one axis: `frames` holds 2 * nbits row pointers, MSB first, pattern then
// inverse. Computes the binary code, the two smallest bit contrasts |P - I| and, if kTrackMask,
// the bit k of the smallest (OpenCV universal intrinsics, SSE2 baseline).
template <typename T>
inline cv::v_uint16x8 Load8(const T* p);
template <>
inline cv::v_uint16x8 Load8<uint8_t>(const uint8_t* p) {
  return cv::v_load_expand(p);
}
template <>
inline cv::v_uint16x8 Load8<uint16_t>(const uint16_t* p) {
  return cv::v_load(p);
}

// Scalar tail shared by both input types.
template <typename T>
void GrayAxisTail(const T* const* frames, int nbits, int x0, int width, uint16_t* code,
                  uint16_t* min1, uint16_t* min2, uint16_t* min_bit) {
  for (int x = x0; x < width; ++x) {
    uint32_t c_code = 0, c_min1 = 0xFFFF, c_min2 = 0xFFFF, c_bit = 0;
    for (int b = 0; b < nbits; ++b) {
      const int32_t pv = frames[2 * b][x], qv = frames[2 * b + 1][x];
      const uint32_t c = static_cast<uint32_t>(pv > qv ? pv - qv : qv - pv);
      c_code = (c_code << 1) | ((c_code & 1u) ^ (pv > qv ? 1u : 0u));
      if (c < c_min1) c_bit = static_cast<uint32_t>(nbits - 1 - b);
      c_min2 = std::min(c_min2, std::max(c_min1, c));
      c_min1 = std::min(c_min1, c);
    }
    code[x] = static_cast<uint16_t>(c_code);
    min1[x] = static_cast<uint16_t>(c_min1);
    min2[x] = static_cast<uint16_t>(c_min2);
    min_bit[x] = static_cast<uint16_t>(c_bit);
  }
}

// 16-bit input: 8 pixels per register, all state uint16 (codes < 2^16: an axis has at most
// 65536 pixels).
template <typename T, bool kTrackMask>
void GrayAxisRow(const T* const* frames, int nbits, int width, uint16_t* __restrict code,
                 uint16_t* __restrict min1, uint16_t* __restrict min2,
                 uint16_t* __restrict min_bit) {
  const int vec_end = width - width % 8;
  const cv::v_uint16x8 one = cv::v_setall_u16(1);
  for (int x = 0; x < vec_end; x += 8) {
    cv::v_uint16x8 c_code = cv::v_setzero_u16(), c_min1 = cv::v_setall_u16(0xFFFF), c_min2 = c_min1;
    cv::v_uint16x8 c_bit = cv::v_setzero_u16();
    for (int b = 0; b < nbits; ++b) {
      const cv::v_uint16x8 p = Load8<T>(frames[2 * b] + x), q = Load8<T>(frames[2 * b + 1] + x);
      const cv::v_uint16x8 g = (p > q) & one;
      const cv::v_uint16x8 c = cv::v_absdiff(p, q);
      c_code =
          cv::v_shl<1>(c_code) | ((c_code & one) ^ g);  // binary bit = previous binary XOR Gray
      if constexpr (kTrackMask) {
        c_bit =
            cv::v_select(c < c_min1, cv::v_setall_u16(static_cast<uint16_t>(nbits - 1 - b)), c_bit);
      }
      c_min2 = cv::v_min(c_min2, cv::v_max(c_min1, c));
      c_min1 = cv::v_min(c_min1, c);
    }
    cv::v_store(code + x, c_code);
    cv::v_store(min1 + x, c_min1);
    cv::v_store(min2 + x, c_min2);
    if constexpr (kTrackMask) cv::v_store(min_bit + x, c_bit);
  }
  GrayAxisTail(frames, nbits, vec_end, width, code, min1, min2, min_bit);
}

// 8-bit input: 16 pixels per register with byte arithmetic (saturating differences give the
// comparison and the contrast); the code is built as a high and a low byte.
template <bool kTrackMask>
void GrayAxisRow8(const uint8_t* const* frames, int nbits, int width, uint16_t* __restrict code,
                  uint16_t* __restrict min1, uint16_t* __restrict min2,
                  uint16_t* __restrict min_bit) {
  const int vec_end = width - width % 16;
  const cv::v_uint8x16 one = cv::v_setall_u8(1), zero = cv::v_setzero_u8();
  for (int x = 0; x < vec_end; x += 16) {
    cv::v_uint8x16 hi = zero, lo = zero, bin = zero, c_min1 = cv::v_setall_u8(0xFF),
                   c_min2 = c_min1, c_bit = zero;
    for (int b = 0; b < nbits; ++b) {
      const cv::v_uint8x16 p = cv::v_load(frames[2 * b] + x), q = cv::v_load(frames[2 * b + 1] + x);
      const cv::v_uint8x16 pq = p - q, qp = q - p;  // saturating: pq > 0 exactly where p > q
      const cv::v_uint8x16 c = pq | qp;             // |p - q|
      bin = bin ^ ~(pq == zero);                    // binary bit = previous binary XOR Gray bit
      const int k = nbits - 1 - b;
      if (k >= 8) {
        hi = cv::v_add_wrap(hi, hi) | (bin & one);
      } else {
        lo = cv::v_add_wrap(lo, lo) | (bin & one);
      }
      if constexpr (kTrackMask)
        c_bit = cv::v_select(c < c_min1, cv::v_setall_u8(static_cast<uint8_t>(k)), c_bit);
      c_min2 = cv::v_min(c_min2, cv::v_max(c_min1, c));
      c_min1 = cv::v_min(c_min1, c);
    }
    cv::v_uint16x8 h0, h1, l0, l1;
    cv::v_expand(hi, h0, h1);
    cv::v_expand(lo, l0, l1);
    cv::v_store(code + x, cv::v_shl<8>(h0) | l0);
    cv::v_store(code + x + 8, cv::v_shl<8>(h1) | l1);
    // Contrast 255 is "no bit seen yet" only when nbits == 0, which a spec never has.
    cv::v_expand(c_min1, l0, l1);
    cv::v_store(min1 + x, l0);
    cv::v_store(min1 + x + 8, l1);
    cv::v_expand(c_min2, l0, l1);
    cv::v_store(min2 + x, l0);
    cv::v_store(min2 + x + 8, l1);
    if constexpr (kTrackMask) {
      cv::v_expand(c_bit, l0, l1);
      cv::v_store(min_bit + x, l0);
      cv::v_store(min_bit + x + 8, l1);
    }
  }
  GrayAxisTail(frames, nbits, vec_end, width, code, min1, min2, min_bit);
}

// Dispatch: byte kernel for 8-bit input.
template <typename T, bool kTrackMask>
void GrayAxis(const T* const* frames, int nbits, int width, uint16_t* code, uint16_t* min1,
              uint16_t* min2, uint16_t* min_bit) {
  if constexpr (std::is_same_v<T, uint8_t>) {
    GrayAxisRow8<kTrackMask>(frames, nbits, width, code, min1, min2, min_bit);
  } else {
    GrayAxisRow<T, kTrackMask>(frames, nbits, width, code, min1, min2, min_bit);
  }
}

// N-step phase of one frequency: wrapped phase in cycles [0, 1), modulation B', and the running
// maximum level (saturation). The sums run over 8 pixels at a time in registers.
// `standard` says the coefficients are sin / cos(2 pi n / N) (no offset, direction +1), which
// allows the exact integer path for 4 steps.
template <typename T>
void PhaseRow(const T* const* frames, int steps, bool standard, const float* sn, const float* cn,
              int width, float* __restrict sum_s, float* __restrict sum_c, float* __restrict cycles,
              float* __restrict modulation, int32_t* __restrict maxv) {
  const int vec_end = width - width % 8;
  if constexpr (std::is_same_v<T, uint8_t>) {
    if (steps == 4 && standard) {
      // 4 steps: S = I1 - I3, C = I0 - I2 exactly, in 16-bit integers.
      for (int x = 0; x < vec_end; x += 8) {
        const cv::v_uint16x8 v0 = Load8<T>(frames[0] + x), v1 = Load8<T>(frames[1] + x);
        const cv::v_uint16x8 v2 = Load8<T>(frames[2] + x), v3 = Load8<T>(frames[3] + x);
        const cv::v_int16x8 ds = cv::v_reinterpret_as_s16(v1) - cv::v_reinterpret_as_s16(v3);
        const cv::v_int16x8 dc = cv::v_reinterpret_as_s16(v0) - cv::v_reinterpret_as_s16(v2);
        cv::v_int32x4 lo, hi;
        cv::v_expand(ds, lo, hi);
        cv::v_store(sum_s + x, cv::v_cvt_f32(lo));
        cv::v_store(sum_s + x + 4, cv::v_cvt_f32(hi));
        cv::v_expand(dc, lo, hi);
        cv::v_store(sum_c + x, cv::v_cvt_f32(lo));
        cv::v_store(sum_c + x + 4, cv::v_cvt_f32(hi));
        const cv::v_uint16x8 top = cv::v_max(cv::v_max(v0, v1), cv::v_max(v2, v3));
        cv::v_uint32x4 tlo, thi;
        cv::v_expand(top, tlo, thi);
        cv::v_store(maxv + x, cv::v_max(cv::v_load(maxv + x), cv::v_reinterpret_as_s32(tlo)));
        cv::v_store(maxv + x + 4,
                    cv::v_max(cv::v_load(maxv + x + 4), cv::v_reinterpret_as_s32(thi)));
      }
    }
  }
  const bool done = std::is_same_v<T, uint8_t> && steps == 4 && standard;
  for (int x = 0; x < (done ? 0 : vec_end); x += 8) {
    cv::v_float32x4 s0 = cv::v_setzero_f32(), s1 = s0, c0 = s0, c1 = s0;
    cv::v_uint16x8 top = cv::v_setzero_u16();
    for (int n = 0; n < steps; ++n) {
      const cv::v_uint16x8 v = Load8<T>(frames[n] + x);
      top = cv::v_max(top, v);
      cv::v_uint32x4 lo, hi;
      cv::v_expand(v, lo, hi);
      const cv::v_float32x4 flo = cv::v_cvt_f32(cv::v_reinterpret_as_s32(lo));
      const cv::v_float32x4 fhi = cv::v_cvt_f32(cv::v_reinterpret_as_s32(hi));
      const cv::v_float32x4 vs = cv::v_setall_f32(sn[n]), vc = cv::v_setall_f32(cn[n]);
      s0 = cv::v_fma(flo, vs, s0);
      s1 = cv::v_fma(fhi, vs, s1);
      c0 = cv::v_fma(flo, vc, c0);
      c1 = cv::v_fma(fhi, vc, c1);
    }
    cv::v_store(sum_s + x, s0);
    cv::v_store(sum_s + x + 4, s1);
    cv::v_store(sum_c + x, c0);
    cv::v_store(sum_c + x + 4, c1);
    cv::v_uint32x4 tlo, thi;
    cv::v_expand(top, tlo, thi);
    cv::v_store(maxv + x, cv::v_max(cv::v_load(maxv + x), cv::v_reinterpret_as_s32(tlo)));
    cv::v_store(maxv + x + 4, cv::v_max(cv::v_load(maxv + x + 4), cv::v_reinterpret_as_s32(thi)));
  }
  for (int x = vec_end; x < width; ++x) {
    float ss = 0, cc = 0;
    for (int n = 0; n < steps; ++n) {
      const int32_t v = frames[n][x];
      ss += static_cast<float>(v) * sn[n];
      cc += static_cast<float>(v) * cn[n];
      maxv[x] = std::max(maxv[x], v);
    }
    sum_s[x] = ss;
    sum_c[x] = cc;
  }
  const float scale = 2.0f / static_cast<float>(steps);
#pragma omp simd
  for (int x = 0; x < width; ++x) {
    const float s = sum_s[x], c = sum_c[x];
    cycles[x] = Atan2CyclesInline(s, c);
    modulation[x] = scale * std::sqrt(s * s + c * c);
  }
}

// Per-stripe scratch rows.
struct Scratch {
  explicit Scratch(int width) : w(static_cast<size_t>(width)) {}
  size_t w;
  std::vector<uint16_t> code[2], min1, min2, min_bit;
  std::vector<uint16_t> code_b, min1_b, min2_b, min_bit_b;  // the shifted Gray code (kShifted)
  std::vector<uint16_t> reference;  // threshold row of Gray bits without inverse, as T
  std::vector<int32_t> sum;         // phase mean accumulator
  std::vector<int32_t> maxv;
  std::vector<float> sum_s, sum_c, cycles[3], modulation[3], coord[2], quality;
  std::vector<uint8_t> flags;
  void Int(std::vector<int32_t>& v) { v.resize(w); }
  void U16(std::vector<uint16_t>& v) { v.resize(w); }
  void Float(std::vector<float>& v) { v.resize(w); }
};

class Decoder {
 public:
  Decoder(const PatternSpec& spec, const std::vector<cv::Mat>& images, const Levels& levels,
          ProjectorMap* out)
      : spec_(spec), images_(images), levels_(levels), out_(out), frames_(spec.Frames()) {
    for (int n = 0; n < spec.phase_steps; ++n) {
      const double d = spec.PhaseStepAngle(n);
      sin_.push_back(static_cast<float>(std::sin(d)));
      cos_.push_back(static_cast<float>(std::cos(d)));
    }
    standard_phase_ = spec.phase_direction == 1 && spec.phase_offset_rad == 0;
    reference_ = spec.ResolvedGrayReference();
    // Frame indices per axis, by role: Gray bits MSB first as (pattern, inverse or -1), phase
    // frames by step, whatever the projection order.
    for (int a = 0; a < 2; ++a) {
      const int nbits = spec.Codes(a) ? spec.GrayBits(a) : 0;
      for (int code = 0; code < 2; ++code)
        gray_[a][code].assign(static_cast<size_t>(nbits), {-1, -1});
      for (int f = 0; f < 3; ++f) phase_[a][f].assign(static_cast<size_t>(spec.phase_steps), -1);
    }
    for (size_t i = 0; i < frames_.size(); ++i) {
      const FrameInfo& fr = frames_[i];
      const int idx = static_cast<int>(i);
      if (fr.role == FrameRole::kGrayBit || fr.role == FrameRole::kGrayBitInverse) {
        auto& bits = gray_[fr.axis][fr.code];
        auto& slot = bits[bits.size() - 1 - static_cast<size_t>(fr.bit)];
        (fr.role == FrameRole::kGrayBit ? slot.first : slot.second) = idx;
      }
      if (fr.role == FrameRole::kPhase)
        phase_[fr.axis][fr.frequency][static_cast<size_t>(fr.step)] = idx;
      if (fr.role == FrameRole::kWhite) white_ = idx;
      if (fr.role == FrameRole::kBlack) black_ = idx;
    }
  }

  template <typename T>
  void Rows(int y0, int y1) const {
    const int width = out_->width();
    Scratch s(width);
    s.U16(s.min1);
    s.U16(s.min2);
    s.U16(s.min_bit);
    s.Int(s.maxv);
    s.Float(s.quality);
    s.flags.resize(s.w);
    for (int a = 0; a < 2; ++a) {
      s.U16(s.code[a]);
      s.Float(s.coord[a]);
    }
    s.Float(s.sum_s);
    s.Float(s.sum_c);
    s.U16(s.reference);
    s.Int(s.sum);
    if (spec_.GrayCodes() == 2) {
      s.U16(s.code_b);
      s.U16(s.min1_b);
      s.U16(s.min2_b);
      s.U16(s.min_bit_b);
    }
    for (int f = 0; f < 3; ++f) {
      s.Float(s.cycles[f]);
      s.Float(s.modulation[f]);
    }
    std::vector<const T*> rows(images_.size());
    const size_t row_bytes = static_cast<size_t>(width) * sizeof(T);
    for (int y = y0; y < y1; ++y) {
      for (size_t i = 0; i < images_.size(); ++i) rows[i] = images_[i].ptr<T>(y);
      // The frames are read 8 pixels at a time across all frames: too many streams for the
      // hardware prefetcher, so fetch the next row of every frame while this one is decoded.
      if (y + 1 < y1) {
        for (size_t i = 0; i < images_.size(); ++i) {
          const char* next = reinterpret_cast<const char*>(images_[i].ptr<T>(y + 1));
          for (size_t off = 0; off < row_bytes; off += 64) __builtin_prefetch(next + off);
        }
      }
      std::fill(s.flags.begin(), s.flags.end(), uint8_t{0});
      switch (spec_.kind) {
        case PatternKind::kGrayCode:
          GrayCodeRow<T>(rows, s);
          break;
        case PatternKind::kPhaseShift:
          PhaseShiftRow<T>(rows, s);
          break;
        case PatternKind::kMultiFrequency:
          MultiFrequencyRow<T>(rows, s);
          break;
      }
      Write(y, s);
    }
  }

 private:
  template <typename T>
  void GatherRows(const std::vector<const T*>& rows, const std::vector<int>& idx,
                  std::vector<const T*>& out) const {
    out.resize(idx.size());
    for (size_t i = 0; i < idx.size(); ++i) out[i] = rows[static_cast<size_t>(idx[i])];
  }

  // The row pointers of one Gray code of axis a, MSB first, each bit as (pattern, inverse); a bit
  // without an inverse gets the reference row, computed here (white_black: (white + black + 1) / 2;
  // phase_mean: the rounded mean of the axis' phase frames).
  template <typename T>
  void GrayRows(const std::vector<const T*>& rows, int a, int code, Scratch& s,
                std::vector<const T*>& out) const {
    const auto& bits = gray_[a][code];
    out.resize(2 * bits.size());
    const T* reference = nullptr;
    if (!spec_.gray_inverse) {
      const int width = out_->width();
      T* ref = reinterpret_cast<T*>(s.reference.data());
      if (reference_ == GrayReference::kWhiteBlack) {
        const T* w = rows[static_cast<size_t>(white_)];
        const T* b = rows[static_cast<size_t>(black_)];
        for (int x = 0; x < width; ++x)
          ref[x] = static_cast<T>((int32_t{w[x]} + int32_t{b[x]} + 1) >> 1);
      } else {
        int32_t* sum = s.sum.data();
        std::fill(sum, sum + width, 0);
        for (const int idx : phase_[a][0]) {
          const T* p = rows[static_cast<size_t>(idx)];
          for (int x = 0; x < width; ++x) sum[x] += p[x];
        }
        const int32_t n = spec_.phase_steps;
        for (int x = 0; x < width; ++x) ref[x] = static_cast<T>((sum[x] + n / 2) / n);
      }
      reference = ref;
    }
    for (size_t b = 0; b < bits.size(); ++b) {
      out[2 * b] = rows[static_cast<size_t>(bits[b].first)];
      out[2 * b + 1] = bits[b].second >= 0 ? rows[static_cast<size_t>(bits[b].second)] : reference;
    }
  }

  template <typename T>
  void GrayCodeRow(const std::vector<const T*>& rows, Scratch& s) const {
    const int width = out_->width();
    const T* __restrict white = rows[static_cast<size_t>(white_)];
    const T* __restrict black = rows[static_cast<size_t>(black_)];
    const uint16_t* __restrict min1 = s.min1.data();
    const uint16_t* __restrict min2 = s.min2.data();
    const uint16_t* __restrict min_bit = s.min_bit.data();
    uint8_t* __restrict flags = s.flags.data();
    float* __restrict quality = s.quality.data();
    const int32_t saturation = levels_.saturation;
// The white frame is the brightest a pixel gets: it alone decides saturation.
#pragma omp simd
    for (int x = 0; x < width; ++x) {
      const int32_t wv = white[x], bv = black[x];
      flags[x] =
          static_cast<uint8_t>((static_cast<float>(wv - bv) < levels_.shadow ? kFlagShadow : 0) |
                               ((wv >= saturation) | (bv >= saturation) ? kFlagSaturated : 0));
      quality[x] = std::numeric_limits<float>::max();
    }
    const int32_t threshold = levels_.contrast;
    const bool edges = levels_.gray_edges;
    std::vector<const T*> frames;
    for (int a = 0; a < 2; ++a) {
      if (!spec_.Codes(a)) continue;
      GrayRows(rows, a, 0, s, frames);
      if (edges) {
        GrayAxis<T, true>(frames.data(), spec_.GrayBits(a), width, s.code[a].data(), s.min1.data(),
                          s.min2.data(), s.min_bit.data());
      } else {
        GrayAxis<T, false>(frames.data(), spec_.GrayBits(a), width, s.code[a].data(), s.min1.data(),
                           s.min2.data(), s.min_bit.data());
      }
      const int32_t size = spec_.AxisSize(a);
      const uint16_t* __restrict code = s.code[a].data();
      float* __restrict coord = s.coord[a].data();
#pragma omp simd
      for (int x = 0; x < width; ++x) {
        const int32_t c = code[x];
        // One unreadable bit whose flip gives the adjacent code: the pixel sees the edge between
        // the two projector pixels, at c +- 0.5.
        // Flipping Gray bit k flips binary bits k..0.
        const int32_t other = c ^ ((2 << min_bit[x]) - 1);
        const int32_t m1 = min1[x], m2 = min2[x];
        const bool edge =
            edges & (m1 < threshold) & (m2 >= threshold) & ((c - other) * (c - other) == 1);
        const bool low = (m1 < threshold) & !edge;
        coord[x] = edge ? 0.5f * static_cast<float>(c + other) : static_cast<float>(c);
        flags[x] |= (c >= size ? kFlagCodeError : 0) | (low ? kFlagLowContrast : 0);
        const float q = static_cast<float>(m1);
        quality[x] = q < quality[x] ? q : quality[x];
      }
    }
  }

  template <typename T>
  void PhaseShiftRow(const std::vector<const T*>& rows, Scratch& s) const {
    const int width = out_->width();
    int32_t* __restrict maxv = s.maxv.data();
    const uint16_t* __restrict min1 = s.min1.data();
    const uint16_t* __restrict min2 = s.min2.data();
    uint8_t* __restrict flags = s.flags.data();
    float* __restrict quality = s.quality.data();
    std::fill(s.maxv.begin(), s.maxv.end(), 0);
    std::fill(s.quality.begin(), s.quality.end(), std::numeric_limits<float>::max());
    std::vector<const T*> frames;
    for (int a = 0; a < 2; ++a) {
      if (!spec_.Codes(a)) continue;
      GatherRows(rows, phase_[a][0], frames);
      PhaseRow<T>(frames.data(), spec_.phase_steps, standard_phase_, sin_.data(), cos_.data(),
                  width, s.sum_s.data(), s.sum_c.data(), s.cycles[0].data(), s.modulation[0].data(),
                  maxv);
      GrayRows(rows, a, spec_.FirstGrayCode(), s, frames);
      const int nbits = spec_.GrayBits(a);
      const uint16_t* __restrict h = s.code[a].data();
      const float* __restrict f = s.cycles[0].data();
      const float* __restrict mod = s.modulation[0].data();
      float* __restrict coord = s.coord[a].data();
      const float period = static_cast<float>(spec_.period_px);
      const float lo = -1.0f, hi = static_cast<float>(spec_.AxisSize(a));
      if (spec_.gray_code == GrayCodeVariant::kShiftedOnly) {
        GrayAxis<T, true>(frames.data(), nbits, width, s.code[a].data(), s.min1.data(),
                          s.min2.data(), s.min_bit.data());
        ShiftedOnlyUnwrap<T>(a, frames.data(), h, f, mod, s.min1.data(), s.min2.data(),
                             s.min_bit.data(), width, coord, flags, quality);
        continue;
      }
      GrayAxis<T, false>(frames.data(), nbits, width, s.code[a].data(), s.min1.data(),
                         s.min2.data(), s.min_bit.data());
      if (spec_.gray_code == GrayCodeVariant::kShifted) {
        GrayRows(rows, a, 1, s, frames);
        GrayAxis<T, false>(frames.data(), nbits, width, s.code_b.data(), s.min1_b.data(),
                           s.min2_b.data(), s.min_bit_b.data());
        const uint16_t* __restrict h2 = s.code_b.data();
        const uint16_t* __restrict min1_b = s.min1_b.data();
        const int32_t k1_max = static_cast<int32_t>(spec_.GrayValue(0, spec_.AxisSize(a) - 1));
        const int32_t k2_max = static_cast<int32_t>(spec_.GrayValue(1, spec_.AxisSize(a) - 1));
#pragma omp simd
        for (int x = 0; x < width; ++x) {
          // k1 = floor(x / P) has its edges at the phase wraps, k2 = floor(x / P + 1/2) half a
          // period away: use k2 near the wraps and k1 in the middle, and only that code's contrast.
          const int32_t k1 = h[x], k2 = h2[x];
          const float fx = f[x];
          const bool middle = (fx >= 0.25f) & (fx <= 0.75f);
          const int32_t k = middle ? k1 : (fx < 0.25f ? k2 : k2 - 1);
          const float xc = (static_cast<float>(k) + fx) * period;
          coord[x] = xc;
          const int32_t contrast = middle ? min1[x] : min1_b[x];
          const bool bad = (k1 > k1_max) | (k2 > k2_max) | (xc < lo) | (xc > hi);
          flags[x] |= (bad ? kFlagCodeError : 0) |
                      (2.0f * mod[x] < levels_.shadow ? kFlagShadow : 0) |
                      (contrast < levels_.contrast ? kFlagLowContrast : 0);
          quality[x] = mod[x] < quality[x] ? mod[x] : quality[x];
        }
        continue;
      }
      const auto h_max =
          static_cast<int32_t>(std::floor(2.0 * (spec_.AxisSize(a) - 1) / spec_.period_px));
      const uint16_t* __restrict contrast = nbits >= 2 ? min2 : min1;
#pragma omp simd
      for (int x = 0; x < width; ++x) {
        // Complementary unwrapping: k1 = h >> 1 has its edges at the phase wraps, k2 = (h + 1) >> 1
        // half a period away; use k2 near the wraps and k1 in the middle of the period.
        const int32_t hx = h[x];
        const int32_t k1 = hx >> 1, k2 = (hx + 1) >> 1;
        const float fx = f[x];
        const int32_t k = fx < 0.25f ? k2 : (fx > 0.75f ? k2 - 1 : k1);
        const float xc = (static_cast<float>(k) + fx) * period;
        coord[x] = xc;
        const bool bad = (hx > h_max) | (xc < lo) | (xc > hi);
        flags[x] |= (bad ? kFlagCodeError : 0) |
                    (2.0f * mod[x] < levels_.shadow ? kFlagShadow : 0) |
                    (static_cast<int32_t>(contrast[x]) < levels_.contrast ? kFlagLowContrast : 0);
        quality[x] = mod[x] < quality[x] ? mod[x] : quality[x];
      }
    }
#pragma omp simd
    for (int x = 0; x < width; ++x) flags[x] |= maxv[x] >= levels_.saturation ? kFlagSaturated : 0;
  }

  // Unwrapping with the shifted code k2 = floor(x / P + 1/2) alone. Near the phase wraps (phi < 1/4
  // or > 3/4) k2 is read a quarter period from its edges: k = k2, or k2 - 1 just before a wrap.
  // In the middle of a period the pixel is near an edge of k2 (between codes m - 1 and m, at
  // projector coordinate e(m) = ceil((m - 1/2) P) - 1/2, where the generated stripes change), and
  // k = m - 1 on both sides of it, so what is needed is which edge, not which side:
  //   - the Gray bit that toggles at the edge (ctz(m)) is weak near it, while every other bit is
  //     at least 3/4 of a period from its own edges. Pattern / inverse pairs have one full
  //     contrast in either state: the edge whose bit is the clearly weaker (below 3/4) of the two
  //     candidates' (ctz(k2) below k2, ctz(k2 + 1) above) is the one. Bits without inverse are
  //     compared with a reference whose contrast differs between the states: the edge is the one
  //     of the weakest bit when it is below half the second weakest;
  //   - otherwise the code is read clearly and the phase says the side: of the two candidates
  //     x = (k2 + phi) P (below e(k2 + 1)) and x - P (above e(k2)), the one farther inside.
  // Low contrast then looks at the second-smallest bit contrast where the smallest is one of the
  // two candidates' (the weak edge bit is expected), else at the smallest.
  template <typename T>
  void ShiftedOnlyUnwrap(int a, const T* const* gray, const uint16_t* h, const float* f,
                         const float* mod, const uint16_t* min1, const uint16_t* min2,
                         const uint16_t* min_bit, int width, float* coord, uint8_t* flags,
                         float* quality) const {
    const double period = spec_.period_px;
    const int nbits = spec_.GrayBits(a);
    const auto k2_max = static_cast<int32_t>(spec_.GrayValue(1, spec_.AxisSize(a) - 1));
    const float lo = -1.0f, hi = static_cast<float>(spec_.AxisSize(a));
    const auto edge = [&](int32_t m) { return std::ceil((m - 0.5) * period) - 0.5; };
    // |pattern - inverse| of Gray bit `bit` at pixel x; no such bit: larger than any contrast.
    const auto contrast_of = [&](int bit, int x) -> double {
      if (bit < 0 || bit >= nbits) return std::numeric_limits<double>::infinity();
      const size_t i = static_cast<size_t>(nbits - 1 - bit);
      const int32_t p = gray[2 * i][x], q = gray[2 * i + 1][x];
      return p > q ? p - q : q - p;
    };
    for (int x = 0; x < width; ++x) {
      const int32_t k2 = h[x];
      const float fx = f[x];
      int32_t k = fx < 0.25f ? k2 : k2 - 1;
      int32_t contrast = min1[x];
      if (fx >= 0.25f && fx <= 0.75f) {
        const double x_above = (k2 + static_cast<double>(fx)) * period;
        const double inside_above = edge(k2 + 1) - x_above;
        const double inside_below = (x_above - period) - edge(k2);
        k = inside_above > inside_below ? k2 : k2 - 1;
        const int below = k2 > 0 ? std::countr_zero(static_cast<uint32_t>(k2)) : -1;
        const int above = std::countr_zero(static_cast<uint32_t>(k2) + 1u);
        const int weakest = min_bit[x];
        int near = 0;  // -1: the edge below k2, +1: the edge above, 0: undecided
        if (spec_.gray_inverse) {
          const double c_below = contrast_of(below, x), c_above = contrast_of(above, x);
          near = c_below < 0.75 * c_above ? -1 : c_above < 0.75 * c_below ? 1 : 0;
        } else if (2 * int32_t{min1[x]} < int32_t{min2[x]}) {
          near = weakest == below ? -1 : weakest == above ? 1 : 0;
        }
        if (near != 0) k = near < 0 ? k2 - 1 : k2;
        if (weakest == below || weakest == above) contrast = min2[x];
      }
      const float xc = (static_cast<float>(k) + fx) * static_cast<float>(period);
      coord[x] = xc;
      const bool bad = (k2 > k2_max) | (xc < lo) | (xc > hi);
      flags[x] |= (bad ? kFlagCodeError : 0) | (2.0f * mod[x] < levels_.shadow ? kFlagShadow : 0) |
                  (contrast < levels_.contrast ? kFlagLowContrast : 0);
      quality[x] = mod[x] < quality[x] ? mod[x] : quality[x];
    }
  }

  template <typename T>
  void MultiFrequencyRow(const std::vector<const T*>& rows, Scratch& s) const {
    const int width = out_->width();
    int32_t* __restrict maxv = s.maxv.data();
    uint8_t* __restrict flags = s.flags.data();
    float* __restrict quality = s.quality.data();
    std::fill(s.maxv.begin(), s.maxv.end(), 0);
    std::fill(s.quality.begin(), s.quality.end(), std::numeric_limits<float>::max());
    const float p1 = static_cast<float>(spec_.periods_px[0]);
    const float p12 = static_cast<float>(spec_.BeatPeriod12Px());
    const float p123 = static_cast<float>(spec_.BeatPeriod123Px());
    const float tol = levels_.unwrap_tol;
    std::vector<const T*> frames;
    for (int a = 0; a < 2; ++a) {
      if (!spec_.Codes(a)) continue;
      for (int fq = 0; fq < 3; ++fq) {
        GatherRows(rows, phase_[a][fq], frames);
        PhaseRow<T>(frames.data(), spec_.phase_steps, standard_phase_, sin_.data(), cos_.data(),
                    width, s.sum_s.data(), s.sum_c.data(), s.cycles[fq].data(),
                    s.modulation[fq].data(), maxv);
      }
      const float* __restrict f1 = s.cycles[0].data();
      const float* __restrict f2 = s.cycles[1].data();
      const float* __restrict f3 = s.cycles[2].data();
      const float* __restrict m1 = s.modulation[0].data();
      const float* __restrict m2 = s.modulation[1].data();
      const float* __restrict m3 = s.modulation[2].data();
      float* __restrict coord = s.coord[a].data();
      const float size = static_cast<float>(spec_.AxisSize(a));
      const float centre = 0.5f * (size - 1.0f);  // middle of the decodable range [-0.5, S - 0.5]
      const float lo = -1.0f, hi = size;
      const float inv_p12 = 1.0f / p12, inv_p1 = 1.0f / p1, centre_cycles = centre / p123;
#pragma omp simd
      for (int x = 0; x < width; ++x) {
        float f12 = f1[x] - f2[x];
        f12 -= Floor(f12);
        float f23 = f2[x] - f3[x];
        f23 -= Floor(f23);
        float f123 = f12 - f23;
        f123 -= Floor(f123);
        // Absolute coordinate from the longest beat, centred on the axis.
        float t = f123 - centre_cycles;
        t -= Round(t);
        const float x123 = centre + p123 * t;
        const float u12 = x123 * inv_p12 - f12;
        const float k12 = Round(u12);
        const float x12 = p12 * (f12 + k12);
        const float u1 = x12 * inv_p1 - f1[x];
        const float k1 = Round(u1);
        const float xc = p1 * (f1[x] + k1);
        coord[x] = xc;
        const bool bad =
            (std::fabs(u12 - k12) > tol) | (std::fabs(u1 - k1) > tol) | (xc < lo) | (xc > hi);
        const float m12 = m1[x] < m2[x] ? m1[x] : m2[x];
        const float mod = m12 < m3[x] ? m12 : m3[x];
        flags[x] |= (bad ? kFlagCodeError : 0) | (2.0f * mod < levels_.shadow ? kFlagShadow : 0);
        quality[x] = mod < quality[x] ? mod : quality[x];
      }
    }
#pragma omp simd
    for (int x = 0; x < width; ++x) flags[x] |= maxv[x] >= levels_.saturation ? kFlagSaturated : 0;
  }

  void Write(int y, const Scratch& s) const {
    const int width = out_->width();
    const float nan = std::numeric_limits<float>::quiet_NaN();
    uint8_t* status = out_->status.ptr<uint8_t>(y);
    float* quality = out_->quality.ptr<float>(y);
    float* px = out_->proj_x.ptr<float>(y);
    float* py = out_->proj_y.ptr<float>(y);
    const float* cx = s.coord[0].data();
    const float* cy = s.coord[1].data();
    const uint8_t* flags = s.flags.data();
    const float* q = s.quality.data();
    const bool has_x = spec_.code_x, has_y = spec_.code_y;
    // Status by priority with byte selects, 16 pixels at a time (order: lowest priority first).
    const int vec16 = width - width % 16;
    const cv::v_uint8x16 zero = cv::v_setzero_u8();
    for (int x = 0; x < vec16; x += 16) {
      const cv::v_uint8x16 f = cv::v_load(flags + x);
      cv::v_uint8x16 st = zero;
      for (const uint8_t flag : {kFlagCodeError, kFlagLowContrast, kFlagShadow, kFlagSaturated}) {
        const cv::v_uint8x16 has = (f & cv::v_setall_u8(flag)) != zero;
        st = cv::v_select(has, cv::v_setall_u8(kStatusOfFlags[flag]), st);
      }
      cv::v_store(status + x, st);
    }
    for (int x = vec16; x < width; ++x) status[x] = kStatusOfFlags[flags[x] & 15];
    std::copy(q, q + width, quality);
    const cv::v_float32x4 vnan = cv::v_setall_f32(nan);
    const int vec4 = width - width % 4;
    for (int x = 0; x < vec4; x += 4) {
      // v_load_expand_q reads its 4 bytes as one int: status rows of odd-width maps are not
      // 4-byte aligned (UB, found by UBSan), so the bytes go through an aligned copy first.
      uint32_t st4;
      std::memcpy(&st4, status + x, sizeof st4);
      const cv::v_uint32x4 st = cv::v_load_expand_q(reinterpret_cast<const uint8_t*>(&st4));
      const cv::v_float32x4 valid = cv::v_reinterpret_as_f32(st == cv::v_setzero_u32());
      cv::v_store(px + x, has_x ? cv::v_select(valid, cv::v_load(cx + x), vnan) : vnan);
      cv::v_store(py + x, has_y ? cv::v_select(valid, cv::v_load(cy + x), vnan) : vnan);
    }
    for (int x = vec4; x < width; ++x) {
      const bool valid = status[x] == 0;
      px[x] = (valid & has_x) ? cx[x] : nan;
      py[x] = (valid & has_y) ? cy[x] : nan;
    }
  }

  const PatternSpec& spec_;
  const std::vector<cv::Mat>& images_;
  Levels levels_;
  ProjectorMap* out_;
  std::vector<FrameInfo> frames_;
  std::vector<float> sin_, cos_;
  bool standard_phase_ = true;
  GrayReference reference_ = GrayReference::kAuto;
  std::vector<std::pair<int, int>>
      gray_[2][2];                // [axis][code][bit, MSB first]: (pattern, inverse or -1)
  std::vector<int> phase_[2][3];  // [axis][frequency][step]: frame index
  int white_ = -1, black_ = -1;
};

}  // namespace

float Atan2Cycles(float y, float x) { return Atan2CyclesInline(y, x); }

void DecodeOptions::Check() const {
  const char* p = "decode options: ";
  SLSHADOW_THROW_IF(!std::isfinite(shadow_threshold) || shadow_threshold < 0, p,
                    "shadow_threshold: must be finite and >= 0 (got ", shadow_threshold, ")");
  SLSHADOW_THROW_IF(!std::isfinite(contrast_threshold) || contrast_threshold < 0, p,
                    "contrast_threshold: must be finite and >= 0 (got ", contrast_threshold, ")");
  SLSHADOW_THROW_IF(saturation_level != -1 && (saturation_level < 1 || saturation_level > 65535), p,
                    "saturation_level: must be -1 (auto) or in [1, 65535] (got ", saturation_level,
                    ")");
  SLSHADOW_THROW_IF(full_scale != -1 && (full_scale < 1 || full_scale > 65535), p,
                    "full_scale: must be -1 (auto) or in [1, 65535] (got ", full_scale, ")");
  SLSHADOW_THROW_IF(!(unwrap_tolerance_cycles > 0 && unwrap_tolerance_cycles <= 0.5), p,
                    "unwrap_tolerance_cycles: must be in (0, 0.5] (got ", unwrap_tolerance_cycles,
                    ")");
}

nlohmann::json DecodeOptionsToJson(const DecodeOptions& o) {
  return {{"shadow_threshold", o.shadow_threshold},
          {"contrast_threshold", o.contrast_threshold},
          {"saturation_level", o.saturation_level},
          {"full_scale", o.full_scale},
          {"gray_edge_midpoint", o.gray_edge_midpoint},
          {"unwrap_tolerance_cycles", o.unwrap_tolerance_cycles},
          {"parallel", o.parallel}};
}

DecodeOptions DecodeOptionsFromConfig(const ConfigNode& node) {
  if (!node.IsObject()) node.Fail("expected a mapping of decode options");
  node.RejectUnknownKeys({"shadow_threshold", "contrast_threshold", "saturation_level",
                          "full_scale", "gray_edge_midpoint", "unwrap_tolerance_cycles",
                          "parallel"});
  DecodeOptions o;
  o.shadow_threshold = node.GetDouble("shadow_threshold", o.shadow_threshold);
  o.contrast_threshold = node.GetDouble("contrast_threshold", o.contrast_threshold);
  o.saturation_level = static_cast<int>(node.GetInt("saturation_level", o.saturation_level));
  o.full_scale = static_cast<int>(node.GetInt("full_scale", o.full_scale));
  o.gray_edge_midpoint = node.GetBool("gray_edge_midpoint", o.gray_edge_midpoint);
  o.unwrap_tolerance_cycles = node.GetDouble("unwrap_tolerance_cycles", o.unwrap_tolerance_cycles);
  o.parallel = node.GetBool("parallel", o.parallel);
  try {
    o.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(node.file(), node.path().empty() ? "" : ": ", node.path(), ": ", e.what());
  }
  return o;
}

ProjectorMap DecodePatterns(const PatternSpec& spec, const std::vector<cv::Mat>& camera_images,
                            const DecodeOptions& options) {
  spec.Check();
  options.Check();
  const int expected = spec.NumImages();
  SLSHADOW_THROW_IF(static_cast<int>(camera_images.size()) != expected, "decode: the ",
                    ToString(spec.kind), " spec has ", expected, " images per camera (got ",
                    camera_images.size(), ")");
  const int type = camera_images[0].type();
  SLSHADOW_THROW_IF(type != CV_8UC1 && type != CV_16UC1,
                    "decode: camera images must be CV_8UC1 or CV_16UC1 (got image 0 of type ", type,
                    ")");
  const cv::Size size = camera_images[0].size();
  SLSHADOW_THROW_IF(size.width < 1 || size.height < 1, "decode: image 0 is empty");
  for (size_t i = 1; i < camera_images.size(); ++i) {
    SLSHADOW_THROW_IF(camera_images[i].type() != type, "decode: image ", i, " has type ",
                      camera_images[i].type(), ", image 0 has type ", type);
    SLSHADOW_THROW_IF(camera_images[i].size() != size, "decode: image ", i, " is ",
                      camera_images[i].cols, "x", camera_images[i].rows, ", image 0 is ",
                      size.width, "x", size.height);
  }
  const int full_scale =
      options.full_scale > 0 ? options.full_scale : (type == CV_8UC1 ? 255 : 65535);
  const double scale = full_scale / 255.0;
  Levels levels;
  levels.shadow = static_cast<float>(options.shadow_threshold * scale);
  levels.contrast = static_cast<int32_t>(std::ceil(options.contrast_threshold * scale));
  levels.saturation = options.saturation_level > 0 ? options.saturation_level : full_scale;
  levels.unwrap_tol = static_cast<float>(options.unwrap_tolerance_cycles);
  levels.gray_edges = options.gray_edge_midpoint;

  // Every pixel of every map is written by the decoder: no need to fill them first.
  ProjectorMap map;
  map.proj_x.create(size, CV_32FC1);
  map.proj_y.create(size, CV_32FC1);
  map.status.create(size, CV_8UC1);
  map.quality.create(size, CV_32FC1);
  map.has_x = spec.code_x;
  map.has_y = spec.code_y;
  const Decoder decoder(spec, camera_images, levels, &map);
  const auto body = [&](const cv::Range& range) {
    if (type == CV_8UC1) {
      decoder.Rows<uint8_t>(range.start, range.end);
    } else {
      decoder.Rows<uint16_t>(range.start, range.end);
    }
  };
  if (options.parallel) {
    cv::parallel_for_(cv::Range(0, size.height), body, std::max(1.0, size.height / 8.0));
  } else {
    body(cv::Range(0, size.height));
  }
  return map;
}

}  // namespace slshadow
