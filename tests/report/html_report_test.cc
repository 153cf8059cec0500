// report/html_report.h in a real browser: Debian's chromium, headless, offline (tests/report/
// chromium.h). The page of a real comparison (compare::CompareAndReport with the page written by
// its before_commit hook) must load from file:// with no console error and no request but its
// own file and data: URIs, draw the cloud in the deviation colours, move when orbited, show the
// picked point's values, and show report.json's values in its tables.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <random>
#include <set>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "compare/report.h"
#include "core/file_util.h"
#include "core/point_cloud.h"
#include "plot/plot.h"
#include "report/html_report.h"
#include "tests/report/chromium.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::report {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::HeadlessChromium;

// A 100 x 100 mm square facing the origin at z = 500 mm (two triangles, normal -z).
TriangleMesh Square() {
  TriangleMesh m;
  m.vertices = {{-60, -60, 500}, {60, -60, 500}, {60, 60, 500}, {-60, 60, 500}};
  m.triangles = {{0, 2, 1}, {0, 3, 2}};
  return m;
}

// Points on the square in three bands of x: 0.2 mm in front (+), on it, 0.2 mm behind (-), each
// with 0.01 mm noise; u, v fields as a camera pixel (10 px per mm) and a `view` field (the band,
// as a multi-view merge labels each point with its view).
PointCloud BandedCloud(int n_side) {
  PointCloud c;
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.01);
  std::vector<float> u, v, view;
  for (int i = 0; i < n_side; ++i) {
    for (int j = 0; j < n_side; ++j) {
      const double x = -50 + 100.0 * (i + 0.5) / n_side, y = -50 + 100.0 * (j + 0.5) / n_side;
      const int band = x < -50 + 100.0 / 3 ? 0 : x < -50 + 200.0 / 3 ? 1 : 2;
      const double d = 0.2 * (band - 1) + noise(rng);
      view.push_back(static_cast<float>(band));
      c.points.emplace_back(x, y, 500 - d);
      u.push_back(static_cast<float>((x + 50) * 10));
      v.push_back(static_cast<float>((y + 50) * 10));
    }
  }
  c.SetScalar("u", u);
  c.SetScalar("v", v);
  c.SetScalar("view", view);
  return c;
}

fs::path Root() {
  const char* base = std::getenv("SLSHADOW_TEST_TMP");
  return fs::path(base ? base : fs::temp_directory_path().string()) / "report_html_test";
}

// One real comparison report with its page, shared by the tests of this file.
const fs::path& CompareFolder() {
  static const fs::path dir = [] {
    const fs::path root = Root();
    fs::remove_all(root);
    fs::create_directories(root);
    WriteMesh(root / "square.ply", Square());
    const compare::Reference ref =
        compare::ReferenceFromMesh(Square(), (root / "square.ply").string(), 20000);
    compare::CompareOptions options;
    options.threshold_mm = 0.1;
    compare::ReportOptions ro;
    ro.before_commit = HtmlWriter();
    compare::CompareAndReport(BandedCloud(160), ref, options, root / "cmp", ro, "banded.ply");
    return root / "cmp";
  }();
  return dir;
}

std::string Url(const fs::path& file) { return "file://" + fs::absolute(file).string(); }

// The canvas's box in page coordinates (the view is at the top of the page).
struct Box {
  double x, y, w, h;
};
Box CanvasBox(HeadlessChromium& b) {
  const json r = b.Evaluate(
      "(() => { const r = document.getElementById('gl').getBoundingClientRect();"
      " return [r.left + scrollX, r.top + scrollY, r.width, r.height]; })()");
  return {r[0].get<double>(), r[1].get<double>(), r[2].get<double>(), r[3].get<double>()};
}

cv::Mat Shot(HeadlessChromium& b, const Box& box) {
  const std::string png = b.Screenshot(box.x, box.y, box.w, box.h);
  const std::vector<uint8_t> bytes(png.begin(), png.end());
  cv::Mat bgr = cv::imdecode(bytes, cv::IMREAD_COLOR);
  EXPECT_FALSE(bgr.empty());
  return bgr;
}

