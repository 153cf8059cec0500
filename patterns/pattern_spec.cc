#include "patterns/pattern_spec.h"

#include <cmath>

#include "core/config.h"
#include "core/error.h"

namespace slshadow {
namespace {

// Smallest n >= 1 with 2^n >= count.
int BitsFor(int64_t count) {
  int n = 1;
  while ((int64_t{1} << n) < count) ++n;
  return n;
}

const char* AxisName(int axis) { return axis == 0 ? "x" : "y"; }

}  // namespace

std::string ToString(PatternKind kind) {
  switch (kind) {
    case PatternKind::kGrayCode: return "gray_code";
    case PatternKind::kPhaseShift: return "phase_shift";
    case PatternKind::kMultiFrequency: return "multi_frequency";
  }
  return "unknown";
}

PatternKind PatternKindFromString(const std::string& name) {
  if (name == "gray_code") return PatternKind::kGrayCode;
  if (name == "phase_shift") return PatternKind::kPhaseShift;
  if (name == "multi_frequency") return PatternKind::kMultiFrequency;
  SLSHADOW_THROW("pattern spec: kind: unknown pattern kind (got \"", name,
                 "\"; known: gray_code, phase_shift, multi_frequency)");
}

std::string FrameInfo::Name() const {
  switch (role) {
    case FrameRole::kWhite: return "white";
    case FrameRole::kBlack: return "black";
    case FrameRole::kGrayBit: return internal::Concat("gray_", AxisName(axis), "_bit", bit);
    case FrameRole::kGrayBitInverse: return internal::Concat("gray_", AxisName(axis), "_bit", bit, "_inv");
    case FrameRole::kPhase: return internal::Concat("phase_", AxisName(axis), "_f", frequency, "_s", step);
  }
  return "unknown";
}

int PatternSpec::GrayBits(int axis) const {
  const int size = AxisSize(axis);
  switch (kind) {
    case PatternKind::kGrayCode: return BitsFor(size);
    case PatternKind::kPhaseShift: {
      // Half-period index h = floor(2 c / P) of the last pixel c = S - 1, plus one.
      const auto h_max = static_cast<int64_t>(std::floor(2.0 * (size - 1) / period_px));
      return BitsFor(h_max + 1);
    }
    case PatternKind::kMultiFrequency: return 0;
  }
  return 0;
}

std::vector<double> PatternSpec::PeriodsPx() const {
  switch (kind) {
    case PatternKind::kGrayCode: return {};
    case PatternKind::kPhaseShift: return {period_px};
    case PatternKind::kMultiFrequency: return periods_px;
  }
  return {};
}

std::vector<FrameInfo> PatternSpec::Frames() const {
  std::vector<FrameInfo> frames;
  const auto add_gray = [&](int axis) {
    for (int bit = GrayBits(axis) - 1; bit >= 0; --bit) {
      frames.push_back({FrameRole::kGrayBit, axis, bit, 0, 0});
      frames.push_back({FrameRole::kGrayBitInverse, axis, bit, 0, 0});
    }
  };
  const auto add_phase = [&](int axis) {
    const int num_frequencies = static_cast<int>(PeriodsPx().size());
    for (int f = 0; f < num_frequencies; ++f) {
      for (int n = 0; n < phase_steps; ++n) frames.push_back({FrameRole::kPhase, axis, 0, f, n});
    }
  };
  const FrameInfo white{FrameRole::kWhite, 0, 0, 0, 0};
  const FrameInfo black{FrameRole::kBlack, 0, 0, 0, 0};
  if (kind == PatternKind::kGrayCode && !opencv_order) {
    frames.push_back(white);
    frames.push_back(black);
  }
  for (int axis = 0; axis < 2; ++axis) {
    if (!Codes(axis)) continue;
    if (kind != PatternKind::kGrayCode) add_phase(axis);
    if (kind != PatternKind::kMultiFrequency) add_gray(axis);
  }
  if (kind == PatternKind::kGrayCode && opencv_order) {
    frames.push_back(white);
    frames.push_back(black);
  }
  return frames;
}

int PatternSpec::NumImages() const { return static_cast<int>(Frames().size()); }

int PatternSpec::WhiteFrameIndex() const {
  if (kind != PatternKind::kGrayCode) return -1;
  return opencv_order ? NumImages() - 2 : 0;
}

int PatternSpec::BlackFrameIndex() const {
  if (kind != PatternKind::kGrayCode) return -1;
  return opencv_order ? NumImages() - 1 : 1;
}

double PatternSpec::BeatPeriod12Px() const {
  return periods_px.at(0) * periods_px.at(1) / (periods_px.at(1) - periods_px.at(0));
}
double PatternSpec::BeatPeriod23Px() const {
  return periods_px.at(1) * periods_px.at(2) / (periods_px.at(2) - periods_px.at(1));
}
double PatternSpec::BeatPeriod123Px() const {
  const double p12 = BeatPeriod12Px(), p23 = BeatPeriod23Px();
  return p12 * p23 / (p23 - p12);
}

void PatternSpec::Check() const {
  const char* p = "pattern spec: ";
  SLSHADOW_THROW_IF(projector_width < 2 || projector_width > 65536, p,
                    "projector_width: must be in [2, 65536] (got ", projector_width, ")");
  SLSHADOW_THROW_IF(projector_height < 2 || projector_height > 65536, p,
                    "projector_height: must be in [2, 65536] (got ", projector_height, ")");
  SLSHADOW_THROW_IF(!code_x && !code_y, p, "code_x, code_y: at least one axis must be coded (got both false)");
  SLSHADOW_THROW_IF(intensity_min < 0 || intensity_min > 254, p,
                    "intensity_min: must be in [0, 254] (got ", intensity_min, ")");
  SLSHADOW_THROW_IF(intensity_max <= intensity_min || intensity_max > 255, p,
                    "intensity_max: must be in (intensity_min, 255] (got ", intensity_max, ")");
  if (opencv_order) {
    SLSHADOW_THROW_IF(kind != PatternKind::kGrayCode, p, "opencv_order: only for kind gray_code (got kind ",
                      ToString(kind), ")");
    SLSHADOW_THROW_IF(!code_x || !code_y, p,
                      "opencv_order: OpenCV's GrayCodePattern codes both axes (got code_x=", code_x,
                      ", code_y=", code_y, ")");
  }
  if (kind == PatternKind::kGrayCode) return;
  SLSHADOW_THROW_IF(phase_steps < 3 || phase_steps > 64, p, "phase_steps: must be in [3, 64] (got ",
                    phase_steps, ")");
  if (kind == PatternKind::kPhaseShift) {
    SLSHADOW_THROW_IF(!std::isfinite(period_px) || period_px < 4 || period_px > 65536, p,
                      "period_px: must be in [4, 65536] projector pixels (got ", period_px, ")");
    return;
  }
  SLSHADOW_THROW_IF(periods_px.size() != 3, p, "periods_px: needs exactly 3 periods (got ", periods_px.size(),
                    ")");
  for (size_t i = 0; i < 3; ++i) {
    SLSHADOW_THROW_IF(!std::isfinite(periods_px[i]) || periods_px[i] < 4, p, "periods_px[", i,
                      "]: must be >= 4 projector pixels (got ", periods_px[i], ")");
  }
  SLSHADOW_THROW_IF(!(periods_px[0] < periods_px[1] && periods_px[1] < periods_px[2]), p,
                    "periods_px: must be strictly increasing (got [", periods_px[0], ", ", periods_px[1], ", ",
                    periods_px[2], "])");
  const double p12 = BeatPeriod12Px(), p23 = BeatPeriod23Px();
  SLSHADOW_THROW_IF(!(p12 < p23), p,
                    "periods_px: the beat of P1, P2 must be shorter than that of P2, P3 (got P12 = ", p12,
                    ", P23 = ", p23, ")");
  const double p123 = BeatPeriod123Px();
  for (int axis = 0; axis < 2; ++axis) {
    SLSHADOW_THROW_IF(Codes(axis) && p123 < AxisSize(axis) * (1 - 1e-9), p,
                      "periods_px: the heterodyne beat period P123 must cover the ", AxisName(axis),
                      " axis of ", AxisSize(axis), " px (got P123 = ", p123, ")");
  }
}

PatternSpec PatternSpecFromConfig(const ConfigNode& root) {
  if (root.IsObject() && root.Has("patterns") && !root.Has("kind")) return PatternSpecFromConfig(root["patterns"]);
  if (!root.IsObject()) root.Fail("expected a pattern spec mapping");
  PatternSpec spec;
  const ConfigNode kind_node = root["kind"];
  try {
    spec.kind = PatternKindFromString(kind_node.AsString());
  } catch (const Error&) {
    kind_node.Fail("unknown pattern kind (known: gray_code, phase_shift, multi_frequency)");
  }
  std::vector<std::string> allowed = {"kind", "projector_width", "projector_height", "code_x", "code_y",
                                      "intensity_min", "intensity_max", "num_images"};
  switch (spec.kind) {
    case PatternKind::kGrayCode: allowed.push_back("opencv_order"); break;
    case PatternKind::kPhaseShift:
      allowed.push_back("phase_steps");
      allowed.push_back("period_px");
      break;
    case PatternKind::kMultiFrequency:
      allowed.push_back("phase_steps");
      allowed.push_back("periods_px");
      break;
  }
  root.RejectUnknownKeys(allowed);
  const auto get_int = [&](const char* key, int fallback) {
    const int64_t v = root.Has(key) ? root[key].AsInt() : fallback;
    if (v < -(int64_t{1} << 30) || v > (int64_t{1} << 30)) root[key].Fail("out of range");
    return static_cast<int>(v);
  };
  spec.projector_width = get_int("projector_width", 0);
  spec.projector_height = get_int("projector_height", 0);
  if (!root.Has("projector_width")) root["projector_width"];  // throws "missing"
  if (!root.Has("projector_height")) root["projector_height"];
  spec.code_x = root.GetBool("code_x", true);
  spec.code_y = root.GetBool("code_y", true);
  spec.opencv_order = root.GetBool("opencv_order", false);
  spec.phase_steps = get_int("phase_steps", spec.phase_steps);
  spec.period_px = root.GetDouble("period_px", spec.period_px);
  if (root.Has("periods_px")) spec.periods_px = root["periods_px"].AsDoubles();
  if (spec.kind == PatternKind::kMultiFrequency && !root.Has("periods_px")) root["periods_px"];
  spec.intensity_min = get_int("intensity_min", spec.intensity_min);
  spec.intensity_max = get_int("intensity_max", spec.intensity_max);
  try {
    spec.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(root.file(), ": ", root.path().empty() ? "" : root.path() + ": ", e.what());
  }
  if (root.Has("num_images") && root["num_images"].AsInt() != spec.NumImages()) {
    root["num_images"].Fail(internal::Concat("does not match the spec, which has ", spec.NumImages(), " images"));
  }
  return spec;
}

nlohmann::json PatternSpecToJson(const PatternSpec& spec) {
  nlohmann::json j;
  j["kind"] = ToString(spec.kind);
  j["projector_width"] = spec.projector_width;
  j["projector_height"] = spec.projector_height;
  j["code_x"] = spec.code_x;
  j["code_y"] = spec.code_y;
  if (spec.kind == PatternKind::kGrayCode) j["opencv_order"] = spec.opencv_order;
  if (spec.kind != PatternKind::kGrayCode) j["phase_steps"] = spec.phase_steps;
  if (spec.kind == PatternKind::kPhaseShift) j["period_px"] = spec.period_px;
  if (spec.kind == PatternKind::kMultiFrequency) j["periods_px"] = spec.periods_px;
  j["intensity_min"] = spec.intensity_min;
  j["intensity_max"] = spec.intensity_max;
  j["num_images"] = spec.NumImages();
  return j;
}

PatternSpec LoadPatternSpec(const std::filesystem::path& yaml_or_json) {
  return PatternSpecFromConfig(ConfigNode::LoadFile(yaml_or_json));
}

}  // namespace slshadow
