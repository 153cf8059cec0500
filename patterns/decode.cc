// Row-parallel decoding. Each stripe of rows owns its scratch rows (allocated once per stripe);
// inner loops run over contiguous image rows with selects instead of branches so that GCC
// vectorises them.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <numbers>

#include "core/error.h"
#include "patterns/codec.h"

namespace slshadow {
namespace {

constexpr uint8_t kFlagSaturated = 1, kFlagShadow = 2, kFlagLowContrast = 4, kFlagCodeError = 8;

inline uint8_t StatusFromFlags(uint8_t flags) {
  if (flags & kFlagSaturated) return static_cast<uint8_t>(PixelStatus::kSaturated);
  if (flags & kFlagShadow) return static_cast<uint8_t>(PixelStatus::kShadow);
  if (flags & kFlagLowContrast) return static_cast<uint8_t>(PixelStatus::kLowContrast);
  if (flags & kFlagCodeError) return static_cast<uint8_t>(PixelStatus::kCodeError);
  return static_cast<uint8_t>(PixelStatus::kValid);
}

// atan2(y, x) / (2 pi) in [0, 1). Octant reduction, then Hastings' odd polynomial for atan on
// [0, 1] (max error 1e-5 rad).
inline float Atan2CyclesInline(float y, float x) {
  const float ax = std::fabs(x), ay = std::fabs(y);
  const float mx = std::max(ax, ay), mn = std::min(ax, ay);
  const float a = mn / std::max(mx, 1e-30f);
  const float s = a * a;
  float r = a * (0.9998660f + s * (-0.3302995f + s * (0.1801410f + s * (-0.0851330f + s * 0.0208351f))));
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
};

// Gray-code bits of one axis: `frames` holds 2 * nbits row pointers, MSB first, pattern then
// inverse. Accumulates the binary code, the two smallest bit contrasts and the maximum level.
template <typename T>
void GrayAxisRow(const T* const* frames, int nbits, int width, int32_t* __restrict code,
                 int32_t* __restrict min1, int32_t* __restrict min2, int32_t* __restrict maxv) {
  std::fill(code, code + width, 0);
  for (int b = 0; b < nbits; ++b) {
    const T* __restrict p = frames[2 * b];
    const T* __restrict q = frames[2 * b + 1];
    for (int x = 0; x < width; ++x) {
      const int32_t pv = p[x], qv = q[x];
      const int32_t d = pv - qv;
      const int32_t g = d > 0 ? 1 : 0;
      const int32_t c = d < 0 ? -d : d;
      const int32_t prev = code[x];
      code[x] = (prev << 1) | ((prev & 1) ^ g);  // binary bit = previous binary bit XOR Gray bit
      const int32_t m1 = min1[x];
      min2[x] = std::min(min2[x], std::max(m1, c));
      min1[x] = std::min(m1, c);
      maxv[x] = std::max(maxv[x], std::max(pv, qv));
    }
  }
}

// N-step phase of one frequency: wrapped phase in cycles [0, 1) and modulation B'.
template <typename T>
void PhaseRow(const T* const* frames, int steps, const float* sn, const float* cn, int width,
              float* __restrict sum_s, float* __restrict sum_c, float* __restrict cycles,
              float* __restrict modulation, int32_t* __restrict maxv) {
  std::fill(sum_s, sum_s + width, 0.0f);
  std::fill(sum_c, sum_c + width, 0.0f);
  for (int n = 0; n < steps; ++n) {
    const T* __restrict p = frames[n];
    const float s = sn[n], c = cn[n];
    for (int x = 0; x < width; ++x) {
      const int32_t v = p[x];
      const float fv = static_cast<float>(v);
      sum_s[x] += fv * s;
      sum_c[x] += fv * c;
      maxv[x] = std::max(maxv[x], v);
    }
  }
  const float scale = 2.0f / static_cast<float>(steps);
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
  std::vector<int32_t> code[2], min1, min2, maxv;
  std::vector<float> sum_s, sum_c, cycles[3], modulation[3], coord[2], quality;
  std::vector<uint8_t> flags;
  void Int(std::vector<int32_t>& v) { v.resize(w); }
  void Float(std::vector<float>& v) { v.resize(w); }
};

class Decoder {
 public:
  Decoder(const PatternSpec& spec, const std::vector<cv::Mat>& images, const Levels& levels, ProjectorMap* out)
      : spec_(spec), images_(images), levels_(levels), out_(out), frames_(spec.Frames()) {
    for (int n = 0; n < spec.phase_steps; ++n) {
      const double d = 2 * std::numbers::pi * n / spec.phase_steps;
      sin_.push_back(static_cast<float>(std::sin(d)));
      cos_.push_back(static_cast<float>(std::cos(d)));
    }
    // Frame indices per axis, by role.
    for (size_t i = 0; i < frames_.size(); ++i) {
      const FrameInfo& fr = frames_[i];
      const int idx = static_cast<int>(i);
      if (fr.role == FrameRole::kGrayBit || fr.role == FrameRole::kGrayBitInverse) gray_[fr.axis].push_back(idx);
      if (fr.role == FrameRole::kPhase) phase_[fr.axis][fr.frequency].push_back(idx);
    }
  }