// Share of the image's pixels whose colour is within 40 (RGB distance) of the heat map at
// t in [t0, t1).
double ColourShare(const cv::Mat& bgr, double t0, double t1) {
  std::vector<std::array<uint8_t, 3>> lut;
  for (int k = 0; k <= 100; ++k) lut.push_back(plot::HeatColor(k / 100.0));
  size_t hits = 0;
  for (int y = 0; y < bgr.rows; ++y) {
    for (int x = 0; x < bgr.cols; ++x) {
      const cv::Vec3b p = bgr.at<cv::Vec3b>(y, x);
      int best = -1, best_d = 40 * 40;
      for (int k = 0; k <= 100; ++k) {
        const int dr = p[2] - lut[static_cast<size_t>(k)][0],
                  dg = p[1] - lut[static_cast<size_t>(k)][1],
                  db = p[0] - lut[static_cast<size_t>(k)][2];
        const int d = dr * dr + dg * dg + db * db;
        if (d < best_d) {
          best_d = d;
          best = k;
        }
      }
      if (best >= 0 && best / 100.0 >= t0 && best / 100.0 < t1) ++hits;
    }
  }
  return static_cast<double>(hits) / static_cast<double>(bgr.total());
}

double DifferingShare(const cv::Mat& a, const cv::Mat& b) {
  size_t n = 0;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      const cv::Vec3b p = a.at<cv::Vec3b>(y, x), q = b.at<cv::Vec3b>(y, x);
      if (std::abs(p[0] - q[0]) + std::abs(p[1] - q[1]) + std::abs(p[2] - q[2]) > 30) ++n;
    }
  }
  return static_cast<double>(n) / static_cast<double>(a.total());
}

std::string Joined(const std::vector<std::string>& lines) {
  std::string out;
  for (const auto& l : lines) out += l + "\n";
  return out;
}

// Loads a page and waits for the view to be ready; the page must have caused no problem.
void Load(HeadlessChromium& b, const fs::path& page) {
  b.ClearRecords();
  b.Navigate(Url(page));
  ASSERT_TRUE(b.WaitUntil("window.slshadow && window.slshadow.ready")) << Joined(b.problems());
}

TEST(HtmlReport, ComparePageLoadsOfflineWithoutErrorsAndDrawsTheCloudInItsDeviationColours) {
  const fs::path page = CompareFolder() / "report.html";
  ASSERT_TRUE(fs::exists(page));
  HeadlessChromium b;
  Load(b, page);
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
  for (const auto& url : b.requests())
    EXPECT_TRUE(url.rfind("file:", 0) == 0 || url.rfind("data:", 0) == 0) << url;
  EXPECT_EQ(b.Evaluate("window.slshadow.active.n"), 160 * 160);
  const Box box = CanvasBox(b);
  ASSERT_GT(box.w, 300);
  const cv::Mat before = Shot(b, box);
  // Signed bands -0.2 / 0 / +0.2 mm over a range of about +-0.21 mm: a third of the points
  // each near blue, green and red; nothing cyan or yellow.
  const double blue = ColourShare(before, 0.0, 0.2), green = ColourShare(before, 0.4, 0.6),
               red = ColourShare(before, 0.8, 1.01),
               between = ColourShare(before, 0.2, 0.4) + ColourShare(before, 0.6, 0.8);
  const double cloud = blue + green + red;
  EXPECT_GT(cloud, 0.05) << "the canvas shows no cloud";
  EXPECT_NEAR(blue / cloud, 1.0 / 3, 0.08);
  EXPECT_NEAR(green / cloud, 1.0 / 3, 0.08);
  EXPECT_NEAR(red / cloud, 1.0 / 3, 0.08);
  EXPECT_LT(between, 0.1 * cloud);
  // Orbit with the mouse: the image changes; "reset view" brings the first one back.
  b.Drag(box.x + box.w / 2, box.y + box.h / 2, box.x + box.w / 2 + 150, box.y + box.h / 2 + 40);
  const cv::Mat orbited = Shot(b, box);
  EXPECT_GT(DifferingShare(before, orbited), 0.05);
  b.Evaluate("document.getElementById('reset').click()");
  EXPECT_LT(DifferingShare(before, Shot(b, box)), 0.01);
  // The reference mesh toggle draws the square over the view.
  b.Evaluate("document.querySelector('input[name=mesh]').click()");
  EXPECT_GT(DifferingShare(before, Shot(b, box)), 0.05);
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
}

