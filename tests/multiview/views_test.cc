#include "workflows/multiview/views.h"

#include <gtest/gtest.h>

#include <fstream>

#include "core/config.h"
#include "core/error.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::multiview {
namespace {

using testing::ErrorOf;
using testing::TempDir;

void WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream(path) << text;
}

Rig TurntableRig() {
  Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  TurntableAxis axis;
  axis.direction_in_rig = Eigen::Vector3d(0, 0, -1);  // exact: reading renormalises the direction
  axis.point_in_rig_mm = Eigen::Vector3d(0, 10, 545);
  rig.turntable = axis;
  return rig;
}

TEST(ViewsFileTest, RoundTripOfTableAndHandPlacedViews) {
  ViewsFile views = FullTurnViews(12, 5);
  ASSERT_EQ(views.views.size(), 12u);
  EXPECT_EQ(views.views[0].name, "view_00");
  EXPECT_EQ(views.views[11].name, "view_11");
  EXPECT_DOUBLE_EQ(*views.views[1].table_deg, 35.0);
  ViewSpec hand;
  hand.name = "flipped";
  hand.part_from_rig_guess =
      Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(3.0, Eigen::Vector3d(1, 2, 3).normalized())),
              Eigen::Vector3d(1.25, -2.5, 1090));
  views.views.push_back(hand);
  ViewSpec no_guess;
  no_guess.name = "free";
  views.views.push_back(no_guess);
  ViewSpec put_down;
  put_down.name = "put_down";
  put_down.placed_on_table = true;
  views.views.push_back(put_down);
  const TempDir tmp;
  for (const char* name : {"views.yaml", "views.json"}) {
    SaveViews(views, tmp / name);
    const ViewsFile back = LoadViews(tmp / name);
    ASSERT_EQ(back.views.size(), views.views.size()) << name;
    for (size_t i = 0; i < views.views.size(); ++i) {
      EXPECT_TRUE(back.views[i] == views.views[i]) << name << " view " << i;
    }
    EXPECT_EQ(ViewsToJson(back), ViewsToJson(views)) << name;
    EXPECT_TRUE(back.views.back().StandsOnTable()) << name;
    EXPECT_FALSE(back.views[views.views.size() - 2].StandsOnTable()) << name;
    EXPECT_TRUE(back.views[0].StandsOnTable()) << name;
  }
}

TEST(ViewsFileTest, DefaultNamesAndRotationVectors) {
  const TempDir tmp;
  WriteText(
      tmp / "v.yaml",
      "format: slshadow-views\nversion: 1\nviews:\n  - table_deg: 0\n  - table_deg: 90\n"
      "  - name: side\n    part_from_rig_guess: {rotation_rvec_rad: [0, 0, 1.5707963267948966], "
      "translation_mm: [0, 0, 500]}\n");
  const ViewsFile v = LoadViews(tmp / "v.yaml");
  ASSERT_EQ(v.views.size(), 3u);
  EXPECT_EQ(v.views[1].name, "view_01");
  EXPECT_FALSE(v.views[2].OnTable());
  EXPECT_NEAR((v.views[2].part_from_rig_guess->rotation * Eigen::Vector3d::UnitX() -
               Eigen::Vector3d::UnitY())
                  .norm(),
              0, 1e-12);
}

TEST(ViewsFileTest, BadInputsNameFileFieldAndValue) {
  const TempDir tmp;
  const auto error_of = [&](const std::string& text) {
    WriteText(tmp / "bad.yaml", text);
    return ErrorOf([&] { LoadViews(tmp / "bad.yaml"); });
  };
  const std::string f = (tmp / "bad.yaml").string();
  EXPECT_NE(error_of("views: []\n").find(f + ": views: at least one view is required"),
            std::string::npos);
  EXPECT_NE(error_of("views:\n  - {name: a, table_deg: 0}\n  - {name: a, table_deg: 10}\n")
                .find(f + ": views[1].name: duplicate view name"),
            std::string::npos);
  EXPECT_NE(
      error_of("views:\n  - {name: 'a/b', table_deg: 0}\n").find("views[0].name: only letters"),
      std::string::npos);
  EXPECT_NE(error_of("views:\n  - {name: '..', table_deg: 0}\n").find("views[0].name"),
            std::string::npos);
  EXPECT_NE(
      error_of("views:\n  - {table_deg: 4000}\n").find("views[0].table_deg: table angle beyond"),
      std::string::npos);
  EXPECT_NE(error_of("views:\n  - {table_deg: .nan}\n").find("views[0].table_deg"),
            std::string::npos);
  EXPECT_NE(error_of("views:\n  - {table_deg: 0, angle: 3}\n").find("angle"), std::string::npos);
  EXPECT_NE(error_of("views:\n  - {table_deg: 0, part_from_rig_guess: {translation_mm: [0, 0, 0], "
                     "rotation_quat_wxyz: [1, 0, 0, 0]}}\n")
                .find("views[0].part_from_rig_guess: a table view's pose follows"),
            std::string::npos);
  EXPECT_NE(error_of("views:\n  - {table_deg: 0, placed_on_table: true}\n")
                .find("views[0].placed_on_table: a table view stands on the table anyway"),
            std::string::npos);
  EXPECT_NE(error_of("views:\n  - {placed_on_table: 3}\n").find("placed_on_table"),
            std::string::npos);
  EXPECT_NE(error_of("views:\n  - {part_from_rig_guess: {translation_mm: [0, 0, 0], "
                     "rotation_quat_wxyz: [2, 0, 0, 0]}}\n")
                .find("rotation_quat_wxyz: quaternion must have unit norm"),
            std::string::npos);
  EXPECT_NE(error_of("format: slshadow-rig\nviews:\n  - {table_deg: 0}\n").find("format"),
            std::string::npos);
  EXPECT_NE(error_of("version: 2\nviews:\n  - {table_deg: 0}\n").find("version"),
            std::string::npos);
  EXPECT_THROW(FullTurnViews(0), Error);
}