  template <typename T>
  void Rows(int y0, int y1) const {
    const int width = out_->width();
    Scratch s(width);
    s.Int(s.min1);
    s.Int(s.min2);
    s.Int(s.maxv);
    s.Float(s.quality);
    s.flags.resize(s.w);
    for (int a = 0; a < 2; ++a) {
      s.Int(s.code[a]);
      s.Float(s.coord[a]);
    }
    s.Float(s.sum_s);
    s.Float(s.sum_c);
    for (int f = 0; f < 3; ++f) {
      s.Float(s.cycles[f]);
      s.Float(s.modulation[f]);
    }
    std::vector<const T*> rows(images_.size());
    for (int y = y0; y < y1; ++y) {
      for (size_t i = 0; i < images_.size(); ++i) rows[i] = images_[i].ptr<T>(y);
      std::fill(s.flags.begin(), s.flags.end(), uint8_t{0});
      switch (spec_.kind) {
        case PatternKind::kGrayCode: GrayCodeRow<T>(rows, s); break;
        case PatternKind::kPhaseShift: PhaseShiftRow<T>(rows, s); break;
        case PatternKind::kMultiFrequency: MultiFrequencyRow<T>(rows, s); break;
      }
      Write(y, s);
    }
  }

 private:
  template <typename T>
  void GatherRows(const std::vector<const T*>& rows, const std::vector<int>& idx, std::vector<const T*>& out) const {
    out.resize(idx.size());
    for (size_t i = 0; i < idx.size(); ++i) out[i] = rows[static_cast<size_t>(idx[i])];
  }

  template <typename T>
  void GrayCodeRow(const std::vector<const T*>& rows, Scratch& s) const {
    const int width = out_->width();
    const T* __restrict white = rows[static_cast<size_t>(spec_.WhiteFrameIndex())];
    const T* __restrict black = rows[static_cast<size_t>(spec_.BlackFrameIndex())];
    int32_t* __restrict maxv = s.maxv.data();
    int32_t* __restrict min1 = s.min1.data();
    int32_t* __restrict min2 = s.min2.data();
    uint8_t* __restrict flags = s.flags.data();
    for (int x = 0; x < width; ++x) {
      const int32_t wv = white[x], bv = black[x];
      maxv[x] = std::max(wv, bv);
      min1[x] = std::numeric_limits<int32_t>::max();
      min2[x] = std::numeric_limits<int32_t>::max();
      flags[x] = static_cast<float>(wv - bv) < levels_.shadow ? kFlagShadow : 0;
    }
    std::vector<const T*> frames;
    for (int a = 0; a < 2; ++a) {
      if (!spec_.Codes(a)) continue;
      GatherRows(rows, gray_[a], frames);
      GrayAxisRow<T>(frames.data(), spec_.GrayBits(a), width, s.code[a].data(), min1, min2, maxv);
      const int32_t size = spec_.AxisSize(a);
      const int32_t* __restrict code = s.code[a].data();
      float* __restrict coord = s.coord[a].data();
      for (int x = 0; x < width; ++x) {
        flags[x] |= code[x] >= size ? kFlagCodeError : 0;
        coord[x] = static_cast<float>(code[x]);
      }
    }
    float* __restrict quality = s.quality.data();
    for (int x = 0; x < width; ++x) {
      flags[x] |= (maxv[x] >= levels_.saturation ? kFlagSaturated : 0) |
                  (min1[x] < levels_.contrast ? kFlagLowContrast : 0);
      quality[x] = static_cast<float>(min1[x]);
    }
  }

