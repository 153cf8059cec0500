// slshadow calibrate camera|stereo|projector|rig|refine|import|export ...: one function per
// subcommand, each parsing into its arguments and making its calls into calib/ and the workflows
// of workflows/pipeline/calibrate.h.
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <sstream>
#include <string>
#include <utility>

#include "apps/cmd_calibrate_turntable.h"
#include "apps/commands.h"
#include "calib/calibration.h"
#include "calib/calibration_input.h"
#include "calib/calibration_io.h"
#include "calib/guidance.h"
#include "calib/model_selection.h"
#include "calib/projector.h"
#include "calib/refine.h"
#include "calib/report.h"
#include "calib/target.h"
#include "calib/uncertainty.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "workflows/pipeline/calibrate.h"

namespace slshadow::app {
namespace {

namespace fs = std::filesystem;

std::pair<int, int> ParseSize(const std::string& s, const std::string& option) {
  int w = 0, h = 0;
  char x = 0;
  if (std::sscanf(s.c_str(), "%d%c%d", &w, &x, &h) != 3 || (x != 'x' && x != 'X') || w <= 0 ||
      h <= 0) {
    SLSHADOW_THROW(option, ": expected WIDTHxHEIGHT in pixels, e.g. 1024x768 (got '", s, "')");
  }
  return {w, h};
}

struct CommonOptions {
  std::string target;
  std::string out;
  std::string report;
  std::string opencv_out;
  std::string name = "calibrated";
  bool fix_aspect = false;
  bool fix_principal_point = false;
  bool zero_tangential = false;
  bool fix_k3 = false;
  std::string loss = "none";
  double loss_scale_px = 1.0;
  bool no_cross_validation = false;
  bool board_warp = false;
  int min_views = 10;
  bool select_model = false;
  bool principal_point_inside = false;

  void Add(CLI::App* app, bool needs_target = true) {
    auto* t = app->add_option(
        "--target", target,
        "target YAML (docs/formats.md, \"Calibration target YAML\"; examples in config/targets/)");
    if (needs_target) t->required();
    app->add_option(
           "--out", out,
           "rig file to write (YAML, docs/formats.md \"Rig YAML\"); keeps the calibration evidence")
        ->required();
    app->add_option("--report", report,
                    "report folder (summary.json, report.txt, PNG charts); default: <out without "
                    "extension>_report");
    app->add_option(
        "--opencv-out", opencv_out,
        "also write an OpenCV FileStorage file (.yml/.xml: camera_matrix... or M1 D1 M2 D2 R T)");
    app->add_option("--name", name, "rig name")->capture_default_str();
    app->add_flag("--fix-aspect", fix_aspect, "hold fy/fx at 1 (OpenCV CALIB_FIX_ASPECT_RATIO)");
    app->add_flag("--fix-principal-point", fix_principal_point,
                  "hold cx, cy at the image centre (CALIB_FIX_PRINCIPAL_POINT)");
    app->add_flag("--zero-tangential", zero_tangential, "p1 = p2 = 0 (CALIB_ZERO_TANGENT_DIST)");
    app->add_flag("--fix-k3", fix_k3, "k3 = 0 (CALIB_FIX_K3)");
    app->add_option("--loss", loss, "robust loss on point residuals: none, huber or cauchy")
        ->capture_default_str();
    app->add_option("--loss-scale-px", loss_scale_px,
                    "residual (px) where the robust loss starts to bend")
        ->capture_default_str();
    app->add_flag("--no-cross-validation", no_cross_validation,
                  "skip calibrating the even and odd poses separately");
    app->add_flag("--board-warp", board_warp,
                  "estimate a board warp (two paraboloid terms, mm) shared by all poses");
    app->add_option("--min-views", min_views,
                    "fewer views per device than this is reported as too few")
        ->capture_default_str();
  }
  // Camera-projector commands only.
  void AddSelectModel(CLI::App* app) {
    app->add_flag("--select-model", select_model,
                  "choose the distortion models (cameras: k1 k2 p1 p2 k3 or without k3; projector: "
                  "all five, without k3, "
                  "k1 k2, or k1) by leave-one-pose-out cross-validation: calibrate without each "
                  "pose, pose its board from "
                  "the first camera, predict its projector corners; the lowest prediction RMS (px) "
                  "wins. Needs 3+ poses; "
                  "costs ~8 x (poses + 1) solves. Default off (all five terms for every device)");
    app->add_flag("--principal-point-inside", principal_point_inside,
                  "bound each device's principal point to its image (-0.5 <= cx <= width - 0.5, "
                  "same for cy, px) "
                  "instead of letting the data place it. Default off: a projector with lens offset "
                  "(throwing upwards "
                  "from a table) has it outside its image, and forcing it in then costs fit and "
                  "held-out accuracy. "
                  "Use it when the optics are known to be centred and the poses too few to locate "
                  "it; the report "
                  "names a bound that ends active (the data pull the point outside)");
  }