TEST(HtmlReport, PickingAPointShowsItsDeviationCameraPixelAndViewFromThePly) {
  HeadlessChromium b;
  Load(b, CompareFolder() / "report.html");
  const Box box = CanvasBox(b);
  b.Click(box.x + box.w * 0.7, box.y + box.h * 0.5);
  const json pick = b.Evaluate("window.slshadow.lastPick");
  ASSERT_TRUE(pick.is_object()) << pick.dump();
  const std::string text = b.Evaluate("document.getElementById('pick').textContent");
  EXPECT_NE(text.find("camera pixel"), std::string::npos) << text;
  // The picked point is a point of compared.ply: its deviation and pixel are that point's.
  const PointCloud ply = ReadPly(CompareFolder() / "compared.ply");
  const Eigen::Vector3d p(pick["position_mm"][0].get<double>(),
                          pick["position_mm"][1].get<double>(),
                          pick["position_mm"][2].get<double>());
  size_t best = 0;
  for (size_t i = 1; i < ply.size(); ++i) {
    if ((ply.points[i] - p).squaredNorm() < (ply.points[best] - p).squaredNorm()) best = i;
  }
  EXPECT_LT((ply.points[best] - p).norm(), 0.01);
  const auto field = [&](const std::string& name) {
    for (const auto& s : ply.scalars) {
      if (s.name == name) return s.values[best];
    }
    return std::nanf("");
  };
  EXPECT_EQ(pick["deviation_mm"].get<float>(), field("deviation"));
  EXPECT_NEAR(pick["pixel"][0].get<double>(), field("u"), 1.0 / 16);  // kept in 1/8 px
  EXPECT_NEAR(pick["pixel"][1].get<double>(), field("v"), 1.0 / 16);
  EXPECT_EQ(pick["view"].get<double>(), field("view"));
  EXPECT_EQ(field("view"), 2) << "the click at 70 % of the width lands in the third band";
  EXPECT_NE(text.find("view: 2"), std::string::npos) << text;
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
}

TEST(HtmlReport, EveryTableCellShowsReportJsonsValue) {
  const json j = json::parse(ReadTextFile(CompareFolder() / "report.json"));
  HeadlessChromium b;
  Load(b, CompareFolder() / "report.html");
  const json cells = b.Evaluate(
      "Array.from(document.querySelectorAll('td[data-key]')).map(td => [td.dataset.src, "
      "td.dataset.key, td.dataset.value, td.textContent])");
  ASSERT_GT(cells.size(), 50u);
  std::set<std::string> keys;
  for (const auto& c : cells) {
    ASSERT_EQ(c[0], "report.json");
    const std::string key = c[1];
    keys.insert(key);
    const json expected = j.at(json::json_pointer(key));
    EXPECT_EQ(json::parse(c[2].get<std::string>()), expected) << key;
    if (expected.is_number_float()) {
      const double shown = std::stod(c[3].get<std::string>());
      EXPECT_NEAR(shown, expected.get<double>(), 1e-5 * std::abs(expected.get<double>()) + 1e-300)
          << key;
    } else if (expected.is_number_integer() || expected.is_number_unsigned()) {
      EXPECT_EQ(c[3].get<std::string>(), expected.dump()) << key;
    } else if (expected.is_string()) {
      EXPECT_EQ(c[3].get<std::string>(), expected.get<std::string>()) << key;
    }
  }
  for (const char* k : {"/c2m/rms_mm", "/c2m/p95_mm", "/c2m/signed_mean_mm", "/c2c/coverage",
                        "/registration/rmse_mm", "/inputs/cloud_points", "/time_s"})
    EXPECT_TRUE(keys.count(k)) << k;
}

