// slshadow demo [--out DIR]
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "core/error.h"
#include "core/rig.h"
#include "sim/scene.h"
#include "workflows/multiview/multiview_demo.h"
#include "workflows/pipeline/demo.h"

namespace slshadow::app {
using pipeline::DemoOptions;
using pipeline::DemoResult;
using pipeline::RunDemoJob;

int RunDemo(int argc, char** argv) {
  DemoOptions options;
  CLI::App app{
      "The digital-shadow loop on the embedded demo, in one command:\n"
      "  1. simulate: the demo rig (two 1920x1200 cameras 200 mm apart, a 1280x800 projector) "
      "scans\n"
      "     the demo part (a machined block with steps, a pocket, holes and a dome, generated in "
      "code)\n"
      "     with a Gray code + 4-step phase shift sequence (38 images per camera), noise-free;\n"
      "  2. the scan is written as an ImageSet (OUT/scan), then read back and decoded like a real "
      "capture;\n"
      "  3. reconstruct in both modes: camera-projector (left camera) and stereo (left-right);\n"
      "  4. compare each cloud with the ground-truth surface (OUT/ground_truth.ply): per-point\n"
      "     deviation, RMS, p95, outliers beyond the threshold, coverage; reports in "
      "OUT/projector\n"
      "     and OUT/stereo (report.json, cloud PLY with deviations, histogram and deviation map "
      "PNG).\n"
      "Prints a table per mode and the wall time, CPU time and peak memory of each stage.\n"
      "'coverage' is the share of the whole ground-truth surface reached within the threshold "
      "(faces\n"
      "no camera sees count as missed); 'visible cov.' the share of what the left camera sees lit.",
      argv[0]};
  app.add_option("--out", options.out_dir,
                 "output folder; replaced only when it holds an earlier demo output")
      ->capture_default_str();
  app.add_option("--rig", options.rig_path,
                 "rig YAML instead of the embedded config/demo/rig.yaml");
  app.add_option("--scene", options.scene_path,
                 "scene YAML instead of the embedded config/demo/scene.yaml");
  app.add_option("--patterns", options.patterns_path,
                 "pattern spec instead of the embedded config/demo/patterns.yaml");
  app.add_option("--method", options.method, "triangulation: midpoint | dlt | optimal")
      ->capture_default_str();
  app.add_option("--threshold-mm", options.threshold_mm, "outlier threshold, mm")
      ->capture_default_str();
  app.add_option("--encoding", options.encoding,
                 "ImageSet image encoding, all lossless: pgm (default, fastest to write and read) "
                 "| png (smaller files, slower to write) | tiff")
      ->capture_default_str();
  app.add_flag("--verbose", options.verbose, "print each stage's full report");
  bool no_html = false;
  AddHtmlOptions(&app, &no_html, &options.html);
  int views = 0;
  app.add_option("--views", views,
                 "N > 0: the whole-part loop instead: the demo part on a turntable, N views over a "
                 "full turn scanned, merged (slshadow merge) and compared with its CAD model; "
                 "prints coverage, RMS and the poses' errors (--out, --encoding, --poses, --noise "
                 "apply; --rig and --scene together replace the demo: a rig with its turntable "
                 "axis and a scene at table angle 0 with its disc, e.g. "
                 "config/demo/turntable_rig.yaml and config/demo/occlusion_turntable_scene.yaml)");
  std::string poses = "registered";
  app.add_option("--poses", poses,
                 "with --views: registered (the table poses refined by pairwise ICP and the pose "
                 "graph, as slshadow merge does) | axis (the table poses as they are)")
      ->capture_default_str()
      ->check(CLI::IsMember({"registered", "axis"}));
  bool no_mesh = false;
  app.add_flag("--no-mesh", no_mesh, "with --views: do not build the surface mesh");
  bool noise = false;
  app.add_flag("--noise", noise, "with --views: sensor noise on (shot and read noise)");
  uint64_t noise_seed = 1;
  app.add_option("--noise-seed", noise_seed,
                 "with --views --noise: the noise's seed (each seed another draw of the same "
                 "noise)")
      ->capture_default_str();
  multiview::MergeOptions fusion;
  AddFusionOptions(&app, &fusion);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  if (views > 0) {
    multiview::MultiviewDemoOptions mv;
    mv.views = views;
    mv.out_dir =
        app.count("--out") ? options.out_dir : std::filesystem::path("slshadow-demo-views");
    mv.encoding = ImageEncodingFromString(options.encoding);
    mv.merge.registration = fusion;
    mv.merge.poses = multiview::PoseSourceFromString(poses);
    mv.sensor_noise = noise;
    mv.noise_seed = noise_seed;
    mv.merge.mesh = !no_mesh;
    if (!options.rig_path.empty() || !options.scene_path.empty()) {
      SLSHADOW_THROW_IF(options.rig_path.empty() || options.scene_path.empty(),
                        "--views with --rig or --scene: give both (the rig with its turntable "
                        "axis, the scene at table angle 0 with its table disc)");
      mv.rig = LoadRig(options.rig_path);
      mv.scene = LoadScene(options.scene_path);
    }
    const multiview::MultiviewDemoResult result = multiview::RunMultiviewDemo(mv);
    std::printf(
        "slshadow demo --views %d: %s on a turntable, scanned, merged and compared with its CAD "
        "model\n\n%s",
        views, mv.scene ? mv.scene->name.c_str() : "the demo part", result.Table().c_str());
    return 0;
  }
  options.write_html = !no_html;
  const DemoResult result = RunDemoJob(options);
  std::printf(
      "slshadow demo: virtual scan of the demo part, reconstructed and compared with its ground "
      "truth\n\n");
  std::printf("%s", result.Table().c_str());
  std::printf(
      "\nreports: %s/{projector,stereo}/ (report.json, summary.txt, PNG charts, cloud PLY); scan: "
      "%s/scan\n",
      result.out_dir.string().c_str(), result.out_dir.string().c_str());
  if (!no_html)
    std::printf("page: %s/report.html (open it in a browser)\n", result.out_dir.string().c_str());
  return 0;
}

}  // namespace slshadow::app