  template <typename T>
  void PhaseShiftRow(const std::vector<const T*>& rows, Scratch& s) const {
    const int width = out_->width();
    int32_t* __restrict maxv = s.maxv.data();
    int32_t* __restrict min1 = s.min1.data();
    int32_t* __restrict min2 = s.min2.data();
    uint8_t* __restrict flags = s.flags.data();
    float* __restrict quality = s.quality.data();
    std::fill(s.maxv.begin(), s.maxv.end(), 0);
    std::fill(s.quality.begin(), s.quality.end(), std::numeric_limits<float>::max());
    std::vector<const T*> frames;
    for (int a = 0; a < 2; ++a) {
      if (!spec_.Codes(a)) continue;
      GatherRows(rows, phase_[a][0], frames);
      PhaseRow<T>(frames.data(), spec_.phase_steps, sin_.data(), cos_.data(), width, s.sum_s.data(),
                  s.sum_c.data(), s.cycles[0].data(), s.modulation[0].data(), maxv);
      std::fill(s.min1.begin(), s.min1.end(), std::numeric_limits<int32_t>::max());
      std::fill(s.min2.begin(), s.min2.end(), std::numeric_limits<int32_t>::max());
      GatherRows(rows, gray_[a], frames);
      const int nbits = spec_.GrayBits(a);
      GrayAxisRow<T>(frames.data(), nbits, width, s.code[a].data(), min1, min2, maxv);
      const int32_t* __restrict h = s.code[a].data();
      const float* __restrict f = s.cycles[0].data();
      const float* __restrict mod = s.modulation[0].data();
      float* __restrict coord = s.coord[a].data();
      const float period = static_cast<float>(spec_.period_px);
      const auto h_max = static_cast<int32_t>(std::floor(2.0 * (spec_.AxisSize(a) - 1) / spec_.period_px));
      const float lo = -1.0f, hi = static_cast<float>(spec_.AxisSize(a));
      const int32_t* __restrict contrast = nbits >= 2 ? min2 : min1;
      for (int x = 0; x < width; ++x) {
        // Complementary unwrapping: k1 = h >> 1 has its edges at the phase wraps, k2 = (h + 1) >> 1
        // half a period away; use k2 near the wraps and k1 in the middle of the period.
        const int32_t k1 = h[x] >> 1, k2 = (h[x] + 1) >> 1;
        const float fx = f[x];
        const int32_t k = fx < 0.25f ? k2 : (fx > 0.75f ? k2 - 1 : k1);
        const float xc = (static_cast<float>(k) + fx) * period;
        coord[x] = xc;
        const bool bad = h[x] > h_max || !(xc >= lo && xc <= hi);
        flags[x] |= (bad ? kFlagCodeError : 0) | (2.0f * mod[x] < levels_.shadow ? kFlagShadow : 0) |
                    (contrast[x] < levels_.contrast ? kFlagLowContrast : 0);
        quality[x] = std::min(quality[x], mod[x]);
      }
    }
    for (int x = 0; x < width; ++x) flags[x] |= maxv[x] >= levels_.saturation ? kFlagSaturated : 0;
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
        PhaseRow<T>(frames.data(), spec_.phase_steps, sin_.data(), cos_.data(), width, s.sum_s.data(),
                    s.sum_c.data(), s.cycles[fq].data(), s.modulation[fq].data(), maxv);
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
      for (int x = 0; x < width; ++x) {
        float f12 = f1[x] - f2[x];
        f12 -= std::floor(f12);
        float f23 = f2[x] - f3[x];
        f23 -= std::floor(f23);
        float f123 = f12 - f23;
        f123 -= std::floor(f123);
        // Absolute coordinate from the longest beat, centred on the axis.
        float t = f123 - centre / p123;
        t -= std::nearbyint(t);
        const float x123 = centre + p123 * t;
        const float u12 = x123 / p12 - f12;
        const float k12 = std::nearbyint(u12);
        const float x12 = p12 * (f12 + k12);
        const float u1 = x12 / p1 - f1[x];
        const float k1 = std::nearbyint(u1);
        const float xc = p1 * (f1[x] + k1);
        coord[x] = xc;
        const bool bad = std::fabs(u12 - k12) > tol || std::fabs(u1 - k1) > tol || !(xc >= lo && xc <= hi);
        const float mod = std::min(m1[x], std::min(m2[x], m3[x]));
        flags[x] |= (bad ? kFlagCodeError : 0) | (2.0f * mod < levels_.shadow ? kFlagShadow : 0);
        quality[x] = std::min(quality[x], mod);
      }
    }
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
    const bool has_x = spec_.code_x, has_y = spec_.code_y;
    for (int x = 0; x < width; ++x) {
      const uint8_t st = StatusFromFlags(s.flags[static_cast<size_t>(x)]);
      status[x] = st;
      quality[x] = s.quality[static_cast<size_t>(x)];
      const bool valid = st == 0;
      px[x] = valid && has_x ? cx[x] : nan;
      py[x] = valid && has_y ? cy[x] : nan;
    }
  }

