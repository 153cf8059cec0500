#include "report/html_report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <Eigen/Geometry>

#include "core/error.h"
#include "core/file_util.h"
#include "report/internal/html_page.h"

namespace slshadow::report {
namespace fs = std::filesystem;
using nlohmann::json;
using namespace internal;  // NOLINT(google-build-using-namespace): the page's own pieces

void HtmlOptions::Check() const {
  SLSHADOW_THROW_IF(max_points < 1, "html report: max_points must be >= 1 (got ", max_points, ")");
}

std::string HtmlSummary::Brief() const {
  char buf[256];
  std::snprintf(buf, sizeof(buf), "%s: %.1f MB, %zu of %zu points in the 3D view",
                path.filename().string().c_str(), static_cast<double>(bytes) / 1e6, points_shown,
                points_total);
  return buf;
}

namespace {

json ReadJson(const fs::path& file) {
  try {
    return json::parse(ReadTextFile(file));
  } catch (const json::exception& e) {
    SLSHADOW_THROW(file.string(), ": not valid JSON: ", e.what());
  }
}

// What a page is made of before it is rendered.
struct Page {
  std::string kind, title, subtitle;
  std::vector<std::string> notes;
  std::vector<CloudLayer> clouds;
  std::vector<MeshLayer> meshes;
  std::string view_note;  // under the 3D view (e.g. which frame it is)
  std::string sections;   // HTML after the 3D view
};

// A cloud to pack: its file and how to colour it.
struct CloudSpec {
  fs::path file;
  std::string source, id, name, field;
  ColourScale scale;
};

// Shares `budget` over the clouds: equal shares, what a small cloud leaves given to the others.
void PackClouds(const std::vector<CloudSpec>& specs, size_t budget, Page* page) {
  std::vector<size_t> counts, order(specs.size());
  for (const auto& s : specs) counts.push_back(PlyVertexCount(s.file));
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::sort(order.begin(), order.end(), [&](size_t a, size_t b) { return counts[a] < counts[b]; });
  std::vector<size_t> share(specs.size());
  size_t left = budget;
  for (size_t k = 0; k < order.size(); ++k) {
    const size_t i = order[k];
    share[i] = std::min(counts[i], left / (order.size() - k));
    left -= share[i];
  }
  for (size_t i = 0; i < specs.size(); ++i) {
    const auto& s = specs[i];
    page->clouds.push_back(
        PackCloud(s.file, s.source, s.id, s.name, s.field, s.scale, std::max<size_t>(share[i], 1)));
  }
}

void AddMesh(const fs::path& file, const std::string& source, const std::string& id,
             const std::string& name, const HtmlOptions& options, Page* page,
             const Eigen::Isometry3d* transform = nullptr) {
  std::error_code ec;
  if (file.empty() || !fs::exists(file, ec)) {
    page->notes.push_back(name + ": " + (source.empty() ? std::string("no file") : source) +
                          " not found, the layer is left out");
    return;
  }
  const std::string ext = file.extension().string();
  if (ext != ".ply" && ext != ".stl" && ext != ".obj") {
    page->notes.push_back(name + ": " + source + " is not a mesh file, the layer is left out");
    return;
  }
  TriangleMesh mesh = ReadMesh(file);
  if (mesh.NumTriangles() > options.max_mesh_triangles || mesh.empty()) {
    page->notes.push_back(name + ": " + std::to_string(mesh.NumTriangles()) + " triangles (limit " +
                          std::to_string(options.max_mesh_triangles) + "), the layer is left out");
    return;
  }
  if (transform) mesh.Transform(transform->linear(), transform->translation());
  page->meshes.push_back(PackMesh(mesh, id, name, source));
}

// --- compare --------------------------------------------------------------------------------

const char* kStatColumns[] = {"count",          "invalid",          "mean_mm",      "std_mm",
                              "rms_mm",         "median_mm",        "p95_mm",       "max_mm",
                              "signed_mean_mm", "signed_std_mm",    "threshold_mm", "inliers",
                              "outliers",       "outlier_fraction", "coverage"};

std::string StatisticsTable(const json& j, const std::string& src) {
  std::string out = "<table class=\"grid stats\">\n<tr><th></th>";
  for (const char* c : kStatColumns) {
    std::string label = c;
    std::replace(label.begin(), label.end(), '_', ' ');
    out += "<th>" + HtmlEscape(label) + "</th>";
  }
  out += "</tr>\n";
  for (const char* row : {"c2c", "c2m", "m3c2"}) {
    if (!j.contains(row)) continue;
    out += std::string("<tr><th>") + row + "</th>";
    for (const char* c : kStatColumns) {
      out += j[row].contains(c) ? ValueCell(j[row][c], src, std::string("/") + row + "/" + c)
                                : std::string("<td></td>");
    }
    out += "</tr>\n";
  }
  return out + "</table>\n";
}

ColourScale CompareScale(const json& j) {
  const json& s = j.contains("c2m") ? j["c2m"] : j["c2c"];
  ColourScale scale;
  scale.lo = s["histogram"].value("lo_mm", 0.0);
  scale.hi = s["histogram"].value("hi_mm", 1.0);
  if (!(scale.hi > scale.lo)) scale.hi = scale.lo + 1e-3;
  const double t = s.value("threshold_mm", 0.0);
  scale.marks = {t};
  if (s["histogram"].value("signed", false)) scale.marks.push_back(-t);
  scale.label = j.contains("c2m") ? "signed deviation (mm, + outside)" : "distance (mm)";
  char buf[128];
  std::snprintf(buf, sizeof(buf), "range %s to %s mm, as deviation_map.png; black: threshold",
                FormatNumber(scale.lo).c_str(), FormatNumber(scale.hi).c_str());
  scale.note = buf;
  return scale;
}

// The comparison's tables and charts; `rel` is the folder relative to the page ("" or "mode/").
std::string CompareSections(const fs::path& dir, const json& j, const std::string& rel,
                            const std::string& heading, std::vector<std::string>* notes) {
  const std::string src = rel + "report.json";
  std::string out = "<section class=\"compare\">\n<h2>" + HtmlEscape(heading) + "</h2>\n";
  out += "<h3>Statistics</h3>\n" + StatisticsTable(j, src);
  out +=
      "<p class=\"hint\">|deviation| statistics over every point of the comparison; "
      "coverage: share of the reference surface reached by inliers.</p>\n";
  out += "<div class=\"cols\"><div><h3>Inputs</h3>\n" + KeyValueTable(j["inputs"], src, "/inputs") +
         "<h3>Options</h3>\n" + KeyValueTable(j["options"], src, "/options") + "</div>\n";
  out += "<div><h3>Registration</h3>\n" +
         KeyValueTable(j["registration"], src, "/registration", {"transform"});
  if (j["registration"].contains("transform")) {
    out += "<table class=\"matrix\"><caption>reference_from_cloud (mm)</caption>";
    const json& m = j["registration"]["transform"];
    for (size_t r = 0; r < m.size(); ++r) {
      out += "<tr>";
      for (size_t c = 0; c < m[r].size(); ++c)
        out += ValueCell(m[r][c], src,
                         "/registration/transform/" + std::to_string(r) + "/" + std::to_string(c));
      out += "</tr>";
    }
    out += "</table>\n";
  }
  out += "</div></div>\n";
  if (j.contains("vdi2634")) {
    const json& v = j["vdi2634"];
    out += "<h3>VDI/VDE 2634-2</h3>\n" + KeyValueTable(v, src, "/vdi2634");
    for (const auto& [key, e] : v.items()) {
      if (e.is_array() && !e.empty() && e[0].is_object())
        out += "<h4>" + HtmlEscape(key) + "</h4>\n" + ArrayTable(e, src, "/vdi2634/" + key);
    }
  }
  out += "<h3>Charts</h3>\n<div class=\"figures\">";
  out += ImageFigure(dir / "histogram.png", rel + "histogram.png", notes);
  out += ImageFigure(dir / "deviation_map.png", rel + "deviation_map.png", notes);
  out += "</div>\n" + FullRecord(j, src, "every field of " + src);
  return out + "</section>\n";
}

Page ComparePage(const fs::path& dir, const json& j, const HtmlOptions& options) {
  Page page;
  page.kind = "compare";
  const json& in = j["inputs"];
  page.title = "Comparison: " + in.value("cloud", std::string("cloud")) + " against " +
               in.value("reference", std::string("reference"));
  page.subtitle = "slshadow compare, " + j.value("created_utc", std::string());
  const std::string field = "deviation";
  PackClouds(
      {{dir / "compared.ply", "compared.ply", "cloud", "compared cloud", field, CompareScale(j)}},
      options.max_points, &page);
  if (in.value("reference_kind", std::string()) == "mesh") {
    const fs::path ref = in.value("reference", std::string());
    AddMesh(ref.is_absolute() ? ref : fs::absolute(ref), ref.string(), "reference",
            "reference mesh", options, &page);
  }
  page.view_note = "The compared cloud in the reference frame (after registration), mm.";
  page.sections = CompareSections(dir, j, "", "Comparison", &page.notes);
  return page;
}

// --- shadow ---------------------------------------------------------------------------------

Page ShadowPage(const fs::path& dir, const json& j, const HtmlOptions& options) {
  Page page;
  page.kind = "shadow";
  const std::string src = "report.json";
  page.title = "Digital shadow: " + j.value("image_set", std::string("real scan")) + " against " +
               j.value("part", std::string("the part"));
  page.subtitle = "slshadow shadow";
  std::vector<std::string> modes;
  if (j.contains("clouds") && j["clouds"].contains("modes")) {
    for (const auto& m : j["clouds"]["modes"]) modes.push_back(m.value("mode", std::string()));
  }
  std::vector<fs::path> plys;
  for (const auto& m : modes) {
    plys.push_back(dir / "clouds" / ("real_" + m + ".ply"));
    plys.push_back(dir / "clouds" / ("twin_" + m + ".ply"));
  }
  ColourScale scale;
  const double range = std::max(AbsPercentile99(plys, "c2m_part_mm"), 1e-3);
  scale.lo = -range;
  scale.hi = range;
  scale.label = "signed distance to the part (mm, + outside)";
  scale.note =
      "range +-" + FormatNumber(range) + " mm: 99 % of |distance| over the real and twin clouds";
  std::vector<CloudSpec> specs;
  for (const auto& m : modes) {
    for (const char* layer : {"real", "twin"}) {
      const std::string file = std::string("clouds/") + layer + "_" + m + ".ply";
      specs.push_back({dir / file, file, std::string(layer) + "-" + m,
                       std::string(layer) + " (" + m + " mode)", "c2m_part_mm", scale});
    }
  }
  PackClouds(specs, options.max_points, &page);
  if (j.contains("pose") && j["pose"].contains("rig_from_part")) {
    const json& p = j["pose"]["rig_from_part"];
    const auto q = p["rotation_quat_wxyz"].get<std::vector<double>>();
    const auto t = p["translation_mm"].get<std::vector<double>>();
    Eigen::Isometry3d rig_from_part = Eigen::Isometry3d::Identity();
    rig_from_part.linear() =
        Eigen::Quaterniond(q.at(0), q.at(1), q.at(2), q.at(3)).normalized().toRotationMatrix();
    rig_from_part.translation() = Eigen::Vector3d(t.at(0), t.at(1), t.at(2));
    const fs::path part = j.value("part", std::string());
    const std::string ext = part.extension().string();
    if (options.part_surface && ext != ".ply" && ext != ".stl" && ext != ".obj") {
      TriangleMesh mesh = *options.part_surface;
      mesh.Transform(rig_from_part.linear(), rig_from_part.translation());
      page.meshes.push_back(
          PackMesh(mesh, "cad", "CAD part at its pose (" + part.string() + ")", part.string()));
    } else {
      AddMesh(part, part.string(), "cad", "CAD part at its pose", options, &page, &rig_from_part);
    }
  }
  page.view_note =
      "Real and twin clouds in the rig frame (mm), coloured by their signed distance "
      "to the part at its pose.";
  std::string& s = page.sections;
  const json& d = j.value("diagnosis", json::object());
  s += "<section id=\"diagnosis\"><h2>Diagnosis</h2>\n<div class=\"cols diag\"><div>\n";
  s += KeyValueTable(d, src, "/diagnosis", {"findings"});
  if (d.contains("findings"))
    s += ArrayTable(d["findings"], src, "/diagnosis/findings", {"evidence"});
  s += "</div><div class=\"figures maps\">\n";
  if (j.contains("maps")) {
    for (const auto& m : j["maps"]) {
      for (const char* key :
           {"projector_residual", "white_difference", "modulation_ratio", "validity"}) {
        if (m.contains(key)) {
          const std::string file = m[key].get<std::string>();
          s += ImageFigure(dir / file, file, &page.notes);
        }
      }
      if (m.contains("validity_legend"))
        s += "<p class=\"hint\">validity: " + HtmlEscape(m["validity_legend"].get<std::string>()) +
             "</p>\n";
    }
  }
  s += "</div></div></section>\n";
  if (j.contains("pose"))
    s += "<section><h2>Pose of the part</h2>\n" + KeyValueTable(j["pose"], src, "/pose") +
         "</section>\n";
  if (j.contains("clouds") && j["clouds"].contains("modes")) {
    s += "<section><h2>Clouds</h2>\n<div class=\"cols\">";
    for (size_t m = 0; m < j["clouds"]["modes"].size(); ++m)
      s += "<div><h3>" + HtmlEscape(modes[m]) + " mode</h3>\n" +
           KeyValueTable(j["clouds"]["modes"][m], src, "/clouds/modes/" + std::to_string(m)) +
           "</div>";
    s += "</div></section>\n";
  }
  if (j.contains("images") && j["images"].contains("cameras")) {
    s += "<section><h2>Images</h2>\n<div class=\"cols\">";
    for (size_t c = 0; c < j["images"]["cameras"].size(); ++c)
      s += "<div>" +
           KeyValueTable(j["images"]["cameras"][c], src, "/images/cameras/" + std::to_string(c),
                         {"patterns"}) +
           "</div>";
    s += "</div></section>\n";
  }
  if (j.contains("physics") && j["physics"].contains("layers"))
    s += "<section><h2>Physics fit</h2>\n" +
         ArrayTable(j["physics"]["layers"], src, "/physics/layers", {"extra"}) + "</section>\n";
  if (j.contains("stages"))
    s += "<section><h2>Stage times</h2>\n" + ArrayTable(j["stages"], src, "/stages") +
         "</section>\n";
  if (j.contains("charts")) {
    s += "<section><h2>Charts</h2>\n<div class=\"figures\">";
    for (const auto& [key, file] : j["charts"].items())
      s += ImageFigure(dir / file.get<std::string>(), file.get<std::string>(), &page.notes);
    s += "</div></section>\n";
  }
  s += FullRecord(j, src, "every field of report.json");
  return page;
}

// --- multi-view merge ----------------------------------------------------------------------

Page MergePage(const fs::path& dir, const json& j, const HtmlOptions& options) {
  Page page;
  page.kind = "merge";
  const std::string src = "report.json";
  page.title = "Multi-view merge: " + j.value("project", std::string("project"));
  page.subtitle = "slshadow merge";
  const json cad = j.contains("cad") && j["cad"].is_object() ? j["cad"] : json();
  ColourScale scale;
  const double range = cad.is_object() && cad.value("color_range_mm", 0.0) > 0
                           ? cad.value("color_range_mm", 0.0)
                           : std::max(AbsPercentile99({dir / "merged.ply"}, "deviation_mm"), 1e-3);
  scale.lo = -range;
  scale.hi = range;
  scale.label = "signed deviation to the CAD model (mm, + outside)";
  scale.note = "range +-" + FormatNumber(range) + " mm, as cad_deviation.ply";
  PackClouds({{dir / "merged.ply", "merged.ply", "merged", "merged cloud", "deviation_mm", scale}},
             options.max_points, &page);
  if (j.contains("views")) {
    json names = json::array();
    for (const auto& v : j["views"]) names.push_back(v.value("name", std::string()));
    for (auto& c : page.clouds) c.meta["view_names"] = names;
  }
  std::error_code ec;
  if (fs::exists(dir / "cad_deviation.ply", ec))
    AddMesh(dir / "cad_deviation.ply", "cad_deviation.ply", "cad", "CAD model", options, &page);
  page.view_note =
      "The merged cloud in the part frame (mm), coloured by its signed distance to "
      "the CAD model; a picked point names its view.";
  std::string& s = page.sections;
  s += "<section><h2>Merge</h2>\n" + KeyValueTable(j, src, "", {"views", "cad"}) + "</section>\n";
  if (j.contains("views"))
    s += "<section><h2>Views</h2>\n" + ArrayTable(j["views"], src, "/views") + "</section>\n";
  if (cad.is_object()) {
    s += "<section><h2>Against the CAD model</h2>\n" +
         KeyValueTable(cad, src, "/cad", {"views", "surface_by_reason"});
    if (cad.contains("views"))
      s += "<h3>Each view</h3>\n" + ArrayTable(cad["views"], src, "/cad/views");
    if (cad.contains("surface_by_reason"))
      s += "<h3>Surface by reason</h3>\n" +
           KeyValueTable(cad["surface_by_reason"], src, "/cad/surface_by_reason");
    s += "</section>\n";
  }
  s += FullRecord(j, src, "every field of report.json");
  return page;
}

// --- demo -----------------------------------------------------------------------------------

Page DemoPage(const fs::path& dir, const json& demo, const HtmlOptions& options) {
  Page page;
  page.kind = "demo";
  page.title = "slshadow demo: the demo part scanned, reconstructed and compared";
  page.subtitle = "slshadow demo";
  std::string& s = page.sections;
  s += "<section id=\"accuracy\"><h2>Accuracy per mode</h2>\n" +
       ArrayTable(demo["modes"], "demo.json", "/modes", {"report"}) + "</section>\n";
  s += "<section id=\"stages\"><h2>Stage times</h2>\n" +
       ArrayTable(demo["stages"], "demo.json", "/stages") + "</section>\n";
  std::vector<CloudSpec> specs;
  for (const auto& m : demo["modes"]) {
    const std::string mode = m.value("mode", std::string());
    const fs::path sub = dir / mode;
    std::error_code ec;
    if (!fs::exists(sub / "report.json", ec)) {
      page.notes.push_back(mode + "/report.json is missing: the " + mode + " mode is left out");
      continue;
    }
    const json j = ReadJson(sub / "report.json");
    specs.push_back({sub / "compared.ply", mode + "/compared.ply", mode, mode + " mode",
                     "deviation", CompareScale(j)});
    s += CompareSections(sub, j, mode + "/", mode + " mode", &page.notes);
  }
  PackClouds(specs, options.max_points, &page);
  AddMesh(dir / "ground_truth.ply", "ground_truth.ply", "truth", "ground truth mesh", options,
          &page);
  page.view_note =
      "Each mode's cloud in the rig frame (mm) with the ground truth it was compared with.";
  s += FullRecord(demo, "demo.json", "every field of demo.json");
  return page;
}

std::string ScriptSafe(std::string text) {
  for (size_t p = text.find("</"); p != std::string::npos; p = text.find("</", p + 3))
    text.replace(p, 2, "<\\/");
  return text;
}

std::string RenderPage(const Page& page) {
  std::string h;
  h.reserve(1 << 20);
  h += "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
       "<meta http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'; img-src data:; "
       "style-src 'unsafe-inline'; script-src 'unsafe-inline'\">\n"
       "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n<title>" +
       HtmlEscape(page.title) + "</title>\n<style>\n" + Joined(kPageCss) +
       "</style></head>\n<body>\n";
  h += "<header><h1>" + HtmlEscape(page.title) + "</h1><p class=\"sub\">" +
       HtmlEscape(page.subtitle) + "</p></header>\n<main>\n";
  if (!page.notes.empty()) {
    h += "<ul class=\"notes\" id=\"notes\">";
    for (const auto& n : page.notes) h += "<li>" + HtmlEscape(n) + "</li>";
    h += "</ul>\n";
  }
  json meta = {{"kind", page.kind}, {"clouds", json::array()}, {"meshes", json::array()}};
  const std::vector<uint8_t> lut = ColourLut();
  meta["lut"] = lut;
  h += "<section id=\"view3d\"><h2>3D view</h2>\n<div class=\"view-wrap\"><div class=\"viewer\" "
       "id=\"viewer\"><canvas id=\"gl\"></canvas><div id=\"empty-msg\" class=\"empty\" hidden>"
       "</div><div id=\"pick\" class=\"pick\" hidden></div><div class=\"hint overlay\">drag: orbit "
       "&middot; right-drag or shift-drag: pan &middot; wheel: zoom &middot; click: pick a point"
       "</div></div>\n<aside class=\"controls\">\n<fieldset id=\"cloud-layers\"><legend>cloud"
       "</legend>\n";
  for (size_t i = 0; i < page.clouds.size(); ++i) {
    const CloudLayer& c = page.clouds[i];
    meta["clouds"].push_back(c.meta);
    h += "<label><input type=\"radio\" name=\"cloud\" value=\"" + HtmlEscape(c.id) + "\"" +
         (i == 0 ? " checked" : "") + "> " + HtmlEscape(c.name) + " <span class=\"count\">" +
         std::to_string(c.shown) + " of " + std::to_string(c.total_points) + " points</span>";
    if (c.nonfinite_deviation > 0 && c.total_points > 0)
      h += "<span class=\"count\">; " + std::to_string(c.nonfinite_deviation) +
           " without a finite deviation, not shown</span>";
    h += "</label>\n";
  }
  if (page.clouds.empty()) h += "<p class=\"hint\">no cloud in this result</p>";
  h += "</fieldset>\n";
  if (!page.meshes.empty()) {
    h += "<fieldset id=\"mesh-layers\"><legend>meshes</legend>\n";
    for (const auto& m : page.meshes) {
      meta["meshes"].push_back(m.meta);
      h += "<label><input type=\"checkbox\" name=\"mesh\" value=\"" + HtmlEscape(m.id) + "\"> " +
           HtmlEscape(m.name) + " <span class=\"count\">" + std::to_string(m.triangles) +
           " triangles</span></label>\n";
    }
    h += "</fieldset>\n";
  }
  h += "<label class=\"size\">point size <input type=\"range\" id=\"point-size\" min=\"1\" "
       "max=\"8\" "
       "step=\"0.5\" value=\"2\"></label>\n<button type=\"button\" id=\"reset\">reset "
       "view</button>\n";
  for (const auto& c : page.clouds) h += ColourBarHtml(c.scale, c.id);
  h += "</aside></div>\n<p class=\"hint\">" + HtmlEscape(page.view_note) +
       " The view shows a uniform sample of at most the display budget; every figure in the "
       "tables comes from all points.</p></section>\n";
  h += page.sections;
  h += "</main>\n<footer><p>Written by slshadow. Every value in the tables is the one in the "
       "result's JSON files (hover a cell for its field).</p>\n<details id=\"licences\"><summary>"
       "Licences of embedded software</summary><p>three.js r111 (Debian package libjs-three) and "
       "its OrbitControls, embedded in this page:</p><pre>" +
       HtmlEscape(Joined(kThreeCopyright)) + "</pre></details></footer>\n";
  for (const auto& c : page.clouds) {
    for (const auto& [id, data] : c.blocks)
      h += "<script type=\"application/octet-stream\" id=\"" + id + "\">" + data + "</script>\n";
  }
  for (const auto& m : page.meshes) {
    for (const auto& [id, data] : m.blocks)
      h += "<script type=\"application/octet-stream\" id=\"" + id + "\">" + data + "</script>\n";
  }
  h += "<script type=\"application/json\" id=\"slshadow-meta\">" + ScriptSafe(meta.dump()) +
       "</script>\n";
  h += "<script>\n/* three.js r111, MIT licence (see Licences above) */\n" +
       ScriptSafe(Joined(kThreeMinJs)) + "\n</script>\n<script>\n" +
       ScriptSafe(Joined(kThreeOrbitControlsJs)) + "\n</script>\n<script>\n" +
       ScriptSafe(Joined(kViewerJs)) + "\n</script>\n</body></html>\n";
  return h;
}

}  // namespace

HtmlSummary WriteHtmlReport(const fs::path& dir, const HtmlOptions& options) {
  options.Check();
  std::error_code ec;
  SLSHADOW_THROW_IF(!fs::is_directory(dir, ec), dir.string(), ": not a folder");
  Page page;
  if (fs::exists(dir / "report.json", ec)) {
    const json j = ReadJson(dir / "report.json");
    const std::string format = j.is_object() ? j.value("format", std::string()) : std::string();
    if (format == "slshadow.compare_report") {
      page = ComparePage(dir, j, options);
    } else if (format == "slshadow-shadow-report") {
      page = ShadowPage(dir, j, options);
    } else if (format == "slshadow-merge-report") {
      page = MergePage(dir, j, options);
    } else {
      SLSHADOW_THROW((dir / "report.json").string(), ": format: '", format,
                     "' has no HTML page (expected slshadow.compare_report, "
                     "slshadow-shadow-report or slshadow-merge-report)");
    }
  } else if (fs::exists(dir / "demo.json", ec)) {
    page = DemoPage(dir, ReadJson(dir / "demo.json"), options);
  } else {
    SLSHADOW_THROW(dir.string(),
                   ": no report.json or demo.json: not a result folder of "
                   "slshadow compare, shadow or demo");
  }
  HtmlSummary summary;
  summary.kind = page.kind;
  summary.notes = page.notes;
  for (const auto& c : page.clouds) {
    summary.points_total += c.total_points;
    summary.points_shown += c.shown;
    if (!c.empty_reason.empty()) summary.notes.push_back(c.empty_reason);
  }
  const std::string html = RenderPage(page);
  summary.path = dir / "report.html";
  summary.bytes = html.size();
  WriteTextFileAtomically(summary.path, html);
  return summary;
}

std::function<void(const fs::path&)> HtmlWriter(const HtmlOptions& options) {
  options.Check();
  return [options](const fs::path& staged) { WriteHtmlReport(staged, options); };
}

}  // namespace slshadow::report