// src / href / url() values outside scripts: anything but data: and in-page anchors is external.
std::vector<std::string> ExternalReferences(const std::string& html) {
  std::string outside;  // the page without the contents of <script> elements
  size_t pos = 0;
  for (;;) {
    const size_t open = html.find("<script", pos);
    outside += html.substr(pos, open == std::string::npos ? std::string::npos : open - pos);
    if (open == std::string::npos) break;
    const size_t close = html.find("</script>", open);
    if (close == std::string::npos) break;
    outside += html.substr(open, html.find('>', open) + 1 - open);
    pos = close;
  }
  std::vector<std::string> found;
  // Attributes of every tag, quoted or not (a hand-written scan: the data: URIs are megabytes).
  const auto lower = [](std::string t) {
    for (char& c : t) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return t;
  };
  const std::set<std::string> loading = {"src",  "href",       "action",     "poster",
                                         "data", "formaction", "background", "srcset"};
  for (size_t lt = outside.find('<'); lt != std::string::npos; lt = outside.find('<', lt + 1)) {
    size_t i = lt + 1;
    while (i < outside.size() && !std::isspace(static_cast<unsigned char>(outside[i])) &&
           outside[i] != '>')
      ++i;
    while (i < outside.size() && outside[i] != '>') {
      while (i < outside.size() && std::isspace(static_cast<unsigned char>(outside[i]))) ++i;
      const size_t name0 = i;
      while (i < outside.size() && outside[i] != '=' && outside[i] != '>' &&
             !std::isspace(static_cast<unsigned char>(outside[i])))
        ++i;
      const std::string name = lower(outside.substr(name0, i - name0));
      std::string value;
      if (i < outside.size() && outside[i] == '=') {
        ++i;
        if (outside[i] == '"' || outside[i] == '\'') {
          const char q = outside[i];
          const size_t end = outside.find(q, i + 1);
          value = outside.substr(i + 1, std::min<size_t>(end - i - 1, 64));
          i = end + 1;
        } else {
          const size_t v0 = i;
          while (i < outside.size() && outside[i] != '>' &&
                 !std::isspace(static_cast<unsigned char>(outside[i])))
            ++i;
          value = outside.substr(v0, std::min<size_t>(i - v0, 64));
        }
      } else if (name.empty()) {
        ++i;
      }
      if (loading.count(name) && value.rfind("data:", 0) != 0 && value.rfind("#", 0) != 0)
        found.push_back(name + "=" + value);
    }
  }
  const std::string low = lower(outside);
  for (const std::string key : {"url(", "@import"}) {
    for (size_t p = low.find(key); p != std::string::npos; p = low.find(key, p + 1)) {
      size_t v = p + key.size();
      while (v < low.size() &&
             (std::isspace(static_cast<unsigned char>(low[v])) || low[v] == '"' || low[v] == '\''))
        ++v;
      if (low.compare(v, 5, "data:") != 0) found.push_back(outside.substr(p, 40));
    }
  }
  for (const char* tag : {"<link", "<iframe", "<object", "<embed", "<base"}) {
    if (outside.find(tag) != std::string::npos) found.push_back(tag);
  }
  return found;
}

TEST(HtmlReport, ThePageReferencesNoExternalUrlAndKeepsThreeJsLicence) {
  const std::string html = ReadTextFile(CompareFolder() / "report.html");
  EXPECT_TRUE(ExternalReferences(html).empty()) << Joined(ExternalReferences(html));
  // Every <script> is inline (no src), the CSP forbids any other source, the licence is kept.
  EXPECT_EQ(html.find("<script src"), std::string::npos);
  EXPECT_NE(html.find("default-src 'none'"), std::string::npos);
  EXPECT_NE(html.find("Permission is hereby granted, free of charge"), std::string::npos);
  // The check finds what it looks for.
  EXPECT_EQ(ExternalReferences("<img src=\"https://example.com/a.png\"><div style=\"background:"
                               "url(http://x/y.png)\"></div><link rel=stylesheet href=a.css>")
                .size(),
            4u);
}

TEST(HtmlReport, TheBrowserHarnessCatchesConsoleErrorsAndFailedRequests) {
  testing::TempDir tmp;
  WriteTextFileAtomically(tmp / "bad.html",
                          "<!DOCTYPE html><html><body><img src=\"missing.png\"><script>"
                          "console.error('boom'); window.slshadow = {ready: true};</script>"
                          "</body></html>");
  HeadlessChromium b;
  Load(b, tmp / "bad.html");
  const std::string all = Joined(b.problems());
  EXPECT_NE(all.find("boom"), std::string::npos) << all;
  EXPECT_NE(all.find("missing.png"), std::string::npos) << all;
}

