#include "workflows/multiview/virtual_project.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>

#include <opencv2/core.hpp>

#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/pose_io.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/testing/error_of.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::multiview {
namespace {
namespace fs = std::filesystem;
using testing::ErrorOf;
using testing::TempDir;

// Every image of every camera of the ImageSet at `dir`, in rig camera then pattern order.
std::vector<cv::Mat> AllImages(const fs::path& dir) {
  const ImageSet set = ImageSet::Open(dir);
  std::vector<cv::Mat> images;
  for (const std::string& camera : set.CameraNames()) {
    for (cv::Mat& m : set.LoadCamera(camera)) images.push_back(m);
  }
  return images;
}

bool Identical(const std::vector<cv::Mat>& a, const std::vector<cv::Mat>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (a[i].size() != b[i].size() || a[i].type() != b[i].type() ||
        cv::norm(a[i], b[i], cv::NORM_INF) != 0)
      return false;
  }
  return true;
}

class VirtualProjectTest : public ::testing::Test {
 protected:
  void SetUp() override {
    setup_ = testing::ScaledTurntableDemo(8);
    spec_ = testing::ScaledDemoPatterns(setup_.rig);
    views_ = FullTurnViews(3, 10);
  }
  TurntableSetup setup_;
  PatternSpec spec_;
  ViewsFile views_;
};

TEST_F(VirtualProjectTest, WritesOneImageSetPerViewWithItsPose) {
  const TempDir tmp;
  const fs::path project_dir = tmp / "project";
  const VirtualProjectSummary summary =
      SimulateProject(setup_.scene, setup_.rig, spec_, views_, project_dir);
  EXPECT_EQ(summary.rendered.size(), 3u);
  EXPECT_TRUE(summary.kept.empty());
  const ProjectManifest project = LoadProject(project_dir);
  ASSERT_EQ(project.views.size(), 3u);
  std::vector<std::vector<cv::Mat>> images;
  for (const ProjectView& v : project.views) {
    EXPECT_EQ(v.state, ViewState::kComplete);
    EXPECT_EQ(v.source, "virtual");
    const ImageSet set = ImageSet::Open(project_dir / v.Folder());
    EXPECT_EQ(set.PatternCount(), spec_.NumImages());
    EXPECT_EQ(set.records().front().source, ImageSource::kVirtual);
    const Rigid3d truth = PoseFromConfig(
        ConfigNode::FromJson(set.extra()["view"]["part_from_rig_true"], "manifest", "extra.view"));
    const Rigid3d expected = setup_.rig.turntable->RigFromTableTurn(*v.spec.table_deg).Inverse();
    EXPECT_NEAR((truth.translation - expected.translation).norm(), 0, 1e-9);
    EXPECT_NEAR(truth.rotation.angularDistance(expected.rotation), 0, 1e-12);
    EXPECT_EQ(set.extra()["view"]["table_deg"].get<double>(), *v.spec.table_deg);
    images.push_back(AllImages(project_dir / v.Folder()));
  }
  // The part turned: the views' images differ.
  EXPECT_FALSE(Identical(images[0], images[1]));
  EXPECT_FALSE(Identical(images[1], images[2]));
  // The project records how it was made.
  EXPECT_EQ(project.provenance["generator"], "slshadow simulate --views");
  EXPECT_EQ(project.provenance["scene"]["summary"], SceneToJson(setup_.scene));
  ASSERT_TRUE(project.rig.turntable.has_value());
}

