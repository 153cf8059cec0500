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
//   kGrayCode:       binary-reflected Gray code g = c ^ (c >> 1) of the pixel index, n = ceil(log2
//   S)
//                    bits, MSB first, each bit as a pattern / inverse pair; plus an all-white and
//                    an all-black frame (first, or last in OpenCV order). Decodes to integers.
//   kPhaseShift:     N-step phase shift of period P px, I_n = A + B cos(2 pi x / P - 2 pi n / N),
//                    unwrapped by a complementary Gray code of the half-period index
//                    h = floor(2 x / P) (one bit more than the period index needs), as pairs.
//   kMultiFrequency: three N-step phase shifts of periods P1 < P2 < P3, unwrapped by the
//                    heterodyne (beat) method; the beat of all three must span the axis.
//
// Variants of the sequences other scanners project (all default off, so a spec written before
// them reads and decodes as it did):
//   gray_inverse = false   each Gray bit is one frame, thresholded against a reference: the mean
//                          of the white and black frames, or of the axis' phase frames.
//   gray_code = kShifted   (phase shift) two Gray codes of the period index, k1 = floor(x / P)
//                          and k2 = floor(x / P + 1/2), instead of the complementary one.
//   gray_code = kShiftedOnly  (phase shift) the shifted code k2 alone.
//   gray_bits              more Gray bits than the axis needs (the extra high bits are 0).
//   white_black            (phase shift) an all-white and an all-black frame first.
//   phase_offset_rad, phase_direction: I_s = A + B cos(2 pi x / P + offset - d 2 pi s / N).
//   frame_order            any permutation of the frames, by FrameInfo::Name().
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace slshadow {

class ConfigNode;
struct Rig;

enum class PatternKind {
  kGrayCode,        // Gray code with inverse pairs + white + black
  kPhaseShift,      // N-step phase shift + complementary Gray code (inverse pairs)
  kMultiFrequency,  // three-frequency heterodyne phase shift
};
std::string ToString(PatternKind kind);  // "gray_code", "phase_shift", "multi_frequency"
PatternKind PatternKindFromString(const std::string& name);  // throws slshadow::Error

// What one projected frame is (for manifests, logs and capture sequencers).
enum class FrameRole { kWhite, kBlack, kGrayBit, kGrayBitInverse, kPhase };
struct FrameInfo {
  FrameRole role = FrameRole::kWhite;
  int axis = 0;       // 0: x (columns), 1: y (rows); unused for white / black
  int bit = 0;        // Gray-code bit (0 = least significant) for kGrayBit / kGrayBitInverse
  int frequency = 0;  // period index into PeriodsPx() for kPhase
  int step = 0;       // phase step n in 0..phase_steps-1 for kPhase
  int code = 0;  // Gray code 0, or 1 for the half-period shifted code (GrayCodeVariant::kShifted)
  // e.g. "white", "gray_x_bit9", "gray_x_bit9_inv", "gray_x_shifted_bit5", "phase_y_f0_s2".
  std::string Name() const;
};

// How a phase_shift spec's Gray code resolves the period index (docs/formats.md).
enum class GrayCodeVariant {
  kComplementary,  // one code of the half-period index h = floor(2 x / P): gray(floor(x / P)) plus
                   // one complementary bit whose edges lie half a period from the phase wraps
  kShifted,      // two codes: k1 = floor(x / P) and the half-period shifted k2 = floor(x / P + 1/2)
  kShiftedOnly,  // the shifted code k2 = floor(x / P + 1/2) alone (no frames of k1)
};
std::string ToString(GrayCodeVariant variant);  // "complementary", "shifted", "shifted_only"
// Throws slshadow::Error naming the value and the accepted names.
GrayCodeVariant GrayCodeVariantFromString(const std::string& name);

// What a Gray bit without an inverse frame is compared with.
enum class GrayReference {
  kAuto,        // gray_code: kWhiteBlack; phase_shift: kWhiteBlack if white_black, else kPhaseMean
  kWhiteBlack,  // (white + black) / 2 of the sequence's white and black frames
  kPhaseMean,   // the mean of the N phase frames of the same axis (phase_shift)
};
std::string ToString(GrayReference reference);  // "auto", "white_black", "phase_mean"

struct PatternSpec {
  PatternKind kind = PatternKind::kGrayCode;
  int projector_width = 0;   // projector pixels
  int projector_height = 0;  // projector pixels
  bool code_x = true;        // code projector columns (x)
  bool code_y = true;        // code projector rows (y)
  // Gray code only: the frame order of cv::structured_light::GrayCodePattern followed by white
  // and black (column pairs, row pairs, white, black). Requires code_x and code_y.
  bool opencv_order = false;
  int phase_steps = 4;             // N >= 3, phase codecs
  double period_px = 16;           // fringe period P in projector pixels (kPhaseShift), >= 4
  std::vector<double> periods_px;  // three periods P1 < P2 < P3 (kMultiFrequency)
  int intensity_min = 0;           // 8-bit projector level of "black" / fringe minimum
  int intensity_max = 255;         // 8-bit projector level of "white" / fringe maximum

  // Gray bits (gray_code, phase_shift).
  bool gray_inverse = true;  // each bit is followed by its inverse frame; false: bits stand alone
  GrayReference gray_reference = GrayReference::kAuto;  // threshold of bits without an inverse
  int gray_bits = 0;  // bits per coded axis; 0: derived (GrayBits); else >= derived, <= 16
  GrayCodeVariant gray_code = GrayCodeVariant::kComplementary;  // phase_shift only
  bool white_black = false;  // phase_shift: an all-white and an all-black frame open the sequence
  // Phase frames (phase codecs): I_s = A + B cos(2 pi x / P + phase_offset_rad
  //                                            - phase_direction 2 pi s / N).
  double phase_offset_rad = 0;  // |offset| <= 2 pi
  int phase_direction = 1;      // +1: fringes move towards +x as s grows; -1: towards -x
  // The projection order as frame names (FrameInfo::Name()), a permutation of the default order;
  // empty: the default order (docs/formats.md, "Frame order").
  std::vector<std::string> frame_order;

  // Number of projector images (= camera images per camera) in the sequence.
  int NumImages() const;
  // Throws slshadow::Error naming the field and value of the first violated constraint.
  void Check() const;

  // Derived layout (valid after Check()).
  int AxisSize(int axis) const { return axis == 0 ? projector_width : projector_height; }
  bool Codes(int axis) const { return axis == 0 ? code_x : code_y; }
  // Gray-code bits per coded axis (of each code): gray_bits when set, else derived: ceil(log2 S)
  // for kGrayCode; for kPhaseShift bits(floor(2 (S - 1) / P) + 1) (complementary) or
  // bits(floor((S - 1) / P + 1/2) + 1) (shifted, shifted_only); 0 for kMultiFrequency.
  int GrayBits(int axis) const;
  int DerivedGrayBits(int axis) const;  // the derived count alone
  // Number of Gray codes per axis: 2 for kShifted phase shift, else 1 (0 for kMultiFrequency).
  int GrayCodes() const;
  // FrameInfo::code of the first Gray code: 1 (the shifted code) for kShiftedOnly, else 0; the
  // codes are FirstGrayCode() .. FirstGrayCode() + GrayCodes() - 1.
  int FirstGrayCode() const;
  // The reference of bits without inverse (kAuto resolved); kAuto when bits have inverses.
  GrayReference ResolvedGrayReference() const;
  // Whether the sequence has an all-white and an all-black frame.
  bool HasWhiteBlack() const { return kind == PatternKind::kGrayCode || white_black; }
  // The phase shift of step s in radians: phase_direction 2 pi s / N - phase_offset_rad, so a
  // phase frame is A + B cos(2 pi x / P - PhaseStepAngle(s)).
  double PhaseStepAngle(int step) const;
  // The value a Gray code of `code` (0 or 1) carries at projector pixel c of an axis:
  // c (kGrayCode), floor(2 c / P) (complementary), floor(c / P) / floor(c / P + 1/2) (shifted;
  // shifted_only has code 1 only).
  uint32_t GrayValue(int code, int c) const;
  // Periods in projector pixels: {period_px}, periods_px, or empty for kGrayCode.
  std::vector<double> PeriodsPx() const;
  // The role of every frame, in projection order (size NumImages()): frame_order, or the default.
  std::vector<FrameInfo> Frames() const;
  std::vector<FrameInfo> DefaultFrames() const;
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

// The spec codes the rig's projector: throws slshadow::Error unless a rig with a projector has
// one of exactly spec.projector_width x spec.projector_height pixels, naming both sizes, e.g.
// "patterns.yaml: the pattern spec codes a 1920x1080 projector, but the rig's projector
// 'projector' is 1280x800 px (rig.yaml): a spec or a rig of another projector?". `spec_what`
// and `rig_what` name the sources (files). A rig without projector passes (stereo rigs). Called
// by capture::Capture and CapturePatternSequence, the multi-view scan and virtual project, and
// `slshadow simulate` (SimulateScan takes projector images and checks their size itself).
void CheckProjectorSize(const Rig& rig, const PatternSpec& spec, const std::string& spec_what,
                        const std::string& rig_what);

}  // namespace slshadow