TEST(ProjectManifestTest, RoundTripAndStateChecks) {
  const TempDir tmp;
  ViewsFile views = FullTurnViews(3);
  ViewSpec hand;
  hand.name = "hand";
  views.views.push_back(hand);
  ProjectManifest project =
      NewProject(TurntableRig(), {{"kind", "gray_code"}}, views, {{"generator", "test"}});
  project.views[1].state = ViewState::kComplete;
  project.views[1].source = "virtual";
  project.views[1].completed = "2026-12-01T00:00:00.000Z";
  // A device scan's record of how the view was taken: round-tripped untouched.
  project.views[1].provenance = {{"table_deg", 120.0},
                                 {"read_back_deg", 119.9995},
                                 {"turntable", "devices.yaml: turntable: grbl on /dev/ttyUSB0"}};
  // A complete view needs its ImageSet's manifest on disk.
  SaveProject(project, tmp.path());
  const std::string missing = ErrorOf([&] { LoadProject(tmp.path()); });
  EXPECT_NE(
      missing.find(
          "project.json: views[1].state: complete, but views/view_01/manifest.json is missing"),
      std::string::npos)
      << missing;
  std::filesystem::create_directories(tmp / "views/view_01");
  WriteText(tmp / "views/view_01/manifest.json", "{}");
  const ProjectManifest back = LoadProject(tmp.path());
  EXPECT_EQ(ProjectToJson(back), ProjectToJson(project));
  EXPECT_EQ(back.views[1].state, ViewState::kComplete);
  EXPECT_EQ(back.views[3].state, ViewState::kMissing);
  EXPECT_EQ(back.views[3].Folder(), std::filesystem::path("views/hand"));
  EXPECT_EQ(back.Find("hand"), &back.views[3]);
  ASSERT_TRUE(back.rig.turntable.has_value());
  EXPECT_EQ(back.views[1].provenance["read_back_deg"], 119.9995);
  EXPECT_TRUE(back.views[0].provenance.is_null());  // none written, none read
}

TEST(ProjectManifestTest, BadManifests) {
  const TempDir tmp;
  EXPECT_NE(ErrorOf([&] { LoadProject(tmp.path()); }).find("project.json: not found"),
            std::string::npos);
  ProjectManifest project =
      NewProject(TurntableRig(), {{"kind", "gray_code"}}, FullTurnViews(2), {});
  nlohmann::json j = ProjectToJson(project);
  const auto error_of = [&](const nlohmann::json& tree) {
    WriteText(tmp / "project.json", tree.dump());
    return ErrorOf([&] { LoadProject(tmp.path()); });
  };
  nlohmann::json bad = j;
  bad["views"][0]["state"] = "done";
  EXPECT_NE(error_of(bad).find("views[0].state: view state: unknown name (got 'done'"),
            std::string::npos);
  bad = j;
  bad["views"][1]["folder"] = "elsewhere";
  EXPECT_NE(error_of(bad).find("views[1].folder: must be views/<name>"), std::string::npos);
  bad = j;
  bad["format"] = "slshadow-imageset";
  EXPECT_NE(error_of(bad).find("format: expected \"slshadow-project\""), std::string::npos);
  bad = j;
  bad["rig"].erase("turntable");
  EXPECT_NE(error_of(bad).find("a table view, but the rig has no turntable axis"),
            std::string::npos);
  bad = j;
  bad["views"][0]["state"] = "complete";
  bad["views"][0]["source"] = "";
  EXPECT_NE(error_of(bad).find("views[0].source: a complete view needs its image source"),
            std::string::npos);
  bad = j;
  bad["views"][0].erase("name");
  EXPECT_NE(error_of(bad).find("views[0].name: missing"), std::string::npos);
  bad = j;
  bad["views"][0]["provenance"] = "by hand";
  EXPECT_NE(error_of(bad).find("views[0].provenance: must be a mapping"), std::string::npos)
      << error_of(bad);
  bad = j;
  bad["extra_key"] = 1;
  EXPECT_NE(error_of(bad).find("extra_key"), std::string::npos);
  EXPECT_EQ(error_of(j), "");
}

}  // namespace
}  // namespace slshadow::multiview