TEST_F(VirtualProjectTest, ResumeRendersMissingViewsBitIdentically) {
  const TempDir tmp;
  const fs::path reference = tmp / "reference", resumed = tmp / "resumed";
  SimulateProject(setup_.scene, setup_.rig, spec_, views_, reference);

  // An interruption after the first view: the callback throws once view_00 is written.
  VirtualProjectOptions interrupt;
  interrupt.on_view = [](const std::string& name, size_t, bool) {
    if (name == "view_00") throw Error("interrupted");
  };
  EXPECT_THROW(SimulateProject(setup_.scene, setup_.rig, spec_, views_, resumed, interrupt), Error);
  {
    const ProjectManifest partial = LoadProject(resumed);
    EXPECT_EQ(partial.views[0].state, ViewState::kComplete);
    EXPECT_EQ(partial.views[1].state, ViewState::kMissing);
    EXPECT_EQ(partial.views[2].state, ViewState::kMissing);
    EXPECT_FALSE(fs::exists(resumed / "views/view_01"));
  }
  // Without --resume an existing project is refused; with it the missing views are rendered.
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, setup_.rig, spec_, views_, resumed);
            }).find("already holds a project (pass --resume"),
            std::string::npos);
  VirtualProjectOptions resume;
  resume.resume = true;
  const auto kept_time = fs::last_write_time(resumed / "views/view_00/manifest.json");
  VirtualProjectSummary s =
      SimulateProject(setup_.scene, setup_.rig, spec_, views_, resumed, resume);
  EXPECT_EQ(s.kept, std::vector<std::string>({"view_00"}));
  EXPECT_EQ(s.rendered, std::vector<std::string>({"view_01", "view_02"}));
  EXPECT_EQ(fs::last_write_time(resumed / "views/view_00/manifest.json"), kept_time)
      << "kept untouched";

  // A view folder lost afterwards is rendered again.
  fs::remove_all(resumed / "views/view_02");
  s = SimulateProject(setup_.scene, setup_.rig, spec_, views_, resumed, resume);
  EXPECT_EQ(s.rendered, std::vector<std::string>({"view_02"}));
  EXPECT_EQ(s.kept.size(), 2u);

  for (const char* v : {"view_00", "view_01", "view_02"}) {
    EXPECT_TRUE(Identical(AllImages(reference / "views" / v), AllImages(resumed / "views" / v)))
        << v;
  }
  const ProjectManifest done = LoadProject(resumed);
  for (const ProjectView& v : done.views) EXPECT_EQ(v.state, ViewState::kComplete) << v.spec.name;
}

TEST_F(VirtualProjectTest, ResumeRefusesOtherInputs) {
  const TempDir tmp;
  const fs::path dir = tmp / "project";
  SimulateProject(setup_.scene, setup_.rig, spec_, FullTurnViews(1), dir);
  VirtualProjectOptions resume;
  resume.resume = true;
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, setup_.rig, spec_, views_, dir, resume);
            }).find("project.json: views (their number) differs from this run's"),
            std::string::npos);
  Rig other = setup_.rig;
  other.turntable->angle_offset_deg = 1;
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, other, spec_, FullTurnViews(1), dir, resume);
            }).find("project.json: rig differs"),
            std::string::npos);
  Scene moved = setup_.scene;
  moved.objects[0].rig_from_object.translation.x() += 1;
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(moved, setup_.rig, spec_, FullTurnViews(1), dir, resume);
            }).find("provenance.scene differs"),
            std::string::npos);
  VirtualProjectOptions png = resume;
  png.encoding = ImageEncoding::kPng;
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, setup_.rig, spec_, FullTurnViews(1), dir, png);
            }).find("provenance.simulate differs"),
            std::string::npos);
  // A non-project folder, a rig without an axis, a hand-placed view without a pose.
  fs::create_directories(tmp / "other");
  std::ofstream(tmp / "other/file.txt") << "x";
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, setup_.rig, spec_, views_, tmp / "other");
            }).find("exists and is not a multi-view project"),
            std::string::npos);
  Rig no_axis = setup_.rig;
  no_axis.turntable.reset();
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, no_axis, spec_, views_, tmp / "p2");
            }).find("has no turntable axis"),
            std::string::npos);
  ViewsFile hand;
  hand.views.push_back(ViewSpec{"hand", std::nullopt, std::nullopt});
  EXPECT_NE(ErrorOf([&] {
              SimulateProject(setup_.scene, setup_.rig, spec_, hand, tmp / "p3");
            }).find("view 'hand': a view placed by hand needs part_from_rig_guess"),
            std::string::npos);
  EXPECT_FALSE(fs::exists(tmp / "p2"));
  EXPECT_FALSE(fs::exists(tmp / "p3"));
}

