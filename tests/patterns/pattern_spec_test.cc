#include "patterns/pattern_spec.h"

#include <gtest/gtest.h>

#include <numbers>

#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

PatternSpec Gray(int w, int h) {
  PatternSpec s;
  s.kind = PatternKind::kGrayCode;
  s.projector_width = w;
  s.projector_height = h;
  return s;
}

TEST(PatternSpec, GrayCodeLayoutMatchesOpenCvOrder) {
  PatternSpec s = Gray(1024, 768);
  s.opencv_order = true;
  s.Check();
  EXPECT_EQ(s.GrayBits(0), 10);
  EXPECT_EQ(s.GrayBits(1), 10);
  ASSERT_EQ(s.NumImages(), 42);
  const auto frames = s.Frames();
  // Index 2m is column bit 9 - m, 2m + 1 its inverse; rows from 20; white 40, black 41.
  for (int m = 0; m < 10; ++m) {
    EXPECT_EQ(frames[2 * m].role, FrameRole::kGrayBit);
    EXPECT_EQ(frames[2 * m].axis, 0);
    EXPECT_EQ(frames[2 * m].bit, 9 - m);
    EXPECT_EQ(frames[2 * m + 1].role, FrameRole::kGrayBitInverse);
    EXPECT_EQ(frames[20 + 2 * m].axis, 1);
    EXPECT_EQ(frames[20 + 2 * m].bit, 9 - m);
  }
  EXPECT_EQ(s.WhiteFrameIndex(), 40);
  EXPECT_EQ(s.BlackFrameIndex(), 41);
  EXPECT_EQ(frames[40].Name(), "white");
  EXPECT_EQ(frames[1].Name(), "gray_x_bit9_inv");
}

TEST(PatternSpec, NativeOrderAndBitCounts) {
  PatternSpec s = Gray(1280, 800);
  s.code_y = false;
  EXPECT_EQ(s.GrayBits(0), 11);  // 1024 < 1280 <= 2048
  EXPECT_EQ(s.NumImages(), 2 + 22);
  EXPECT_EQ(s.WhiteFrameIndex(), 0);
  EXPECT_EQ(s.BlackFrameIndex(), 1);
  EXPECT_EQ(Gray(2, 2).GrayBits(0), 1);
  EXPECT_EQ(Gray(1025, 2).GrayBits(0), 11);

  PatternSpec p = s;
  p.kind = PatternKind::kPhaseShift;
  p.code_y = true;
  p.phase_steps = 4;
  p.period_px = 16;
  // x: h = floor(2 * 1279 / 16) = 159 -> 160 codes -> 8 bits; y: floor(2 * 799 / 16) = 99 -> 7
  // bits.
  EXPECT_EQ(p.GrayBits(0), 8);
  EXPECT_EQ(p.GrayBits(1), 7);
  EXPECT_EQ(p.NumImages(), (4 + 16) + (4 + 14));
  EXPECT_EQ(p.WhiteFrameIndex(), -1);
  EXPECT_EQ(p.Frames()[4].role, FrameRole::kGrayBit);
  EXPECT_EQ(p.Frames()[4].bit, 7);

  PatternSpec m = p;
  m.kind = PatternKind::kMultiFrequency;
  m.periods_px = {1280.0 / 70, 1280.0 / 64, 1280.0 / 59};
  m.Check();
  EXPECT_NEAR(m.BeatPeriod12Px(), 1280.0 / 6, 1e-9);
  EXPECT_NEAR(m.BeatPeriod23Px(), 1280.0 / 5, 1e-9);
  EXPECT_NEAR(m.BeatPeriod123Px(), 1280.0, 1e-6);
  EXPECT_EQ(m.NumImages(), 2 * 3 * 4);
  EXPECT_EQ(m.GrayBits(0), 0);
}

