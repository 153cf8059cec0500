// One self-contained HTML page per result (docs/formats.md "HTML report"): `report.html` beside
// the result's report.json. The page opens from file:// with no network and no server: three.js
// (Debian's libjs-three r111, its licence kept in the page), the page's script, style, charts
// (PNG as data: URIs) and point data (base64 typed arrays) are all inside it.
//
// What the page holds, by the kind of folder (found from its files):
//   compare  (report.json `format: slshadow.compare_report`): compared.ply coloured by deviation
//            with the PNG map's colour scale and range, the reference mesh as a toggle when
//            `inputs.reference` is a mesh file that still exists, the statistics / registration /
//            coverage / VDI/VDE 2634-2 tables, histogram.png and deviation_map.png;
//   shadow   (report.json `format: slshadow-shadow-report`): real and twin clouds per mode
//            (clouds/*.ply, field c2m_part_mm) and the CAD part at its pose when `part` is a mesh
//            file, the diagnosis table beside the maps/*.png, the pose, image, cloud, physics and
//            stage tables, charts/*.png;
//   merge    (report.json `format: slshadow-merge-report`, a model folder of `slshadow merge`):
//            merged.ply coloured by deviation_mm (a picked point names its view), the painted CAD
//            mesh cad_deviation.ply, the merge's, views' and CAD comparison's tables;
//   demo     (demo.json of `slshadow demo`): one cloud layer per mode (<mode>/compared.ply), the
//            ground truth mesh (ground_truth.ply), the modes' accuracy and the stage times, and
//            each mode's comparison tables and charts.
// Tables show report.json's own values: each value cell carries the JSON pointer it shows
// (`data-src`, `data-key`) and the exact JSON text (`data-value`); nothing is recomputed in the
// page's script. The 3D view shows at most `max_points` points over all its clouds (a fixed-seed
// uniform sample; the tables' figures come from every point).
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/mesh.h"

namespace slshadow::report {

struct HtmlOptions {
  size_t max_points = 1'000'000;  // display budget over all clouds of the page (>= 1)
  // Triangles above this leave a mesh layer out (the page says so); 0: no mesh layers.
  size_t max_mesh_triangles = 2'000'000;
  // Shadow pages: the part's surface in the part frame, drawn at the report's pose when the
  // report's `part` is not a mesh file (e.g. a scene file); set by the shadow workflow.
  std::shared_ptr<const TriangleMesh> part_surface;
  void Check() const;  // throws slshadow::Error naming the bad field
};

struct HtmlSummary {
  std::filesystem::path path;      // the page written
  std::string kind;                // "compare", "shadow", "merge" or "demo"
  size_t bytes = 0;                // page size
  size_t points_total = 0;         // points of the clouds the page shows (all layers)
  size_t points_shown = 0;         // of those, drawn in the 3D view
  std::vector<std::string> notes;  // what the page says is missing or left out (one line each)
  std::string Brief() const;       // one line: "report.html: 12.3 MB, 1000000 of 2100000 points"
};

// Writes DIR/report.html (atomically: a temporary sibling, then renamed) for the result folder
// `dir`. Throws slshadow::Error naming the file and field when `dir` is not a result folder
// (no report.json / demo.json of a known format) or a file it names cannot be read. A cloud with
// no points, or with no finite deviation, still gives a page: its view says why it is empty.
HtmlSummary WriteHtmlReport(const std::filesystem::path& dir, const HtmlOptions& options = {});

// The same as a hook for the report writers that stage a folder and rename it into place
// (compare::ReportOptions::before_commit, the demo, the shadow report): writes the page into the
// staged folder, so the page appears with the rest of the folder.
std::function<void(const std::filesystem::path&)> HtmlWriter(const HtmlOptions& options = {});

}  // namespace slshadow::report
