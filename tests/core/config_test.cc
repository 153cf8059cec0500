#include "core/config.h"

#include <fstream>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

using testing::ErrorOf;

TEST(Config, YamlScalarsAreTyped) {
  const auto n = ConfigNode::ParseYaml(
      "a: 3\nb: 2.5\nc: true\nd: hello\ne: \"42\"\nf: [1, 2.0, -3e2]\ng: ~\n", "x.yaml");
  EXPECT_EQ(n["a"].AsInt(), 3);
  EXPECT_EQ(n["b"].AsDouble(), 2.5);
  EXPECT_TRUE(n["c"].AsBool());
  EXPECT_EQ(n["d"].AsString(), "hello");
  EXPECT_EQ(n["e"].AsString(), "42");  // quoted: a string
  EXPECT_EQ(n["f"].AsDoubles(3), (std::vector<double>{1, 2, -300}));
  EXPECT_FALSE(n.Has("g"));
  EXPECT_EQ(n.GetDouble("missing", 7.0), 7.0);
}

TEST(Config, ErrorsNameFileFieldAndValue) {
  const auto n = ConfigNode::ParseYaml("cams:\n  - fx: abc\n  - fx: .nan\n", "rig.yaml");
  EXPECT_EQ(ErrorOf([&] { n["cams"].at(0)["fx"].AsDouble(); }),
            "rig.yaml: cams[0].fx: expected a number (got \"abc\")");
  EXPECT_EQ(ErrorOf([&] { n["cams"].at(1)["fx"].AsDouble(); }),
            "rig.yaml: cams[1].fx: must be a finite number (got NaN)");
  EXPECT_EQ(ErrorOf([&] { n["cams"].at(0)["fy"]; }),
            "rig.yaml: cams[0].fy: missing required field");
  EXPECT_EQ(ErrorOf([&] { n["cams"].at(5); }).find("rig.yaml: cams: list has 2 entries"), 0u);
  EXPECT_NE(
      ErrorOf([&] { n.RejectUnknownKeys({"cameras"}); }).find("rig.yaml: cams: unknown field"),
      std::string::npos);
}

TEST(Config, FilesAndParseErrors) {
  testing::TempDir dir;
  EXPECT_NE(ErrorOf([&] { ConfigNode::LoadFile(dir / "none.yaml"); }).find("file not found"),
            std::string::npos);
  {
    std::ofstream f(dir / "bad.yaml");
    f << "a: [1, 2\nb: 3\n";
  }
  EXPECT_NE(ErrorOf([&] { ConfigNode::LoadFile(dir / "bad.yaml"); }).find("not valid YAML at line"),
            std::string::npos);
  {
    std::ofstream f(dir / "bad.json");
    f << "{\"a\": }";
  }
  EXPECT_NE(ErrorOf([&] { ConfigNode::LoadFile(dir / "bad.json"); }).find("not valid JSON"),
            std::string::npos);
}

TEST(Config, JsonToYamlRoundTripsExactly) {
  nlohmann::json j = {
      {"name", "x"},
      {"n", 3},
      {"v", {0.1, 1.0 / 3.0, -2.5e-17}},
      {"flag", false},
      {"nested", {{"s", "true"}, {"list", nlohmann::json::array({{{"a", 1}}, {{"a", 2}}})}}}};
  const auto back = ConfigNode::ParseYaml(JsonToYaml(j), "t.yaml").json();
  EXPECT_EQ(back, j) << JsonToYaml(j);
}

// Inputs the fuzzer found escaping as exceptions other than slshadow::Error (fuzz/regressions/):
// each is now one clear error naming the file.
TEST(Config, FuzzerFindingsAreClearErrors) {
  testing::TempDir dir;
  // Invalid UTF-8 in a YAML value: the error message used to throw nlohmann's type_error 316.
  EXPECT_EQ(ErrorOf([&] { ConfigNode::ParseYaml("name: ab\xff\n", "rig.yaml"); }),
            "rig.yaml: not valid UTF-8 text (byte 8)");
  EXPECT_EQ(ErrorOf([&] { ConfigNode::ParseYaml("n: \xc0\xaf\n", "rig.yaml"); }),  // overlong '/'
            "rig.yaml: not valid UTF-8 text (byte 3)");
  EXPECT_EQ(ConfigNode::ParseYaml("name: caf\xc3\xa9\n", "rig.yaml")["name"].AsString(),
            "caf\xc3\xa9");
  // A mapping key that is itself a list (yaml-cpp's TypedBadConversion).
  EXPECT_NE(ErrorOf([&] {
              ConfigNode::ParseYaml("? [a, b]\n: 1\n", "rig.yaml");
            }).find("rig.yaml: not valid YAML"),
            std::string::npos);
  // A JSON number beyond double range (nlohmann's out_of_range 406).
  { std::ofstream(dir / "m.json") << "{\"a\": 1e309}"; }
  EXPECT_NE(ErrorOf([&] {
              ConfigNode::LoadFile(dir / "m.json");
            }).find((dir / "m.json").string() + ": not valid JSON"),
            std::string::npos);
  // A value with a control character is shown JSON-escaped in one line.
  const auto n = ConfigNode::ParseYaml("fx: \"a\\nb\"\n", "rig.yaml");
  EXPECT_EQ(ErrorOf([&] { n["fx"].AsDouble(); }),
            "rig.yaml: fx: expected a number (got \"a\\nb\")");
}

}  // namespace
}  // namespace slshadow