// A comparison folder whose compared.ply is replaced by `cloud` (the report.json stays).
fs::path FolderWithCloud(const testing::TempDir& tmp, const PointCloud& cloud) {
  const fs::path dir = tmp / "cmp";
  fs::create_directories(dir);
  for (const char* f : {"report.json", "histogram.png", "deviation_map.png"})
    fs::copy_file(CompareFolder() / f, dir / f);
  WritePly(dir / "compared.ply", cloud);
  WriteHtmlReport(dir);
  return dir;
}

TEST(HtmlReport, EmptyTinyAndNanCloudsGiveAPageThatSaysWhy) {
  testing::TempDir tmp;
  HeadlessChromium b;
  {  // 0 points
    PointCloud empty;
    empty.SetScalar("deviation", {});
    const fs::path dir = FolderWithCloud(tmp, empty);
    Load(b, dir / "report.html");
    EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
    EXPECT_EQ(b.Evaluate("document.getElementById('empty-msg').hidden"), false);
    const std::string why = b.Evaluate("document.getElementById('empty-msg').textContent");
    EXPECT_NE(why.find("has no points"), std::string::npos) << why;
    fs::remove_all(dir);
  }
  {  // every deviation NaN
    PointCloud nan_cloud = BandedCloud(20);
    nan_cloud.SetScalar("deviation", std::vector<float>(nan_cloud.size(), std::nanf("")));
    const fs::path dir = FolderWithCloud(tmp, nan_cloud);
    Load(b, dir / "report.html");
    EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
    const std::string why = b.Evaluate("document.getElementById('empty-msg').textContent");
    EXPECT_NE(why.find("none of the 400 points"), std::string::npos) << why;
    EXPECT_NE(why.find("NaN"), std::string::npos) << why;
    fs::remove_all(dir);
  }
  {  // 3 points, one of them NaN: two drawn, the page says one is left out
    PointCloud tiny;
    tiny.points = {{0, 0, 500}, {1, 0, 500}, {0, 1, 500}};
    tiny.SetScalar("deviation", {0.1f, std::nanf(""), -0.1f});
    const fs::path dir = FolderWithCloud(tmp, tiny);
    Load(b, dir / "report.html");
    EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
    EXPECT_EQ(b.Evaluate("window.slshadow.active.n"), 2);
    EXPECT_EQ(b.Evaluate("document.getElementById('empty-msg').hidden"), true);
    const std::string label = b.Evaluate("document.getElementById('cloud-layers').textContent");
    EXPECT_NE(label.find("2 of 3 points"), std::string::npos) << label;
    EXPECT_NE(label.find("1 without a finite deviation"), std::string::npos) << label;
  }
}

TEST(HtmlReport, TheDisplayBudgetDecimatesThePointsButNotTheTables) {
  testing::TempDir tmp;
  const fs::path dir = tmp / "cmp";
  fs::copy(CompareFolder(), dir);
  HtmlOptions options;
  options.max_points = 1000;
  const HtmlSummary s = WriteHtmlReport(dir, options);
  EXPECT_EQ(s.points_total, 160u * 160u);
  EXPECT_EQ(s.points_shown, 1000u);
  const size_t full = fs::file_size(CompareFolder() / "report.html");
  EXPECT_LT(s.bytes + 15u * 24600u, full);  // at least 15 bytes less per point left out
  HeadlessChromium b;
  Load(b, dir / "report.html");
  EXPECT_TRUE(b.problems().empty()) << Joined(b.problems());
  EXPECT_EQ(b.Evaluate("window.slshadow.active.n"), 1000);
  EXPECT_EQ(
      b.Evaluate("document.querySelector('td[data-key=\"/inputs/cloud_points\"]').textContent"),
      "25600");
}

TEST(HtmlReport, ANonResultFolderIsRefusedNamingIt) {
  testing::TempDir tmp;
  try {
    WriteHtmlReport(tmp.path());
    FAIL() << "no error";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("no report.json or demo.json"), std::string::npos)
        << e.what();
  }
  WriteTextFileAtomically(tmp / "report.json", "{\"format\": \"something-else\"}");
  try {
    WriteHtmlReport(tmp.path());
    FAIL() << "no error";
  } catch (const std::exception& e) {
    EXPECT_NE(std::string(e.what()).find("something-else"), std::string::npos) << e.what();
  }
  EXPECT_FALSE(fs::exists(tmp / "report.html"));
}

}  // namespace
}  // namespace slshadow::report
