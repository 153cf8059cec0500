// The pages of the real workflows in a real browser: `slshadow demo` (RunDemoJob) and
// `slshadow shadow` (RunShadow on the demo's scan against the demo scene) write report.html by
// default; each loads offline in headless Chromium with no console error or failed request, draws
// its layers, shows every JSON value it names exactly, and the demo's page is at most 25 MB.
#include <gtest/gtest.h>

#include "core/file_util.h"
#include "tests/multiview/multiview_test_util.h"
#include "tests/report/chromium.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/multiview_demo.h"
#include "workflows/pipeline/demo.h"
#include "workflows/twin/twin.h"

namespace slshadow::report {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::HeadlessChromium;

std::string Joined(const std::vector<std::string>& lines) {
  std::string out;
  for (const auto& l : lines) out += l + "\n";
  return out;
}

void Load(HeadlessChromium& b, const fs::path& page) {
  b.ClearRecords();
  b.Navigate("file://" + fs::absolute(page).string());
  ASSERT_TRUE(b.WaitUntil("window.slshadow && window.slshadow.ready")) << Joined(b.problems());
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
  for (const auto& url : b.requests())
    EXPECT_TRUE(url.rfind("file:", 0) == 0 || url.rfind("data:", 0) == 0) << url;
}

// Every value cell equals the value at its JSON pointer in its file (relative to the page).
size_t CheckCells(HeadlessChromium& b, const fs::path& dir) {
  const json cells = b.Evaluate(
      "Array.from(document.querySelectorAll('td[data-key]')).map(td => [td.dataset.src, "
      "td.dataset.key, td.dataset.value])");
  std::map<std::string, json> files;
  for (const auto& c : cells) {
    const std::string src = c[0];
    if (!files.count(src)) files[src] = json::parse(ReadTextFile(dir / src));
    EXPECT_EQ(json::parse(c[2].get<std::string>()),
              files[src].at(json::json_pointer(c[1].get<std::string>())))
        << src << " " << c[1];
  }
  return cells.size();
}

// Image of the canvas as PNG bytes.
std::string Canvas(HeadlessChromium& b) {
  const json r = b.Evaluate(
      "(() => { const r = document.getElementById('gl').getBoundingClientRect();"
      " return [r.left + scrollX, r.top + scrollY, r.width, r.height]; })()");
  return b.Screenshot(r[0], r[1], r[2], r[3]);
}

TEST(HtmlPages, DemoAndShadowPagesLoadOfflineShowTheirLayersAndTheirJsonValues) {
  testing::TempDir tmp;
  pipeline::DemoOptions demo;
  demo.out_dir = tmp / "demo";
  pipeline::RunDemoJob(demo);
  const fs::path demo_page = tmp / "demo" / "report.html";
  ASSERT_TRUE(fs::exists(demo_page));
  EXPECT_LE(fs::file_size(demo_page), 25'000'000u);
  HeadlessChromium b;
  {
    Load(b, demo_page);
    EXPECT_EQ(b.Evaluate("document.querySelectorAll('input[name=cloud]').length"), 2);
    EXPECT_EQ(b.Evaluate("window.slshadow.active.n"), 500000);
    EXPECT_GT(CheckCells(b, tmp / "demo"), 200u);
    for (const char* src : {"demo.json", "projector/report.json", "stereo/report.json"}) {
      EXPECT_EQ(b.Evaluate(std::string("document.querySelectorAll('td[data-src=\"") + src +
                           "\"]').length > 10"),
                true)
          << src;
    }
    // The other mode's layer and the ground truth mesh change the view.
    const std::string first = Canvas(b);
    b.Evaluate("document.querySelector('input[name=cloud][value=stereo]').click()");
    EXPECT_EQ(b.Evaluate("window.slshadow.active.meta.id"), "stereo");
    const std::string stereo = Canvas(b);
    EXPECT_NE(first, stereo);
    b.Evaluate("document.querySelector('input[name=mesh]').click()");
    EXPECT_NE(stereo, Canvas(b));
    EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
  }
  {
    twin::ShadowOptions options;
    options.rig_from_part = Rigid3d();  // the demo scene is in the rig frame
    const twin::ShadowPart part =
        twin::LoadShadowPart(testing::SourceDir() / "config" / "demo" / "scene.yaml");
    twin::RunShadow(tmp / "demo" / "scan", part, options, tmp / "shadow");
    Load(b, tmp / "shadow" / "report.html");
    EXPECT_EQ(b.Evaluate("document.querySelectorAll('input[name=cloud]').length"), 4);
    EXPECT_EQ(b.Evaluate("document.querySelectorAll('input[name=mesh]').length"), 1);
    EXPECT_EQ(b.Evaluate("document.querySelectorAll('#diagnosis img').length > 3"), true);
    EXPECT_EQ(b.Evaluate("document.querySelector('td[data-key=\"/diagnosis/verdict\"]') !== null"),
              true);
    EXPECT_GT(CheckCells(b, tmp / "shadow"), 200u);
    const std::string real = Canvas(b);
    b.Evaluate("document.querySelector('input[name=cloud][value=twin-projector]').click()");
    EXPECT_NE(real, Canvas(b));
    EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
  }
}

// A multi-view merge (the whole-part demo at 1/4 of the demo rig's resolution, 3 views): the
// merged cloud coloured by its deviation to the CAD, the painted CAD mesh, the views' table; a
// picked point names its view.
TEST(HtmlPages, AMergeModelPageNamesThePickedPointsView) {
  testing::TempDir tmp;
  const multiview::TurntableSetup setup = testing::ScaledTurntableDemo(4);
  multiview::MultiviewDemoOptions options;
  options.views = 3;
  options.out_dir = tmp / "mv";
  options.rig = setup.rig;
  options.scene = setup.scene;
  multiview::RunMultiviewDemo(options);
  const fs::path model = tmp / "mv" / "model";
  HeadlessChromium b;
  Load(b, model / "report.html");
  EXPECT_GT(b.Evaluate("window.slshadow.active.n").get<int>(), 1000);
  EXPECT_EQ(b.Evaluate("document.querySelectorAll('input[name=mesh]').length"), 1);
  EXPECT_GT(CheckCells(b, model), 50u);
  // Click until a point is hit (the part does not fill the view): its view is named.
  const json r = b.Evaluate(
      "(() => { const c = document.getElementById('gl').getBoundingClientRect();"
      " return [c.left + scrollX, c.top + scrollY, c.width, c.height]; })()");
  const json names = json::parse(ReadTextFile(model / "report.json"))["views"];
  bool hit = false;
  for (int k = 0; k < 25 && !hit; ++k) {
    b.Click(r[0].get<double>() + r[2].get<double>() * (0.3 + 0.1 * (k % 5)),
            r[1].get<double>() + r[3].get<double>() * (0.3 + 0.1 * (k / 5)));
    const json pick = b.Evaluate("window.slshadow.lastPick");
    if (!pick.is_object()) continue;
    hit = true;
    const int view = pick["view"].get<int>();
    ASSERT_LT(static_cast<size_t>(view), names.size());
    const std::string text = b.Evaluate("document.getElementById('pick').textContent");
    EXPECT_NE(text.find("view: " + names[static_cast<size_t>(view)]["name"].get<std::string>()),
              std::string::npos)
        << text;
  }
  EXPECT_TRUE(hit);
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
}

}  // namespace
}  // namespace slshadow::report
