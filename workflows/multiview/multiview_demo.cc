#include "workflows/multiview/multiview_demo.h"

#include <algorithm>
#include <chrono>

#include "core/error.h"
#include "core/file_util.h"
#include "core/mesh.h"
#include "core/string_printf.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {
constexpr const char* kMarker = "multiview_demo.json";
}  // namespace

void MultiviewDemoOptions::Check() const {
  SLSHADOW_THROW_IF(views < 1 || views > 360, "--views: must be in 1..360 (got ", views, ")");
  SLSHADOW_THROW_IF(out_dir.empty(), "--out: an output folder is required");
  SLSHADOW_THROW_IF(rig.has_value() != scene.has_value(),
                    "multi-view demo: give both a rig and a scene, or neither");
  SLSHADOW_THROW_IF(rig && !rig->turntable, "multi-view demo: the rig has no turntable axis");
  merge.Check();
}

nlohmann::json MultiviewDemoResult::ToJson() const {
  nlohmann::json j = merge.ToJson();
  j["scan"] = {{"rendered", scan.rendered},
               {"kept", scan.kept},
               {"render_s", scan.render_seconds},
               {"write_s", scan.write_seconds},
               {"total_s", scan.total_seconds}};
  j["single_view_rms_mm"] = single_view_rms_mm;
  j["total_s"] = total_seconds;
  return j;
}

std::string MultiviewDemoResult::Table() const {
  std::string out = merge.Summary();
  out += StringPrintf("virtual scan: %s\n", scan.BriefReport().c_str());
  if (merge.cad) {
    out += StringPrintf(
        "\nwhole part: coverage %.2f %% of the reachable CAD surface (the face on the table "
        "excluded), merged C2M RMS %.4f mm against %.4f mm for a single view (median), ratio "
        "%.3f\n",
        100 * merge.cad->coverage_reachable, merge.cad->merged_c2m.rms_mm, single_view_rms_mm,
        single_view_rms_mm > 0 ? merge.cad->merged_c2m.rms_mm / single_view_rms_mm : 0.0);
  }
  out += StringPrintf("total %.2f s wall; outputs in %s/{project,model}\n", total_seconds,
                      out_dir.string().c_str());
  return out;
}

MultiviewDemoResult RunMultiviewDemo(const MultiviewDemoOptions& options) {
  const auto t0 = std::chrono::steady_clock::now();
  options.Check();
  std::error_code ec;
  SLSHADOW_THROW_IF(fs::exists(options.out_dir, ec) && !fs::exists(options.out_dir / kMarker, ec),
                    options.out_dir.string(),
                    ": exists and is not an earlier multi-view demo output; choose another --out");
  TurntableSetup setup =
      options.rig ? TurntableSetup{*options.rig, *options.scene} : DemoTurntableSetup();
  if (options.sensor_noise) {
    setup.scene.layers.noise_enabled = true;
    setup.scene.layers.seed = options.noise_seed;
  }
  // The demo's sequence, sized to the rig's projector (a replacement rig may have another).
  PatternSpec spec = pipeline::LoadPatternSpecOrDemo("");
  spec.projector_width = setup.rig.projector->model.width;
  spec.projector_height = setup.rig.projector->model.height;
  spec.Check();
  const ViewsFile views = FullTurnViews(options.views, options.start_deg);
  const TriangleMesh cad = PartSurface(setup.scene);

  StagingDirectory staged(options.out_dir);
  const fs::path& dir = staged.path();
  MultiviewDemoResult result;
  result.out_dir = options.out_dir;
  VirtualProjectOptions scan_options;
  scan_options.encoding = options.encoding;
  scan_options.generator = "slshadow demo --views";
  result.scan = SimulateProject(setup.scene, setup.rig, spec, views, dir / "project", scan_options);
  result.merge = MergeProject(dir / "project", &cad, options.merge);
  result.merge.project = (options.out_dir / "project").string();
  if (result.merge.cad) {
    std::vector<double> rms;
    for (const CadViewFigures& v : result.merge.cad->views) {
      if (v.merged) rms.push_back(v.c2m.rms_mm);
    }
    if (!rms.empty()) {
      std::nth_element(rms.begin(), rms.begin() + static_cast<long>((rms.size() - 1) / 2),
                       rms.end());
      result.single_view_rms_mm = rms[(rms.size() - 1) / 2];
    }
  }
  WriteModel(result.merge, &cad, dir / "model", false);
  WriteMesh(dir / "cad.ply", cad);
  result.total_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  WriteTextFileAtomically(dir / kMarker, result.ToJson().dump(1) + "\n");
  staged.Commit(/*overwrite=*/true);
  return result;
}

}  // namespace slshadow::multiview
