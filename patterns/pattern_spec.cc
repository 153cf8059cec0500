#include "patterns/pattern_spec.h"

#include <cmath>
#include <map>
#include <numbers>

#include "core/config.h"
#include "core/enum_names.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/simulator_projector.h"

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

constexpr EnumName<PatternKind> kPatternKindNames[] = {
    {PatternKind::kGrayCode, "gray_code"},
    {PatternKind::kPhaseShift, "phase_shift"},
    {PatternKind::kMultiFrequency, "multi_frequency"}};

std::string ToString(PatternKind value) { return EnumToString(value, kPatternKindNames); }

PatternKind PatternKindFromString(const std::string& name) {
  return EnumFromString("pattern spec: kind", name, kPatternKindNames);
}

constexpr EnumName<GrayCodeVariant> kGrayCodeVariantNames[] = {
    {GrayCodeVariant::kComplementary, "complementary"},
    {GrayCodeVariant::kShifted, "shifted"},
    {GrayCodeVariant::kShiftedOnly, "shifted_only"}};

std::string ToString(GrayCodeVariant value) { return EnumToString(value, kGrayCodeVariantNames); }

GrayCodeVariant GrayCodeVariantFromString(const std::string& name) {
  return EnumFromString("pattern spec: gray_code", name, kGrayCodeVariantNames);
}

constexpr EnumName<GrayReference> kGrayReferenceNames[] = {
    {GrayReference::kAuto, "auto"},
    {GrayReference::kWhiteBlack, "white_black"},
    {GrayReference::kPhaseMean, "phase_mean"}};

std::string ToString(GrayReference value) { return EnumToString(value, kGrayReferenceNames); }

std::string FrameInfo::Name() const {
  const char* code_name = code == 1 ? "_shifted" : "";
  switch (role) {
    case FrameRole::kWhite:
      return "white";
    case FrameRole::kBlack:
      return "black";
    case FrameRole::kGrayBit:
      return internal::Concat("gray_", AxisName(axis), code_name, "_bit", bit);
    case FrameRole::kGrayBitInverse:
      return internal::Concat("gray_", AxisName(axis), code_name, "_bit", bit, "_inv");
    case FrameRole::kPhase:
      return internal::Concat("phase_", AxisName(axis), "_f", frequency, "_s", step);
  }
  return "unknown";
}

int PatternSpec::DerivedGrayBits(int axis) const {
  const int size = AxisSize(axis);
  switch (kind) {
    case PatternKind::kGrayCode:
      return BitsFor(size);
    case PatternKind::kPhaseShift: {
      // The largest code value (at the last pixel c = S - 1), plus one.
      const auto max_value = static_cast<int64_t>(
          GrayValue(gray_code == GrayCodeVariant::kComplementary ? 0 : 1, size - 1));
      return BitsFor(max_value + 1);
    }
    case PatternKind::kMultiFrequency:
      return 0;
  }
  return 0;
}

int PatternSpec::GrayBits(int axis) const {
  if (kind == PatternKind::kMultiFrequency) return 0;
  return gray_bits > 0 ? gray_bits : DerivedGrayBits(axis);
}

int PatternSpec::GrayCodes() const {
  if (kind == PatternKind::kMultiFrequency) return 0;
  return kind == PatternKind::kPhaseShift && gray_code == GrayCodeVariant::kShifted ? 2 : 1;
}

int PatternSpec::FirstGrayCode() const {
  return kind == PatternKind::kPhaseShift && gray_code == GrayCodeVariant::kShiftedOnly ? 1 : 0;
}

GrayReference PatternSpec::ResolvedGrayReference() const {
  if (gray_inverse || kind == PatternKind::kMultiFrequency) return GrayReference::kAuto;
  if (gray_reference != GrayReference::kAuto) return gray_reference;
  return HasWhiteBlack() ? GrayReference::kWhiteBlack : GrayReference::kPhaseMean;
}

double PatternSpec::PhaseStepAngle(int step) const {
  return phase_direction * (2 * std::numbers::pi * step / phase_steps) - phase_offset_rad;
}

uint32_t PatternSpec::GrayValue(int code, int c) const {
  if (kind == PatternKind::kGrayCode) return static_cast<uint32_t>(c);
  if (gray_code == GrayCodeVariant::kComplementary)
    return static_cast<uint32_t>(std::floor(2.0 * c / period_px));
  return static_cast<uint32_t>(std::floor(c / period_px + (code == 1 ? 0.5 : 0.0)));
}