TEST(PatternSpec, CheckNamesTheField) {
  const auto message = [](const PatternSpec& s) {
    try {
      s.Check();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  PatternSpec s = Gray(1, 768);
  EXPECT_NE(message(s).find("projector_width"), std::string::npos);
  s = Gray(64, 64);
  s.code_x = s.code_y = false;
  EXPECT_NE(message(s).find("code_x"), std::string::npos);
  s = Gray(64, 64);
  s.code_y = false;
  s.opencv_order = true;
  EXPECT_NE(message(s).find("opencv_order"), std::string::npos);
  s = Gray(64, 64);
  s.intensity_max = s.intensity_min;
  EXPECT_NE(message(s).find("intensity_max"), std::string::npos);
  s = Gray(64, 64);
  s.kind = PatternKind::kPhaseShift;
  s.phase_steps = 2;
  EXPECT_NE(message(s).find("phase_steps"), std::string::npos);
  s.phase_steps = 3;
  s.period_px = 3;
  EXPECT_NE(message(s).find("period_px"), std::string::npos);
  s.kind = PatternKind::kMultiFrequency;
  s.periods_px = {16, 18};
  EXPECT_NE(message(s).find("periods_px"), std::string::npos);
  s.periods_px = {18, 16, 21};
  EXPECT_NE(message(s).find("increasing"), std::string::npos);
  s.projector_width = 1280;
  s.periods_px = {16, 18, 21};  // P12 = 144 > P23 = 126
  EXPECT_NE(message(s).find("beat of P1, P2"), std::string::npos);
  s.periods_px = {10, 12, 14};  // P12 = 60, P23 = 84, P123 = 210 < 1280
  EXPECT_NE(message(s).find("P123"), std::string::npos);
}

TEST(PatternSpec, JsonRoundTripForEveryKind) {
  PatternSpec g = Gray(1024, 768);
  g.opencv_order = true;
  PatternSpec p = Gray(1280, 800);
  p.kind = PatternKind::kPhaseShift;
  p.phase_steps = 5;
  p.period_px = 19.5;
  p.code_y = false;
  p.intensity_min = 10;
  p.intensity_max = 240;
  PatternSpec m = Gray(1280, 800);
  m.kind = PatternKind::kMultiFrequency;
  m.periods_px = {1280.0 / 70, 1280.0 / 64, 1280.0 / 59};
  for (const PatternSpec& s : {g, p, m}) {
    const nlohmann::json j = PatternSpecToJson(s);
    const PatternSpec back = PatternSpecFromConfig(ConfigNode::FromJson(j, "spec.json"));
    EXPECT_EQ(PatternSpecToJson(back), j);
    EXPECT_EQ(back.NumImages(), s.NumImages());
    EXPECT_EQ(j["num_images"], s.NumImages());
    // Nested under "patterns", as in an ImageSet manifest.
    nlohmann::json manifest;
    manifest["patterns"] = j;
    manifest["version"] = 1;
    EXPECT_EQ(
        PatternSpecToJson(PatternSpecFromConfig(ConfigNode::FromJson(manifest, "manifest.json"))),
        j);
  }
}

TEST(PatternSpec, ConfigErrorsNameFileFieldAndValue) {
  const auto message = [](const std::string& yaml) {
    try {
      PatternSpecFromConfig(ConfigNode::ParseYaml(yaml, "p.yaml"));
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(
      message("kind: stripes\nprojector_width: 64\nprojector_height: 64\n").find("p.yaml: kind"),
      std::string::npos);
  EXPECT_NE(message("kind: gray_code\nprojector_width: 64\n").find("projector_height: missing"),
            std::string::npos);
  EXPECT_NE(message("kind: gray_code\nprojector_width: 64\nprojector_height: 64\nperiod_px: 16\n")
                .find("period_px"),
            std::string::npos);
  EXPECT_NE(message("kind: phase_shift\nprojector_width: 64\nprojector_height: 64\nperiod_px: 2\n")
                .find("p.yaml: pattern spec: period_px"),
            std::string::npos);
  EXPECT_NE(message("kind: gray_code\nprojector_width: 64\nprojector_height: 64\nnum_images: 3\n")
                .find("num_images"),
            std::string::npos);
  EXPECT_EQ(message("kind: gray_code\nprojector_width: 64\nprojector_height: 64\nnum_images: 26\n"),
            "");
}

TEST(PatternSpec, ShippedExampleConfigsLoad) {
  const PatternSpec kamino =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml");
  EXPECT_EQ(kamino.kind, PatternKind::kGrayCode);
  EXPECT_TRUE(kamino.opencv_order);
  EXPECT_EQ(kamino.NumImages(), 42);
  const PatternSpec phase =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/graycode_phase.yaml");
  EXPECT_EQ(phase.kind, PatternKind::kPhaseShift);
  EXPECT_EQ(phase.projector_width, 1280);
  EXPECT_EQ(phase.projector_height, 800);
  EXPECT_TRUE(phase.code_x && phase.code_y);
  const PatternSpec multi =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/multi_frequency.yaml");
  EXPECT_EQ(multi.kind, PatternKind::kMultiFrequency);

  testing::TempDir dir;
  WriteTextFileAtomically(dir / "spec.json", PatternSpecToJson(phase).dump(2));
  EXPECT_EQ(PatternSpecToJson(LoadPatternSpec(dir / "spec.json")), PatternSpecToJson(phase));
}

// The sequence variants: frame layout, JSON round trip, and errors that name the field.
TEST(PatternSpec, VariantLayouts) {
  PatternSpec p = Gray(1280, 800);
  p.kind = PatternKind::kPhaseShift;
  p.period_px = 20;  // 64 periods across 1280 px
  p.phase_steps = 12;
  p.code_y = false;
  p.gray_inverse = false;
  p.Check();
  EXPECT_EQ(p.GrayBits(0), 7);  // complementary: half-period index 0..127
  EXPECT_EQ(p.NumImages(), 12 + 7);
  EXPECT_EQ(p.ResolvedGrayReference(), GrayReference::kPhaseMean);
  EXPECT_EQ(p.Frames()[12].Name(), "gray_x_bit6");
  p.white_black = true;
  EXPECT_EQ(p.ResolvedGrayReference(), GrayReference::kWhiteBlack);
  EXPECT_EQ(p.NumImages(), 2 + 12 + 7);
  EXPECT_EQ(p.WhiteFrameIndex(), 0);
  EXPECT_EQ(p.BlackFrameIndex(), 1);
  p.gray_reference = GrayReference::kPhaseMean;
  EXPECT_EQ(p.ResolvedGrayReference(), GrayReference::kPhaseMean);
  p.white_black = false;
  p.gray_reference = GrayReference::kAuto;
  p.gray_code = GrayCodeVariant::kShifted;
  EXPECT_EQ(p.GrayBits(0), 7);  // floor(1279 / 20 + 1/2) = 64 needs 7 bits
  EXPECT_EQ(p.GrayCodes(), 2);
  EXPECT_EQ(p.NumImages(), 12 + 2 * 7);
  EXPECT_EQ(p.Frames()[19].Name(), "gray_x_shifted_bit6");
  EXPECT_EQ(p.GrayValue(0, 29), 1u);
  EXPECT_EQ(p.GrayValue(1, 29), 1u);
  EXPECT_EQ(p.GrayValue(1, 30), 2u);
  p.gray_bits = 9;
  EXPECT_EQ(p.GrayBits(0), 9);
  EXPECT_EQ(p.NumImages(), 12 + 2 * 9);
  // Phase angle: A + B cos(2 pi x / P - angle), angle = d 2 pi s / N - offset.
  p.phase_offset_rad = -std::numbers::pi;
  p.phase_direction = -1;
  EXPECT_NEAR(p.PhaseStepAngle(3), -2 * std::numbers::pi * 3 / 12 + std::numbers::pi, 1e-12);
  // A frame order is a permutation; the white and black frames are found wherever they are.
  PatternSpec g = Gray(64, 32);
  for (const FrameInfo& f : g.Frames()) g.frame_order.insert(g.frame_order.begin(), f.Name());
  g.Check();
  EXPECT_EQ(g.WhiteFrameIndex(), g.NumImages() - 1);
  EXPECT_EQ(g.BlackFrameIndex(), g.NumImages() - 2);
  EXPECT_EQ(g.Frames().front().Name(), "gray_y_bit0_inv");
}

// The shifted code alone: one code per axis, its frames named as the shifted code of kShifted,
// its bits those of floor(x / P + 1/2); the 9-frame sequence of issue 31 (columns, 4 steps, 5 bits
// without inverse) is described, and reads back from JSON.
TEST(PatternSpec, ShiftedOnlyLayout) {
  PatternSpec p = Gray(400, 300);
  p.kind = PatternKind::kPhaseShift;
  p.period_px = 16;
  p.code_y = false;
  p.gray_inverse = false;
  p.gray_code = GrayCodeVariant::kShiftedOnly;
  p.Check();
  EXPECT_EQ(p.GrayCodes(), 1);
  EXPECT_EQ(p.FirstGrayCode(), 1);
  EXPECT_EQ(p.GrayBits(0), 5);  // floor(399 / 16 + 1/2) = 25 needs 5 bits
  EXPECT_EQ(p.NumImages(), 9);
  const std::vector<FrameInfo> frames = p.Frames();
  EXPECT_EQ(frames[4].Name(), "gray_x_shifted_bit4");
  EXPECT_EQ(frames[8].Name(), "gray_x_shifted_bit0");
  for (const FrameInfo& f : frames) {
    if (f.role != FrameRole::kPhase) {
      EXPECT_EQ(f.code, 1);
    }
  }
  EXPECT_EQ(p.GrayValue(1, 7), 0u);
  EXPECT_EQ(p.GrayValue(1, 8), 1u);
  // With inverse pairs and both axes: 2 x (4 + 2 n) frames; the y axis needs bits(19) = 5.
  p.code_y = true;
  p.gray_inverse = true;
  EXPECT_EQ(p.NumImages(), (4 + 2 * 5) + (4 + 2 * 5));
  const nlohmann::json j = PatternSpecToJson(p);
  EXPECT_EQ(j["gray_code"], "shifted_only");
  EXPECT_EQ(PatternSpecToJson(PatternSpecFromConfig(ConfigNode::FromJson(j, "spec.json"))), j);
  EXPECT_EQ(GrayCodeVariantFromString("shifted_only"), GrayCodeVariant::kShiftedOnly);
  EXPECT_EQ(ToString(GrayCodeVariant::kShiftedOnly), "shifted_only");
  try {
    PatternSpecFromConfig(ConfigNode::ParseYaml(
        "kind: phase_shift\nprojector_width: 64\nprojector_height: 64\ngray_code: shifted-only\n",
        "p.yaml"));
    ADD_FAILURE() << "an unknown variant was accepted";
  } catch (const Error& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("p.yaml: gray_code"), std::string::npos) << m;
    EXPECT_NE(m.find("unknown name (expected complementary, shifted or shifted_only) (got "
                     "\"shifted-only\")"),
              std::string::npos)
        << m;
  }
  // Like the other variants, only for phase_shift.
  PatternSpec g = Gray(64, 64);
  g.gray_code = GrayCodeVariant::kShiftedOnly;
  EXPECT_THROW(g.Check(), Error);
}

// The spec codes the rig's projector: the same size passes, another (smaller or larger) is refused
// naming both sizes and the sources; a rig without projector passes.
TEST(PatternSpec, CheckProjectorSizeNamesBothSizes) {
  Rig rig;
  rig.name = "wide";
  rig.cameras.push_back({"left", CameraModel(640, 480, 500, 500, 319.5, 239.5), Rigid3d()});
  rig.projector = RigDevice{"dlp", CameraModel(1280, 800, 1500, 1500, 639.5, 399.5), Rigid3d()};
  const PatternSpec code = Gray(1920, 1080);
  try {
    CheckProjectorSize(rig, code, "patterns.yaml", "rig.yaml");
    ADD_FAILURE() << "a 1920 px code was accepted for a 1280 px projector";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              "patterns.yaml: the pattern spec codes a 1920x1080 projector, but the rig's "
              "projector 'dlp' is 1280x800 px (rig.yaml): a spec or a rig of another projector?");
  }
  EXPECT_THROW(CheckProjectorSize(rig, Gray(1280, 720), "p", "r"), Error);
  EXPECT_NO_THROW(CheckProjectorSize(rig, Gray(1280, 800), "p", "r"));
  rig.projector.reset();
  EXPECT_NO_THROW(CheckProjectorSize(rig, code, "p", "r"));
}

TEST(PatternSpec, VariantErrorsNameTheField) {
  const auto message = [](const PatternSpec& s) {
    try {
      s.Check();
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  PatternSpec p = Gray(1280, 800);
  p.kind = PatternKind::kPhaseShift;
  p.period_px = 20;
  p.gray_bits = 5;
  EXPECT_NE(message(p).find("gray_bits: the x axis needs 7 bits (got 5)"), std::string::npos)
      << message(p);
  p.gray_bits = 17;
  EXPECT_NE(message(p).find("gray_bits"), std::string::npos);
  p.gray_bits = 0;
  p.gray_reference = GrayReference::kPhaseMean;
  EXPECT_NE(message(p).find("gray_reference: only for bits without inverse"), std::string::npos);
  p.gray_inverse = false;
  p.gray_reference = GrayReference::kWhiteBlack;
  EXPECT_NE(message(p).find("gray_reference: white_black needs white_black: true"),
            std::string::npos);
  p.gray_reference = GrayReference::kAuto;
  p.phase_direction = 0;
  EXPECT_NE(message(p).find("phase_direction"), std::string::npos);
  p.phase_direction = 1;
  p.phase_offset_rad = 7;
  EXPECT_NE(message(p).find("phase_offset_rad"), std::string::npos);
  p.phase_offset_rad = 0;
  p.frame_order = {"phase_x_f0_s0"};
  EXPECT_NE(message(p).find("frame_order: frame \"phase_x_f0_s1\" is missing"), std::string::npos)
      << message(p);
  p.frame_order = {"phase_x_f0_s9"};
  EXPECT_NE(message(p).find("frame_order[0]: no such frame in this spec (got \"phase_x_f0_s9\""),
            std::string::npos);
  p.frame_order = {"phase_x_f0_s0", "phase_x_f0_s0"};
  EXPECT_NE(message(p).find("frame_order[1]: frame \"phase_x_f0_s0\" appears twice"),
            std::string::npos);
  PatternSpec g = Gray(64, 64);
  g.gray_code = GrayCodeVariant::kShifted;
  EXPECT_NE(message(g).find("gray_code"), std::string::npos);
  g.gray_code = GrayCodeVariant::kComplementary;
  g.gray_inverse = false;
  g.gray_reference = GrayReference::kPhaseMean;
  EXPECT_NE(message(g).find("gray_code has no phase frames"), std::string::npos);
}

TEST(PatternSpec, VariantJsonRoundTripAndFrameOrderReadBack) {
  PatternSpec p = Gray(1280, 800);
  p.kind = PatternKind::kPhaseShift;
  p.period_px = 20;
  p.phase_steps = 12;
  p.gray_inverse = false;
  p.gray_bits = 8;
  p.white_black = true;
  p.gray_reference = GrayReference::kPhaseMean;
  p.gray_code = GrayCodeVariant::kShifted;
  p.phase_offset_rad = -std::numbers::pi;
  p.phase_direction = -1;
  // The order `slshadow patterns show` prints, reversed, read back.
  for (const FrameInfo& f : p.Frames()) p.frame_order.insert(p.frame_order.begin(), f.Name());
  const nlohmann::json j = PatternSpecToJson(p);
  EXPECT_EQ(j["gray_code"], "shifted");
  EXPECT_EQ(j["gray_reference"], "phase_mean");
  const PatternSpec back = PatternSpecFromConfig(ConfigNode::FromJson(j, "spec.json"));
  EXPECT_EQ(PatternSpecToJson(back), j);
  ASSERT_EQ(back.Frames().size(), p.Frames().size());
  for (size_t i = 0; i < p.Frames().size(); ++i)
    EXPECT_EQ(back.Frames()[i].Name(), p.Frames()[i].Name());
  // A default spec writes none of the variant fields.
  const nlohmann::json plain = PatternSpecToJson(Gray(64, 64));
  for (const char* key : {"gray_inverse", "gray_reference", "gray_bits", "gray_code", "white_black",
                          "phase_offset_rad", "phase_direction", "frame_order"}) {
    EXPECT_FALSE(plain.contains(key)) << key;
  }
  // Config errors name the file and field.
  const auto message = [](const std::string& yaml) {
    try {
      PatternSpecFromConfig(ConfigNode::ParseYaml(yaml, "p.yaml"));
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  const std::string base = "kind: phase_shift\nprojector_width: 64\nprojector_height: 64\n";
  EXPECT_NE(message(base + "gray_code: twisted\n").find("p.yaml: gray_code"), std::string::npos);
  EXPECT_NE(message(base + "gray_reference: median\n").find("p.yaml: gray_reference"),
            std::string::npos);
  EXPECT_NE(message(base + "frame_order: white\n").find("p.yaml: frame_order"), std::string::npos);
  EXPECT_NE(message("kind: multi_frequency\nprojector_width: 64\nprojector_height: 64\nperiods_px: "
                    "[20, 21.875, "
                    "23.728813559322035]\ngray_inverse: false\n")
                .find("gray_inverse"),
            std::string::npos);
}

TEST(PatternSpec, ShippedVariantExamplesLoad) {
  const PatternSpec stereo =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/phase12_gray7_no_inverse.yaml");
  EXPECT_EQ(stereo.NumImages(), 19);
  EXPECT_FALSE(stereo.gray_inverse);
  EXPECT_EQ(stereo.phase_direction, -1);
  const PatternSpec shifted =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/phase_shifted_gray.yaml");
  EXPECT_EQ(shifted.gray_code, GrayCodeVariant::kShifted);
  const PatternSpec shifted_only =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/phase_shifted_only.yaml");
  EXPECT_EQ(shifted_only.gray_code, GrayCodeVariant::kShiftedOnly);
  EXPECT_EQ(shifted_only.NumImages(), 4 + 7);
  const PatternSpec ordered =
      LoadPatternSpec(testing::SourceDir() / "config/patterns/phase_frame_order.yaml");
  EXPECT_FALSE(ordered.frame_order.empty());
  EXPECT_EQ(ordered.WhiteFrameIndex(), ordered.NumImages() - 2);
}

}  // namespace
}  // namespace slshadow
