// The main job on the embedded demo: simulate a scan of the demo part with the demo rig, write it
// as an ImageSet, reconstruct it from that ImageSet in both modes (camera-projector and stereo),
// compare each cloud against the part's ground truth, and report accuracy, time and memory per
// stage. The rig, scene and pattern files of config/demo/ are compiled into the binary, so the
// job needs no files; each can be replaced by a path. Built on the scan pipeline
// (workflows/pipeline/scan_pipeline.h).
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/stage_meter.h"
#include "report/html_report.h"
#include "workflows/pipeline/scan_pipeline.h"

namespace slshadow::pipeline {

struct DemoOptions {
  std::filesystem::path out_dir = "slshadow-demo";  // replaced only if it holds an earlier demo
  std::filesystem::path rig_path;                   // empty: the embedded config/demo/rig.yaml
  std::filesystem::path scene_path;                 // empty: the embedded config/demo/scene.yaml
  std::filesystem::path patterns_path;              // empty: the embedded config/demo/patterns.yaml
  std::string method = "midpoint";  // triangulation method (reconstruct/triangulation.h)
  double threshold_mm = 0.25;       // outlier threshold of the comparison
  std::string encoding = "pgm";     // ImageSet image encoding: pgm (fastest) | png | tiff
  bool verbose = false;             // print each stage's full report
  bool write_html = true;           // report.html beside demo.json (report/html_report.h)
  report::HtmlOptions html;
  void Check() const;
};

// The accuracy figures of one mode (visible coverage: of what the left camera sees lit) and
// where its report folder is.
struct DemoModeResult : ModeAccuracy {
  std::filesystem::path report_dir;
};

struct DemoResult {
  std::vector<DemoModeResult> modes;
  std::vector<StageMeasurement> stages;
  std::filesystem::path out_dir;
  nlohmann::json ToJson() const;
  // The table the command prints: per mode, then per stage.
  std::string Table() const;
};

// Runs the whole job; throws slshadow::Error on bad options or inputs. Writes out_dir
// atomically (a complete new folder replaces an earlier demo output).
DemoResult RunDemoJob(const DemoOptions& options);

}  // namespace slshadow::pipeline