TEST_F(VirtualProjectTest, HandPlacedViewIsRenderedAtItsPose) {
  const TempDir tmp;
  ViewsFile views;
  ViewSpec table;
  table.name = "table";
  table.table_deg = 40;
  ViewSpec hand;
  hand.name = "hand";
  hand.part_from_rig_guess = setup_.rig.turntable->RigFromTableTurn(40).Inverse();
  views.views = {table, hand};
  SimulateProject(setup_.scene, setup_.rig, spec_, views, tmp / "p");
  // The same pose by hand and by the table: the same images.
  EXPECT_TRUE(Identical(AllImages(tmp / "p/views/table"), AllImages(tmp / "p/views/hand")));
}

// Sensor noise is drawn anew for every view, as a real camera draws it in every frame: two views
// at the same table angle render the same noise-free images (the oracle: the difference between
// their noisy images is the noise alone), but with noise on their noise fields are independent
// (correlation near 0; one seed for every view made them equal, correlation 1), and a seed
// reproduces every view bit for bit. Each view's provenance records its own seed.
TEST_F(VirtualProjectTest, EveryViewDrawsItsOwnSensorNoise) {
  const TempDir tmp;
  ViewsFile twice;
  for (const char* name : {"a", "b"}) {
    ViewSpec v;
    v.name = name;
    v.table_deg = 10.0;
    twice.views.push_back(v);
  }
  auto render = [&](const std::string& name, bool noise, uint64_t seed) {
    Scene scene = setup_.scene;
    scene.layers.noise_enabled = noise;
    scene.layers.seed = seed;
    SimulateProject(scene, setup_.rig, spec_, twice, tmp / name);
    return std::vector<std::vector<cv::Mat>>{AllImages(tmp / name / "views" / "a"),
                                             AllImages(tmp / name / "views" / "b")};
  };
  const auto clean = render("clean", false, 5);
  const auto noisy = render("noisy", true, 5);
  const auto again = render("again", true, 5);
  ASSERT_FALSE(clean[0].empty());
  EXPECT_TRUE(Identical(clean[0], clean[1])) << "noise-free, one pose: the same images";
  EXPECT_TRUE(Identical(noisy[0], again[0]) && Identical(noisy[1], again[1]))
      << "the same seed must reproduce every view bit for bit";
  // Each view's noise n_v = noisy_v - clean, over every image's pixels where either is non-zero.
  ASSERT_EQ(noisy[0].size(), clean[0].size());
  size_t images_differ = 0;
  double saa = 0, sbb = 0, sab = 0;
  for (size_t k = 0; k < clean[0].size(); ++k) {
    cv::Mat c, a, b;
    clean[0][k].convertTo(c, CV_64F);
    noisy[0][k].convertTo(a, CV_64F);
    noisy[1][k].convertTo(b, CV_64F);
    a -= c;
    b -= c;
    saa += a.dot(a);
    sbb += b.dot(b);
    sab += a.dot(b);
    if (cv::norm(noisy[0][k], noisy[1][k], cv::NORM_INF) != 0) ++images_differ;
  }
  ASSERT_GT(saa, 0) << "the noise is on";
  ASSERT_GT(sbb, 0);
  const double correlation = sab / std::sqrt(saa * sbb);
  std::printf("noise of view a and view b: correlation %.4f over %zu images\n", correlation,
              clean[0].size());
  EXPECT_EQ(images_differ, clean[0].size()) << "every image of view b must draw its own noise";
  // Measured 0.045: the ADC's rounding and its clipping at 0 DN, the same for both views at one
  // pixel, leave a small shared part; one noise field for both would give 1.
  EXPECT_LT(std::abs(correlation), 0.2);
  // The seeds, as recorded in each view's provenance.
  for (size_t i = 0; i < 2; ++i) {
    const nlohmann::json extra =
        ImageSet::Open(tmp / "noisy" / "views" / twice.views[i].name).extra();
    EXPECT_EQ(extra.at("provenance").at("scene").at("summary").at("layers").at("noise").at("seed"),
              VirtualViewNoiseSeed(5, i))
        << extra.dump();
  }
  EXPECT_NE(VirtualViewNoiseSeed(5, 0), VirtualViewNoiseSeed(5, 1));
  EXPECT_NE(VirtualViewNoiseSeed(5, 0), VirtualViewNoiseSeed(6, 0));
}

}  // namespace
}  // namespace slshadow::multiview