  CalibrationOptions Options() const {
    CalibrationOptions o;
    o.fix_aspect_ratio = fix_aspect;
    o.fix_principal_point = fix_principal_point;
    o.zero_tangential = zero_tangential;
    o.fix_k3 = fix_k3;
    o.loss = LossTypeFromString(loss);
    o.loss_scale_px = loss_scale_px;
    o.estimate_board_warp = board_warp;
    o.principal_point_inside = principal_point_inside;
    o.Check();
    return o;
  }

  fs::path ReportDir() const {
    if (!report.empty()) return report;
    fs::path p(out);
    return p.parent_path() / (p.stem().string() + "_report");
  }
};

void Print(const std::string& text) { std::fputs(text.c_str(), stdout); }

void PrintMissed(const std::vector<ImageCheck>& checks) {
  Print(pipeline::DescribeBoardDetections(checks));
}

// The workflow's options from the command line's.
int CalibrateAndWrite(CalibrationInput input, const std::vector<ImageCheck>& checks,
                      const CommonOptions& common, nlohmann::json extra) {
  pipeline::CalibrateWriteOptions o;
  o.solve = common.Options();
  o.select_model = common.select_model;
  o.cross_validate = !common.no_cross_validation;
  o.min_views = common.min_views;
  o.rig_name = common.name;
  o.rig_out = common.out;
  o.report_dir = common.ReportDir();
  o.opencv_out = common.opencv_out;
  pipeline::CalibrateAndWrite(std::move(input), checks, o, std::move(extra), Print);
  return 0;
}

// Decoding and local-homography options of `projector` and `rig` (library defaults).
struct ProcamArgs {
  ProcamInputOptions options;
  int window = LocalHomographyOptions{}.half_window_px;

