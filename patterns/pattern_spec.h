// PatternSpec: everything needed to generate the projector images of a structured-light scan and
// to decode camera images of them. It is stored verbatim in the ImageSet manifest ("patterns"),
// so a recorded capture decodes without any other configuration. The exact image formulas and the
// frame order are in docs/formats.md, "Pattern spec"; they are summarised here.
//
// Conventions: projector pixel (c, r) has its centre at x = c, y = r (OpenCV). A coded axis of
// size S (projector_width for x, projector_height for y) is decoded to a coordinate in
// [-0.5, S - 0.5] in projector pixels.
//
// Codecs (per coded axis, x first, then y):
//   kGrayCode:       binary-reflected Gray code g = c ^ (c >> 1) of the pixel index, n = ceil(log2 S)
//                    bits, MSB first, each bit as a pattern / inverse pair; plus an all-white and
//                    an all-black frame (first, or last in OpenCV order). Decodes to integers.
//   kPhaseShift:     N-step phase shift of period P px, I_n = A + B cos(2 pi x / P - 2 pi n / N),
//                    unwrapped by a complementary Gray code of the half-period index
//                    h = floor(2 x / P) (one bit more than the period index needs), as pairs.
//   kMultiFrequency: three N-step phase shifts of periods P1 < P2 < P3, unwrapped by the
//                    heterodyne (beat) method; the beat of all three must span the axis.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow {

class ConfigNode;

enum class PatternKind {
  kGrayCode,        // Gray code with inverse pairs + white + black
  kPhaseShift,      // N-step phase shift + complementary Gray code (inverse pairs)
  kMultiFrequency,  // three-frequency heterodyne phase shift
};
std::string ToString(PatternKind kind);            // "gray_code", "phase_shift", "multi_frequency"
PatternKind PatternKindFromString(const std::string& name);  // throws slshadow::Error

// What one projected frame is (for manifests, logs and capture sequencers).
enum class FrameRole { kWhite, kBlack, kGrayBit, kGrayBitInverse, kPhase };
struct FrameInfo {
  FrameRole role = FrameRole::kWhite;
  int axis = 0;       // 0: x (columns), 1: y (rows); unused for white / black
  int bit = 0;        // Gray-code bit (0 = least significant) for kGrayBit / kGrayBitInverse
  int frequency = 0;  // period index into PeriodsPx() for kPhase
  int step = 0;       // phase step n in 0..phase_steps-1 for kPhase
  std::string Name() const;  // e.g. "white", "gray_x_bit9", "gray_x_bit9_inv", "phase_y_f0_s2"
};

struct PatternSpec {
  PatternKind kind = PatternKind::kGrayCode;
  int projector_width = 0;   // projector pixels
  int projector_height = 0;  // projector pixels
  bool code_x = true;        // code projector columns (x)
  bool code_y = true;        // code projector rows (y)
  // Gray code only: the frame order of cv::structured_light::GrayCodePattern followed by white
  // and black (column pairs, row pairs, white, black). Requires code_x and code_y.
  bool opencv_order = false;
  int phase_steps = 4;               // N >= 3, phase codecs
  double period_px = 16;             // fringe period P in projector pixels (kPhaseShift), >= 4
  std::vector<double> periods_px;    // three periods P1 < P2 < P3 (kMultiFrequency)
  int intensity_min = 0;             // 8-bit projector level of "black" / fringe minimum
  int intensity_max = 255;           // 8-bit projector level of "white" / fringe maximum

  // Number of projector images (= camera images per camera) in the sequence.
  int NumImages() const;
  // Throws slshadow::Error naming the field and value of the first violated constraint.
  void Check() const;

  // Derived layout (valid after Check()).
  int AxisSize(int axis) const { return axis == 0 ? projector_width : projector_height; }
  bool Codes(int axis) const { return axis == 0 ? code_x : code_y; }
  // Gray-code bits per coded axis: ceil(log2 S) for kGrayCode, ceil(log2 ceil(2 S / P)) for
  // kPhaseShift (at least 1), 0 for kMultiFrequency.
  int GrayBits(int axis) const;
  // Periods in projector pixels: {period_px}, periods_px, or empty for kGrayCode.
  std::vector<double> PeriodsPx() const;
  // The role of every frame, in projection order (size NumImages()).
  std::vector<FrameInfo> Frames() const;
  // Index of the all-white / all-black frame, or -1 when the sequence has none.
  int WhiteFrameIndex() const;
  int BlackFrameIndex() const;
  // Heterodyne beat periods (kMultiFrequency): P12 = P1 P2 / (P2 - P1), P23 = P2 P3 / (P3 - P2),
  // P123 = P12 P23 / (P23 - P12), in projector pixels.
  double BeatPeriod12Px() const;
  double BeatPeriod23Px() const;
  double BeatPeriod123Px() const;
};

// Reads a spec from a config node: the spec's fields at the node itself, or under a member
// "patterns" (so an ImageSet manifest or a larger config can be passed). Unknown keys are
// rejected; the result is Check()ed. Field names are those of PatternSpecToJson.
PatternSpec PatternSpecFromConfig(const ConfigNode& node);
// The spec as JSON (the ImageSet manifest "patterns" value); includes "num_images" as a check.
nlohmann::json PatternSpecToJson(const PatternSpec& spec);
// Loads a .yaml/.yml/.json file holding a spec (or a manifest with a "patterns" member).
PatternSpec LoadPatternSpec(const std::filesystem::path& yaml_or_json);

}  // namespace slshadow