  const PatternSpec& spec_;
  const std::vector<cv::Mat>& images_;
  Levels levels_;
  ProjectorMap* out_;
  std::vector<FrameInfo> frames_;
  std::vector<float> sin_, cos_;
  std::vector<int> gray_[2];
  std::vector<int> phase_[2][3];
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
                    "saturation_level: must be -1 (auto) or in [1, 65535] (got ", saturation_level, ")");
  SLSHADOW_THROW_IF(full_scale != -1 && (full_scale < 1 || full_scale > 65535), p,
                    "full_scale: must be -1 (auto) or in [1, 65535] (got ", full_scale, ")");
  SLSHADOW_THROW_IF(!(unwrap_tolerance_cycles > 0 && unwrap_tolerance_cycles <= 0.5), p,
                    "unwrap_tolerance_cycles: must be in (0, 0.5] (got ", unwrap_tolerance_cycles, ")");
}

ProjectorMap DecodePatterns(const PatternSpec& spec, const std::vector<cv::Mat>& camera_images,
                            const DecodeOptions& options) {
  spec.Check();
  options.Check();
  const int expected = spec.NumImages();
  SLSHADOW_THROW_IF(static_cast<int>(camera_images.size()) != expected, "decode: the ", ToString(spec.kind),
                    " spec has ", expected, " images per camera (got ", camera_images.size(), ")");
  const int type = camera_images[0].type();
  SLSHADOW_THROW_IF(type != CV_8UC1 && type != CV_16UC1,
                    "decode: camera images must be CV_8UC1 or CV_16UC1 (got image 0 of type ", type, ")");
  const cv::Size size = camera_images[0].size();
  SLSHADOW_THROW_IF(size.width < 1 || size.height < 1, "decode: image 0 is empty");
  for (size_t i = 1; i < camera_images.size(); ++i) {
    SLSHADOW_THROW_IF(camera_images[i].type() != type, "decode: image ", i, " has type ",
                      camera_images[i].type(), ", image 0 has type ", type);
    SLSHADOW_THROW_IF(camera_images[i].size() != size, "decode: image ", i, " is ", camera_images[i].cols, "x",
                      camera_images[i].rows, ", image 0 is ", size.width, "x", size.height);
  }
  const int full_scale = options.full_scale > 0 ? options.full_scale : (type == CV_8UC1 ? 255 : 65535);
  const double scale = full_scale / 255.0;
  Levels levels;
  levels.shadow = static_cast<float>(options.shadow_threshold * scale);
  levels.contrast = static_cast<int32_t>(std::ceil(options.contrast_threshold * scale));
  levels.saturation = options.saturation_level > 0 ? options.saturation_level : full_scale;
  levels.unwrap_tol = static_cast<float>(options.unwrap_tolerance_cycles);

  ProjectorMap map;
  map.Allocate(size.width, size.height, spec.code_x, spec.code_y);
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