  void Add(CLI::App* app, bool long_help) {
    app->add_option("--shadow-threshold", options.decode.shadow_threshold,
                    long_help ? "decode: minimum white - black, grey levels (8-bit scale)"
                              : "decode: minimum white - black, grey levels")
        ->capture_default_str();
    app->add_option("--contrast-threshold", options.decode.contrast_threshold,
                    "decode: minimum |bit - inverse|, grey levels")
        ->capture_default_str();
    app->add_option("--window", window,
                    long_help ? "local homography half window, camera px (window 2n+1)"
                              : "local homography half window, camera px")
        ->capture_default_str();
  }
  ProcamInputOptions Options() const {
    ProcamInputOptions o = options;
    o.decode.Check();
    o.local.SetHalfWindow(window);
    o.Check();
    return o;
  }
};

struct CameraArgs {
  CommonOptions common;
  std::vector<std::string> images;
  std::string camera_name = "camera";
};

int RunCalibrateCamera(const CameraArgs& a, nlohmann::json extra) {
  const TargetSpec spec = LoadTargetSpec(a.common.target);
  const auto files = ImageFiles(a.images, "--images");
  std::vector<ImageCheck> checks;
  const CalibrationInput input = CameraInputFromImages(spec, files, a.camera_name, &checks);
  PrintMissed(checks);
  extra["target"] = a.common.target;
  return CalibrateAndWrite(input, checks, a.common, extra);
}

struct StereoArgs {
  CommonOptions common;
  std::vector<std::string> left, right;
  std::string left_name = "left", right_name = "right";
};

int RunCalibrateStereo(const StereoArgs& a, nlohmann::json extra) {
  const TargetSpec spec = LoadTargetSpec(a.common.target);
  const auto lf = ImageFiles(a.left, "--left"), rf = ImageFiles(a.right, "--right");
  std::vector<ImageCheck> checks;
  const CalibrationInput input =
      StereoInputFromImages(spec, lf, rf, a.left_name, a.right_name, &checks);
  PrintMissed(checks);
  extra["target"] = a.common.target;
  return CalibrateAndWrite(input, checks, a.common, extra);
}

struct ProjectorArgs {
  CommonOptions common;
  ProcamArgs procam;
  std::string patterns_path, camera_rig;
  std::vector<std::string> captures;
  std::string camera_name = "camera";
};

int RunCalibrateProjector(const ProjectorArgs& a, nlohmann::json extra) {
  const ProcamInputOptions procam = a.procam.Options();
  const TargetSpec spec = LoadTargetSpec(a.common.target);
  const PatternSpec patterns = LoadPatternSpec(a.patterns_path);
  std::optional<Rig> known;
  if (!a.camera_rig.empty()) known = LoadRig(a.camera_rig);
  std::vector<ImageCheck> checks;
  std::vector<std::string> skipped;
  const CalibrationInput input = ProcamInputFromCaptures(
      patterns, a.patterns_path, spec, a.captures, a.camera_name,
      known ? &known->cameras.at(0).model : nullptr, procam, &checks, &skipped);
  for (const auto& s : skipped) std::printf("%s\n", s.c_str());
  PrintMissed(checks);
  extra["target"] = a.common.target;
  extra["patterns"] = PatternSpecToJson(patterns);
  return CalibrateAndWrite(input, checks, a.common, extra);
}

struct RigArgs {
  CommonOptions common;
  ProcamArgs procam;
  std::vector<std::string> imagesets;
};

int RunCalibrateRig(const RigArgs& a, nlohmann::json extra) {
  const ProcamInputOptions procam = a.procam.Options();
  const TargetSpec spec = LoadTargetSpec(a.common.target);
  std::vector<ImageCheck> checks;
  const CalibrationInput input = ProcamInputFromImageSets(a.imagesets, spec, procam, &checks);
  PrintMissed(checks);
  extra["target"] = a.common.target;
  return CalibrateAndWrite(input, checks, a.common, extra);
}

struct RefineArgs {
  std::string rig, scan, out, camera, stereo, known_distance;
  bool refine_focal = false;
  double known_baseline_mm = 0;
};

// --known-distance U1,V1,U2,V2,MM: five numbers.
std::vector<double> ParseKnownDistance(const std::string& text) {
  std::vector<double> v;
  std::stringstream in(text);
  for (std::string item; std::getline(in, item, ',');) {
    try {
      v.push_back(std::stod(item));
    } catch (const std::exception&) {
      v.clear();
      break;
    }
  }
  SLSHADOW_THROW_IF(v.size() != 5, "--known-distance: expected U1,V1,U2,V2,MM (got '", text, "')");
  return v;
}

int RunCalibrateRefine(const RefineArgs& a) {
  pipeline::RefineFromScanRequest r;
  r.rig = a.rig;
  r.scan = a.scan;
  r.out = a.out;
  r.camera = a.camera;
  r.stereo = a.stereo;
  if (!a.known_distance.empty()) r.known_distance = ParseKnownDistance(a.known_distance);
  r.refine.refine_focal = a.refine_focal;
  r.refine.known_baseline_mm = a.known_baseline_mm;
  r.decode = DecodeOptions{};
  const RefineResult result = pipeline::RefineRigFromScan(r);
  std::printf("%s\nwrote %s\n", result.message.c_str(), a.out.c_str());
  return 0;
}

struct ImportArgs {
  std::string in, out, image_size, projector_size, map;
};

int RunCalibrateImport(const ImportArgs& a) {
  int w = 0, h = 0, pw = 0, ph = 0;
  if (!a.image_size.empty()) std::tie(w, h) = ParseSize(a.image_size, "--image-size");
  if (!a.projector_size.empty()) std::tie(pw, ph) = ParseSize(a.projector_size, "--projector-size");
  const OpenCvNodeMap node_map = a.map.empty() ? OpenCvNodeMap{} : ParseOpenCvNodeMap(a.map);
  const Rig rig = ReadOpenCvCalibration(a.in, w, h, pw, ph, node_map);
  SaveRig(rig, a.out);
  std::printf("%s", DescribeRig(rig).c_str());
  std::printf("wrote %s\n", a.out.c_str());
  return 0;
}

int RunCalibrateExport(const std::string& in, const std::string& out) {
  WriteOpenCvCalibration(LoadRig(in), out);
  std::printf("wrote %s\n", out.c_str());
  return 0;
}

}  // namespace

int RunCalibrate(int argc, char** argv) {
  CLI::App app{
      "Calibrate cameras, stereo pairs and projectors from images of a board (Ceres bundle "
      "adjustment).\n\n"
      "Every solve writes RIG.yaml (cameras, projector, poses; rig frame = first camera; mm, px) "
      "with the\n"
      "evidence needed to recompute it (observations, options, covariance), and a report folder: "
      "summary.json,\n"
      "report.txt, per-view RMS chart, residual vectors, projection uncertainty and "
      "cross-validation maps (px).\n"
      "The camera model is OpenCV's (fx fy cx cy k1 k2 p1 p2 k3). Findings name problems in the "
      "data (too few\n"
      "views, fronto-parallel boards, corners only in the centre, saturated images, outlier views) "
      "and what\n"
      "to capture next.\n\n"
      "  camera    --target T.yaml --images DIR|FILES... --out RIG.yaml\n"
      "  stereo    --target T.yaml --left DIR --right DIR --out RIG.yaml     (pairs in sorted name "
      "order)\n"
      "  projector --target T.yaml --patterns P.yaml --captures DIR... --out RIG.yaml\n"
      "            each DIR holds one board pose: the camera's images of the pattern sequence in "
      "name order;\n"
      "            corners are carried into the projector by local homographies (Moreno & Taubin "
      "2012)\n"
      "  rig       --target T.yaml --imagesets DIR... --out RIG.yaml\n"
      "            each DIR an ImageSet (one board pose) with all cameras; projector and cameras "
      "jointly\n"
      "  refine    --rig RIG.yaml --imageset SCAN --out RIG2.yaml [--camera NAME] [--stereo NAME] "
      "[--refine-focal]\n"
      "            [--baseline-mm MM | --known-distance U1,V1,U2,V2,MM]\n"
      "            the scale is the rig file's baseline (\"scale not verified\") unless a known "
      "length sets it: the\n"
      "            baseline, or the distance between the scene points at pixels (U1,V1), (U2,V2) "
      "of --camera;\n"
      "            solutions behind a device (twisted pair) or fitting under half the "
      "correspondences are refused\n"
      "            check the rig against a scan's dense camera-projector correspondences (epipolar "
      "residual,\n"
      "            projector px: median, p95) and re-estimate the projector's pose, keeping the "
      "baseline length;\n"
      "            with --stereo NAME the pose of camera NAME relative to --camera instead "
      "(camera-camera matches:\n"
      "            pixels decoding to the same projector coordinate; residual in NAME's px); "
      "--refine-focal also\n"
      "            re-estimates the focal length (fx, fy by one factor) of the projector, or of "
      "NAME with --stereo\n"
      "  import    OPENCV.yml --out RIG.yaml [--image-size WxH] [--projector-size WxH] [--map "
      "K1=NODE,D1=NODE,...]\n"
      "            layouts: calibration sample, stereo_calib (M1 D1 M2 D2 R T), M1 D1 M2 D2 Rlr "
      "Tlr S,\n"
      "            cam1_intrinsics cam1_distorsion cam2_* R T cam1_size, procam (cam_int "
      "proj_int); --map names\n"
      "            the nodes of any other one- or two-camera layout (keys K1 D1 K2 D2 R T size1 "
      "size2)\n"
      "  export    RIG.yaml --out OPENCV.yml"
      "\n  turntable --rig RIG.yaml --target T.yaml --images DIR... [--angles A1,A2,...] --out "
      "RIG2.yaml\n"
      "            the turntable axis from a board on the table at 3+ commanded angles",
      argv[0]};
  app.require_subcommand(1);

  CameraArgs camera_args;
  auto* camera = app.add_subcommand("camera", "calibrate one camera from images of the board");
  camera_args.common.Add(camera);
  camera
      ->add_option("--images", camera_args.images,
                   "image files or folders (all images in name order)")
      ->required();
  camera->add_option("--camera-name", camera_args.camera_name, "camera name in the rig")
      ->capture_default_str();

  StereoArgs stereo_args;
  auto* stereo = app.add_subcommand(
      "stereo", "calibrate two cameras and their relative pose from image pairs");
  stereo_args.common.Add(stereo);
  stereo
      ->add_option("--left", stereo_args.left,
                   "first camera's images (files or folders); defines the rig frame")
      ->required();
  stereo->add_option("--right", stereo_args.right, "second camera's images, same count and order")
      ->required();
  stereo->add_option("--left-name", stereo_args.left_name, "first camera's name")
      ->capture_default_str();
  stereo->add_option("--right-name", stereo_args.right_name, "second camera's name")
      ->capture_default_str();

  ProjectorArgs projector_args;
  auto* projector = app.add_subcommand(
      "projector", "calibrate a camera and a projector from fringe captures of the board");
  projector_args.common.Add(projector);
  projector_args.common.AddSelectModel(projector);
  projector
      ->add_option("--patterns", projector_args.patterns_path,
                   "pattern spec YAML (docs/formats.md \"Pattern spec\"), must code x and y and "
                   "have a white frame")
      ->required();
  projector
      ->add_option("--captures", projector_args.captures,
                   "one folder per board pose with the camera's images in sequence (name) order")
      ->required();
  projector->add_option("--camera-name", projector_args.camera_name, "camera name in the rig")
      ->capture_default_str();
  projector->add_option(
      "--camera-rig", projector_args.camera_rig,
      "rig file whose first camera's intrinsics are held fixed (else estimated jointly)");
  projector_args.procam.Add(projector, true);

  RigArgs rig_args;
  auto* rig_cmd = app.add_subcommand(
      "rig", "calibrate all cameras and the projector of a rig from ImageSets of the board");
  rig_args.common.Add(rig_cmd);
  rig_args.common.AddSelectModel(rig_cmd);
  rig_cmd
      ->add_option("--imagesets", rig_args.imagesets,
                   "one ImageSet folder per board pose (manifest with rig and pattern spec)")
      ->required();
  rig_args.procam.Add(rig_cmd, false);

  RefineArgs refine_args;
  auto* refine = app.add_subcommand(
      "refine", "check a rig against a scan and re-estimate the projector pose (self-calibration)");
  refine->add_option("--rig", refine_args.rig, "rig file to check")->required();
  refine
      ->add_option(
          "--imageset", refine_args.scan,
          "ImageSet of a scan (any object) with the rig's camera and a pattern spec coding x and y")
      ->required();
  refine->add_option("--out", refine_args.out, "refined rig file to write")->required();
  refine->add_option("--camera", refine_args.camera,
                     "camera to use (default: the rig's first camera)");
  refine->add_option(
      "--stereo", refine_args.stereo,
      "second camera: refine its pose relative to --camera from camera-camera correspondences "
      "(default: none, refine the projector)");
  refine->add_option(
      "--baseline-mm", refine_args.known_baseline_mm,
      "known baseline length between --camera and the refined device, mm: fixes the scale");
  refine->add_option(
      "--known-distance", refine_args.known_distance,
      "U1,V1,U2,V2,MM: two pixels of --camera seeing scene points MM mm apart: fixes the scale");
  refine->add_flag("--refine-focal", refine_args.refine_focal,
                   "also re-estimate the focal length of the projector (or of the --stereo "
                   "camera); default off");

  ImportArgs import_args;
  auto* import = app.add_subcommand("import",
                                    "convert an OpenCV calibration file (calibrateCamera / "
                                    "stereoCalibrate / procam layout) to a rig");
  import->add_option("OPENCV", import_args.in, "OpenCV FileStorage file (.yml/.yaml/.xml)")
      ->required();
  import->add_option("--out", import_args.out, "rig file to write")->required();
  import->add_option("--image-size", import_args.image_size,
                     "camera image size WxH when the file has none");
  import->add_option("--projector-size", import_args.projector_size,
                     "projector size WxH when the file has a projector without size");
  import->add_option("--map", import_args.map,
                     "node names of a layout slshadow does not know: "
                     "K1=NODE,D1=NODE[,K2=,D2=,R=,T=,size1=,size2=]");

  std::string export_in, export_out;
  auto* exp = app.add_subcommand(
      "export", "write a rig as an OpenCV calibration file (camera_matrix... or M1 D1 M2 D2 R T)");
  exp->add_option("RIG", export_in, "rig file")->required();
  exp->add_option("--out", export_out, "OpenCV FileStorage file (.yml/.xml)")->required();

  CalibrateTurntableCommand turntable;
  turntable.Register(&app);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  nlohmann::json extra;
  extra["command"] = CommandLine(argc, argv);

  if (camera->parsed()) return RunCalibrateCamera(camera_args, extra);
  if (stereo->parsed()) return RunCalibrateStereo(stereo_args, extra);
  if (projector->parsed()) return RunCalibrateProjector(projector_args, extra);
  if (rig_cmd->parsed()) return RunCalibrateRig(rig_args, extra);
  if (refine->parsed()) return RunCalibrateRefine(refine_args);
  if (import->parsed()) return RunCalibrateImport(import_args);
  if (exp->parsed()) return RunCalibrateExport(export_in, export_out);
  if (turntable.command->parsed()) return turntable.Run();
  return 1;
}

}  // namespace slshadow::app