std::vector<double> PatternSpec::PeriodsPx() const {
  switch (kind) {
    case PatternKind::kGrayCode:
      return {};
    case PatternKind::kPhaseShift:
      return {period_px};
    case PatternKind::kMultiFrequency:
      return periods_px;
  }
  return {};
}

std::vector<FrameInfo> PatternSpec::DefaultFrames() const {
  std::vector<FrameInfo> frames;
  const auto add_gray = [&](int axis) {
    for (int code = FirstGrayCode(); code < FirstGrayCode() + GrayCodes(); ++code) {
      for (int bit = GrayBits(axis) - 1; bit >= 0; --bit) {
        frames.push_back({FrameRole::kGrayBit, axis, bit, 0, 0, code});
        if (gray_inverse) frames.push_back({FrameRole::kGrayBitInverse, axis, bit, 0, 0, code});
      }
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
  if (HasWhiteBlack() && !opencv_order) {
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

std::vector<FrameInfo> PatternSpec::Frames() const {
  std::vector<FrameInfo> frames = DefaultFrames();
  if (frame_order.empty() || frame_order.size() != frames.size())
    return frames;  // Check() rejects the latter
  std::map<std::string, FrameInfo> by_name;
  for (const FrameInfo& f : frames) by_name[f.Name()] = f;
  std::vector<FrameInfo> ordered;
  for (const std::string& name : frame_order) {
    const auto it = by_name.find(name);
    if (it == by_name.end()) return frames;  // Check() rejects it
    ordered.push_back(it->second);
  }
  return ordered;
}

int PatternSpec::NumImages() const { return static_cast<int>(DefaultFrames().size()); }

namespace {
int FindRole(const std::vector<FrameInfo>& frames, FrameRole role) {
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].role == role) return static_cast<int>(i);
  }
  return -1;
}
}  // namespace

int PatternSpec::WhiteFrameIndex() const { return FindRole(Frames(), FrameRole::kWhite); }

int PatternSpec::BlackFrameIndex() const { return FindRole(Frames(), FrameRole::kBlack); }

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
  SLSHADOW_THROW_IF(!code_x && !code_y, p,
                    "code_x, code_y: at least one axis must be coded (got both false)");
  SLSHADOW_THROW_IF(intensity_min < 0 || intensity_min > 254, p,
                    "intensity_min: must be in [0, 254] (got ", intensity_min, ")");
  SLSHADOW_THROW_IF(intensity_max <= intensity_min || intensity_max > 255, p,
                    "intensity_max: must be in (intensity_min, 255] (got ", intensity_max, ")");
  if (opencv_order) {
    SLSHADOW_THROW_IF(kind != PatternKind::kGrayCode, p,
                      "opencv_order: only for kind gray_code (got kind ", ToString(kind), ")");
    SLSHADOW_THROW_IF(!code_x || !code_y, p,
                      "opencv_order: OpenCV's GrayCodePattern codes both axes (got code_x=", code_x,
                      ", code_y=", code_y, ")");
  }
  if (kind == PatternKind::kPhaseShift) {  // GrayBits() below divides by it
    SLSHADOW_THROW_IF(!std::isfinite(period_px) || period_px < 4 || period_px > 65536, p,
                      "period_px: must be in [4, 65536] projector pixels (got ", period_px, ")");
  }
  if (kind != PatternKind::kPhaseShift) {
    SLSHADOW_THROW_IF(gray_code != GrayCodeVariant::kComplementary, p,
                      "gray_code: a Gray-code variant is only for kind phase_shift (got ",
                      ToString(gray_code), ")");
    SLSHADOW_THROW_IF(white_black, p,
                      "white_black: only for kind phase_shift (gray_code always has them)");
  }
  if (kind == PatternKind::kMultiFrequency) {
    SLSHADOW_THROW_IF(!gray_inverse || gray_bits != 0 || gray_reference != GrayReference::kAuto, p,
                      "gray_inverse, gray_bits, gray_reference: multi_frequency has no Gray code");
  } else {
    SLSHADOW_THROW_IF(gray_bits < 0 || gray_bits > 16, p,
                      "gray_bits: must be 0 (derived) or in [1, 16] (got ", gray_bits, ")");
    for (int axis = 0; axis < 2; ++axis) {
      if (!Codes(axis) || gray_bits == 0) continue;
      SLSHADOW_THROW_IF(gray_bits < DerivedGrayBits(axis), p, "gray_bits: the ", AxisName(axis),
                        " axis needs ", DerivedGrayBits(axis), " bits (got ", gray_bits, ")");
    }
    for (int axis = 0; axis < 2; ++axis) {
      SLSHADOW_THROW_IF(Codes(axis) && GrayBits(axis) > 16, p, "the ", AxisName(axis),
                        " axis needs ", GrayBits(axis),
                        " Gray bits, more than the 16 the decoder reads");
    }
    if (gray_inverse) {
      SLSHADOW_THROW_IF(gray_reference != GrayReference::kAuto, p,
                        "gray_reference: only for bits without inverse (gray_inverse: false; got ",
                        ToString(gray_reference), ")");
    } else {
      SLSHADOW_THROW_IF(
          gray_reference == GrayReference::kPhaseMean && kind == PatternKind::kGrayCode, p,
          "gray_reference: gray_code has no phase frames (got phase_mean; use white_black)");
      SLSHADOW_THROW_IF(
          gray_reference == GrayReference::kWhiteBlack && !HasWhiteBlack(), p,
          "gray_reference: white_black needs white_black: true (the sequence has no white and "
          "black frames)");
    }
  }
  if (!frame_order.empty()) {
    const std::vector<FrameInfo> frames = DefaultFrames();
    std::map<std::string, int> count;
    for (const FrameInfo& f : frames) count[f.Name()] = 0;
    for (size_t i = 0; i < frame_order.size(); ++i) {
      const auto it = count.find(frame_order[i]);
      SLSHADOW_THROW_IF(it == count.end(), p, "frame_order[", i,
                        "]: no such frame in this spec (got \"", frame_order[i],
                        "\"; `slshadow patterns show` lists the frames)");
      SLSHADOW_THROW_IF(++it->second > 1, p, "frame_order[", i, "]: frame \"", frame_order[i],
                        "\" appears twice");
    }
    for (const FrameInfo& f : frames) {
      SLSHADOW_THROW_IF(count[f.Name()] == 0, p, "frame_order: frame \"", f.Name(),
                        "\" is missing (the spec has ", frames.size(), " frames, the order lists ",
                        frame_order.size(), ")");
    }
  }
  if (kind == PatternKind::kGrayCode) return;
  SLSHADOW_THROW_IF(
      !std::isfinite(phase_offset_rad) || std::fabs(phase_offset_rad) > 2 * std::numbers::pi + 1e-9,
      p, "phase_offset_rad: must be in [-2 pi, 2 pi] (got ", phase_offset_rad, ")");
  SLSHADOW_THROW_IF(phase_direction != 1 && phase_direction != -1, p,
                    "phase_direction: must be 1 or -1 (got ", phase_direction, ")");
  SLSHADOW_THROW_IF(phase_steps < 3 || phase_steps > 64, p, "phase_steps: must be in [3, 64] (got ",
                    phase_steps, ")");
  if (kind == PatternKind::kPhaseShift) {
    SLSHADOW_THROW_IF(!std::isfinite(period_px) || period_px < 4 || period_px > 65536, p,
                      "period_px: must be in [4, 65536] projector pixels (got ", period_px, ")");
    return;
  }
  SLSHADOW_THROW_IF(periods_px.size() != 3, p, "periods_px: needs exactly 3 periods (got ",
                    periods_px.size(), ")");
  for (size_t i = 0; i < 3; ++i) {
    SLSHADOW_THROW_IF(!std::isfinite(periods_px[i]) || periods_px[i] < 4, p, "periods_px[", i,
                      "]: must be >= 4 projector pixels (got ", periods_px[i], ")");
  }
  SLSHADOW_THROW_IF(!(periods_px[0] < periods_px[1] && periods_px[1] < periods_px[2]), p,
                    "periods_px: must be strictly increasing (got [", periods_px[0], ", ",
                    periods_px[1], ", ", periods_px[2], "])");
  const double p12 = BeatPeriod12Px(), p23 = BeatPeriod23Px();
  SLSHADOW_THROW_IF(
      !(p12 < p23), p,
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
  if (root.IsObject() && root.Has("patterns") && !root.Has("kind"))
    return PatternSpecFromConfig(root["patterns"]);
  if (!root.IsObject()) root.Fail("expected a pattern spec mapping");
  PatternSpec spec;
  const ConfigNode kind_node = root["kind"];
  spec.kind = EnumFromConfig(kind_node, kPatternKindNames);
  std::vector<std::string> allowed = {"kind",          "projector_width", "projector_height",
                                      "code_x",        "code_y",          "intensity_min",
                                      "intensity_max", "num_images"};
  allowed.push_back("frame_order");
  const std::vector<std::string> gray_keys = {"gray_inverse", "gray_reference", "gray_bits"};
  const std::vector<std::string> phase_keys = {"phase_steps", "phase_offset_rad",
                                               "phase_direction"};
  switch (spec.kind) {
    case PatternKind::kGrayCode:
      allowed.push_back("opencv_order");
      allowed.insert(allowed.end(), gray_keys.begin(), gray_keys.end());
      break;
    case PatternKind::kPhaseShift:
      allowed.insert(allowed.end(), phase_keys.begin(), phase_keys.end());
      allowed.insert(allowed.end(), gray_keys.begin(), gray_keys.end());
      allowed.push_back("period_px");
      allowed.push_back("gray_code");
      allowed.push_back("white_black");
      break;
    case PatternKind::kMultiFrequency:
      allowed.insert(allowed.end(), phase_keys.begin(), phase_keys.end());
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
  spec.gray_inverse = root.GetBool("gray_inverse", true);
  spec.gray_bits = get_int("gray_bits", 0);
  spec.white_black = root.GetBool("white_black", false);
  spec.phase_offset_rad = root.GetDouble("phase_offset_rad", 0.0);
  spec.phase_direction = get_int("phase_direction", 1);
  if (root.Has("gray_reference"))
    spec.gray_reference = EnumFromConfig(root["gray_reference"], kGrayReferenceNames);
  if (root.Has("gray_code"))
    spec.gray_code = EnumFromConfig(root["gray_code"], kGrayCodeVariantNames);
  if (root.Has("frame_order")) {
    const ConfigNode order = root["frame_order"];
    if (!order.IsArray())
      order.Fail("expected a list of frame names (as `slshadow patterns show` prints them)");
    for (size_t i = 0; i < order.size(); ++i) spec.frame_order.push_back(order.at(i).AsString());
  }
  try {
    spec.Check();
  } catch (const Error& e) {
    SLSHADOW_THROW(root.file(), ": ", root.path().empty() ? "" : root.path() + ": ", e.what());
  }
  if (root.Has("num_images") && root["num_images"].AsInt() != spec.NumImages()) {
    root["num_images"].Fail(
        internal::Concat("does not match the spec, which has ", spec.NumImages(), " images"));
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
  // The variant fields only when they differ from their defaults: a spec without them is written
  // as it was before they existed.
  if (!spec.gray_inverse) j["gray_inverse"] = false;
  if (spec.gray_reference != GrayReference::kAuto)
    j["gray_reference"] = ToString(spec.gray_reference);
  if (spec.gray_bits != 0) j["gray_bits"] = spec.gray_bits;
  if (spec.gray_code != GrayCodeVariant::kComplementary) j["gray_code"] = ToString(spec.gray_code);
  if (spec.white_black) j["white_black"] = true;
  if (spec.phase_offset_rad != 0) j["phase_offset_rad"] = spec.phase_offset_rad;
  if (spec.phase_direction != 1) j["phase_direction"] = spec.phase_direction;
  if (!spec.frame_order.empty()) j["frame_order"] = spec.frame_order;
  j["num_images"] = spec.NumImages();
  return j;
}

PatternSpec LoadPatternSpec(const std::filesystem::path& yaml_or_json) {
  return PatternSpecFromConfig(ConfigNode::LoadFile(yaml_or_json));
}

void CheckSimulatorProjector(const Rig& rig, const PatternSpec& spec, const std::string& spec_what,
                             const std::string& rig_what) {
  SLSHADOW_THROW_IF(!rig.projector, rig_what, ": rig has no projector: the simulator needs one");
  CheckProjectorSize(rig, spec, spec_what, rig_what);
}

void CheckProjectorSize(const Rig& rig, const PatternSpec& spec, const std::string& spec_what,
                        const std::string& rig_what) {
  if (!rig.projector) return;
  const CameraModel& m = rig.projector->model;
  SLSHADOW_THROW_IF(m.width != spec.projector_width || m.height != spec.projector_height, spec_what,
                    ": the pattern spec codes a ", spec.projector_width, "x", spec.projector_height,
                    " projector, but the rig's projector '", rig.projector->name, "' is ", m.width,
                    "x", m.height, " px (", rig_what, "): a spec or a rig of another projector?");
}

}  // namespace slshadow
