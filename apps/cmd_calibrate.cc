// slshadow calibrate camera|stereo|projector|rig|import|export ...
#include <CLI/CLI.hpp>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <utility>

#include "apps/commands.h"
#include "calib/calibration.h"
#include "calib/calibration_io.h"
#include "calib/guidance.h"
#include "calib/projector.h"
#include "calib/model_selection.h"
#include "calib/refine.h"
#include "calib/report.h"
#include "calib/target.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"

namespace slshadow::app {
namespace {

namespace fs = std::filesystem;

// Image files of a folder (sorted by name), or the file itself.
std::vector<fs::path> ImageFiles(const std::vector<std::string>& args, const std::string& what) {
  static const std::set<std::string> kExt = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"};
  std::vector<fs::path> files;
  for (const auto& a : args) {
    const fs::path p(a);
    SLSHADOW_THROW_IF(!fs::exists(p), what, ": ", a, ": no such file or folder");
    if (fs::is_directory(p)) {
      std::vector<fs::path> in_dir;
      for (const auto& e : fs::directory_iterator(p)) {
        std::string ext = e.path().extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
        if (e.is_regular_file() && kExt.count(ext)) in_dir.push_back(e.path());
      }
      std::sort(in_dir.begin(), in_dir.end());
      SLSHADOW_THROW_IF(in_dir.empty(), what, ": ", a, ": folder holds no images (.png .jpg .bmp .tif .pgm)");
      files.insert(files.end(), in_dir.begin(), in_dir.end());
    } else {
      files.push_back(p);
    }
  }
  return files;
}

std::pair<int, int> ParseSize(const std::string& s, const std::string& option) {
  int w = 0, h = 0;
  char x = 0;
  if (std::sscanf(s.c_str(), "%d%c%d", &w, &x, &h) != 3 || (x != 'x' && x != 'X') || w <= 0 || h <= 0) {
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
    auto* t = app->add_option("--target", target, "target YAML (docs/formats.md, \"Calibration target YAML\"; examples in config/targets/)");
    if (needs_target) t->required();
    app->add_option("--out", out, "rig file to write (YAML, docs/formats.md \"Rig YAML\"); keeps the calibration evidence")->required();
    app->add_option("--report", report, "report folder (summary.json, report.txt, PNG charts); default: <out without extension>_report");
    app->add_option("--opencv-out", opencv_out, "also write an OpenCV FileStorage file (.yml/.xml: camera_matrix... or M1 D1 M2 D2 R T)");
    app->add_option("--name", name, "rig name")->capture_default_str();
    app->add_flag("--fix-aspect", fix_aspect, "hold fy/fx at 1 (OpenCV CALIB_FIX_ASPECT_RATIO)");
    app->add_flag("--fix-principal-point", fix_principal_point, "hold cx, cy at the image centre (CALIB_FIX_PRINCIPAL_POINT)");
    app->add_flag("--zero-tangential", zero_tangential, "p1 = p2 = 0 (CALIB_ZERO_TANGENT_DIST)");
    app->add_flag("--fix-k3", fix_k3, "k3 = 0 (CALIB_FIX_K3)");
    app->add_option("--loss", loss, "robust loss on point residuals: none, huber or cauchy")->capture_default_str();
    app->add_option("--loss-scale-px", loss_scale_px, "residual (px) where the robust loss starts to bend")->capture_default_str();
    app->add_flag("--no-cross-validation", no_cross_validation, "skip calibrating the even and odd poses separately");
    app->add_flag("--board-warp", board_warp, "estimate a board warp (two paraboloid terms, mm) shared by all poses");
    app->add_option("--min-views", min_views, "fewer views per device than this is reported as too few")->capture_default_str();
  }
  // Camera-projector commands only.
  void AddSelectModel(CLI::App* app) {
    app->add_flag("--select-model", select_model,
                  "choose the distortion models (cameras: k1 k2 p1 p2 k3 or without k3; projector: all five, without k3, "
                  "k1 k2, or k1) by leave-one-pose-out cross-validation: calibrate without each pose, pose its board from "
                  "the first camera, predict its projector corners; the lowest prediction RMS (px) wins. Needs 3+ poses; "
                  "costs ~8 x (poses + 1) solves. Default off (all five terms for every device)");
    app->add_flag("--principal-point-inside", principal_point_inside,
                  "bound each device's principal point to its image (-0.5 <= cx <= width - 0.5, same for cy, px) "
                  "instead of letting the data place it. Default off: a projector with lens offset (throwing upwards "
                  "from a table) has it outside its image, and forcing it in then costs fit and held-out accuracy. "
                  "Use it when the optics are known to be centred and the poses too few to locate it; the report "
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

// Calibrates, reviews, writes the rig, the OpenCV file and the report, prints the summary.
// --select-model: sets the devices' held_params to the candidate with the lowest leave-one-pose-out
// prediction RMS of the projector's corners, records the scores in `extra` and returns the chosen
// candidate's calibration with all poses (the same input and options: not solved again).
CalibrationResult SelectModels(CalibrationInput* input, const CalibrationOptions& options, nlohmann::json* extra) {
  int projector = -1;
  for (size_t d = 0; d < input->devices.size(); ++d) {
    if (input->devices[d].is_projector) projector = static_cast<int>(d);
  }
  SLSHADOW_THROW_IF(projector < 0, "--select-model: the input has no projector");
  using M = CameraModel;
  const std::vector<std::pair<std::string, std::vector<int>>> cameras = {{"k1 k2 p1 p2 k3", {}}, {"k1 k2 p1 p2", {M::kK3}}};
  const std::vector<std::pair<std::string, std::vector<int>>> projectors = {
      {"k1 k2 p1 p2 k3", {}}, {"k1 k2 p1 p2", {M::kK3}}, {"k1 k2", {M::kP1, M::kP2, M::kK3}}, {"k1", {M::kK2, M::kP1, M::kP2, M::kK3}}};
  std::vector<ModelCandidate> candidates;
  for (const auto& [cam_name, cam_held] : cameras) {
    for (const auto& [proj_name, proj_held] : projectors) {
      ModelCandidate c;
      c.name = "cameras " + cam_name + " / projector " + proj_name;
      for (size_t d = 0; d < input->devices.size(); ++d) {
        c.held_params.push_back(static_cast<int>(d) == projector ? proj_held : cam_held);
      }
      candidates.push_back(std::move(c));
    }
  }
  auto scores = ScoreModelsByLeaveOnePoseOut(*input, options, candidates, 0, projector);
  size_t best = 0;
  nlohmann::json table = nlohmann::json::array();
  std::printf("model selection (leave-one-pose-out, projector corners):\n");
  for (size_t i = 0; i < scores.size(); ++i) {
    std::printf("  %-45s fit %.4f px, predicted %.4f px (%d corners)\n", scores[i].name.c_str(), scores[i].fit_rms_px,
                scores[i].prediction_rms_px, scores[i].num_predicted);
    table.push_back({{"model", scores[i].name}, {"fit_rms_px", scores[i].fit_rms_px},
                     {"prediction_rms_px", scores[i].prediction_rms_px}, {"num_predicted", scores[i].num_predicted}});
    if (scores[i].prediction_rms_px < scores[best].prediction_rms_px) best = i;
  }
  std::printf("  chosen: %s\n", scores[best].name.c_str());
  for (size_t d = 0; d < input->devices.size(); ++d) input->devices[d].held_params = candidates[best].held_params[d];
  (*extra)["model_selection"] = {{"candidates", table}, {"chosen", scores[best].name}};
  return std::move(scores[best].result);
}

int CalibrateAndWrite(CalibrationInput input, const std::vector<ImageCheck>& checks, const CommonOptions& common,
                      nlohmann::json extra) {
  const CalibrationOptions options = common.Options();
  const CalibrationResult result = common.select_model ? SelectModels(&input, options, &extra) : Calibrate(input, options);
  std::optional<CrossValidation> cv;
  if (!common.no_cross_validation) {
    bool enough = true;
    for (size_t d = 0; d < input.devices.size(); ++d) {
      std::set<int> poses;
      for (const auto& v : input.views) {
        if (v.device == static_cast<int>(d)) poses.insert(v.pose);
      }
      int even = 0, odd = 0;
      for (int p : poses) (p % 2 ? odd : even)++;
      enough = enough && even >= 2 && odd >= 2;
    }
    if (enough) {
      cv = CrossValidate(input, options);
    } else {
      std::printf("cross-validation skipped: needs at least 2 views per device among the even and among the odd poses\n");
    }
  }
  GuidanceOptions go;
  go.min_views = common.min_views;
  const std::vector<Finding> findings = ReviewCalibration(input, result, checks, go);
  Rig rig = RigFromCalibration(input, result, common.name);
  rig.calibration = CalibrationEvidenceToJson(input, options, result, cv);
  SaveRig(rig, common.out);
  if (!common.opencv_out.empty()) WriteOpenCvCalibration(rig, common.opencv_out);
  CalibrationReport report;
  report.input = &input;
  report.options = &options;
  report.result = &result;
  report.cross_validation = cv;
  report.findings = findings;
  report.extra = std::move(extra);
  WriteCalibrationReport(common.ReportDir(), report);

  std::printf("%s\n", result.summary.BriefReport().c_str());
  for (const auto& d : result.devices) {
    const auto& m = d.model;
    std::printf("  %s: %dx%d fx %.3f fy %.3f cx %.3f cy %.3f k1 %.5f k2 %.5f p1 %.6f p2 %.6f k3 %.5f\n", d.name.c_str(), m.width,
                m.height, m.fx(), m.fy(), m.cx(), m.cy(), m.params[4], m.params[5], m.params[6], m.params[7], m.params[8]);
  }
  for (const auto& s : result.summary.devices) std::printf("  %s: RMS %.4f px over %d points\n", s.name.c_str(), s.rms_px, s.num_points);
  for (const auto& b : result.summary.bounds_active) {
    std::printf("  --principal-point-inside: %s; the data pull it outside the image (compare the fit without the flag)\n", b.c_str());
  }
  for (const auto& f : findings) std::printf("%s\n", f.Text().c_str());
  std::printf("wrote %s and report %s\n", common.out.c_str(), common.ReportDir().string().c_str());
  return 0;
}

// Detects the target in each file; device d, pose = index in the list.
void DetectInto(const TargetSpec& spec, const std::vector<fs::path>& files, int device, CalibrationInput* input,
                std::vector<ImageCheck>* checks) {
  const auto board = BoardPoints(spec);
  auto& dev = input->devices[static_cast<size_t>(device)];
  for (size_t p = 0; p < files.size(); ++p) {
    const TargetDetection det = DetectTargetInFile(spec, files[p]);
    if (dev.width == 0) {
      dev.width = det.width;
      dev.height = det.height;
    }
    SLSHADOW_THROW_IF(det.width != dev.width || det.height != dev.height, files[p].string(), ": image is ", det.width, "x",
                      det.height, " but the first image of '", dev.name, "' is ", dev.width, "x", dev.height,
                      " (mismatched image sizes: one camera per list)");
    checks->push_back({files[p].string(), device, det.found, det.reason, det.saturated_fraction});
    if (!det.found) continue;
    BoardView v;
    v.device = device;
    v.pose = static_cast<int>(p);
    v.label = files[p].filename().string();
    for (size_t i = 0; i < det.pixels_px.size(); ++i) {
      v.points_in_board_mm.push_back(board[static_cast<size_t>(det.point_ids[i])]);
      v.pixels_px.push_back(det.pixels_px[i]);
    }
    input->views.push_back(std::move(v));
  }
}

void PrintMissed(const std::vector<ImageCheck>& checks) {
  int found = 0;
  for (const auto& c : checks) {
    if (c.found) {
      ++found;
    } else {
      std::printf("not found: %s: %s\n", c.label.c_str(), c.reason.c_str());
    }
  }
  std::printf("board found in %d of %zu images\n", found, checks.size());
}

}  // namespace

int RunCalibrate(int argc, char** argv) {
  CLI::App app{
      "Calibrate cameras, stereo pairs and projectors from images of a board (Ceres bundle adjustment).\n\n"
      "Every solve writes RIG.yaml (cameras, projector, poses; rig frame = first camera; mm, px) with the\n"
      "evidence needed to recompute it (observations, options, covariance), and a report folder: summary.json,\n"
      "report.txt, per-view RMS chart, residual vectors, projection uncertainty and cross-validation maps (px).\n"
      "The camera model is OpenCV's (fx fy cx cy k1 k2 p1 p2 k3). Findings name problems in the data (too few\n"
      "views, fronto-parallel boards, corners only in the centre, saturated images, outlier views) and what\n"
      "to capture next.\n\n"
      "  camera    --target T.yaml --images DIR|FILES... --out RIG.yaml\n"
      "  stereo    --target T.yaml --left DIR --right DIR --out RIG.yaml     (pairs in sorted name order)\n"
      "  projector --target T.yaml --patterns P.yaml --captures DIR... --out RIG.yaml\n"
      "            each DIR holds one board pose: the camera's images of the pattern sequence in name order;\n"
      "            corners are carried into the projector by local homographies (Moreno & Taubin 2012)\n"
      "  rig       --target T.yaml --imagesets DIR... --out RIG.yaml\n"
      "            each DIR an ImageSet (one board pose) with all cameras; projector and cameras jointly\n"
      "  refine    --rig RIG.yaml --imageset SCAN --out RIG2.yaml [--camera NAME] [--stereo NAME] [--refine-focal]\n"
      "            [--baseline-mm MM | --known-distance U1,V1,U2,V2,MM]\n"
      "            the scale is the rig file's baseline (\"scale not verified\") unless a known length sets it: the\n"
      "            baseline, or the distance between the scene points at pixels (U1,V1), (U2,V2) of --camera;\n"
      "            solutions behind a device (twisted pair) or fitting under half the correspondences are refused\n"
      "            check the rig against a scan's dense camera-projector correspondences (epipolar residual,\n"
      "            projector px: median, p95) and re-estimate the projector's pose, keeping the baseline length;\n"
      "            with --stereo NAME the pose of camera NAME relative to --camera instead (camera-camera matches:\n"
      "            pixels decoding to the same projector coordinate; residual in NAME's px); --refine-focal also\n"
      "            re-estimates the focal length (fx, fy by one factor) of the projector, or of NAME with --stereo\n"
      "  import    OPENCV.yml --out RIG.yaml [--image-size WxH] [--projector-size WxH] [--map K1=NODE,D1=NODE,...]\n"
      "            layouts: calibration sample, stereo_calib (M1 D1 M2 D2 R T), M1 D1 M2 D2 Rlr Tlr S,\n"
      "            cam1_intrinsics cam1_distorsion cam2_* R T cam1_size, procam (cam_int proj_int); --map names\n"
      "            the nodes of any other one- or two-camera layout (keys K1 D1 K2 D2 R T size1 size2)\n"
      "  export    RIG.yaml --out OPENCV.yml",
      argv[0]};
  app.require_subcommand(1);

  CommonOptions cam_common, stereo_common, proj_common, rig_common;
  std::vector<std::string> images, left, right, captures, imagesets;
  std::string camera_name = "camera", left_name = "left", right_name = "right";
  std::string patterns_path, camera_rig;
  double shadow_threshold = 12, contrast_threshold = 4;
  int window = 20;

  auto* camera = app.add_subcommand("camera", "calibrate one camera from images of the board");
  cam_common.Add(camera);
  camera->add_option("--images", images, "image files or folders (all images in name order)")->required();
  camera->add_option("--camera-name", camera_name, "camera name in the rig")->capture_default_str();

  auto* stereo = app.add_subcommand("stereo", "calibrate two cameras and their relative pose from image pairs");
  stereo_common.Add(stereo);
  stereo->add_option("--left", left, "first camera's images (files or folders); defines the rig frame")->required();
  stereo->add_option("--right", right, "second camera's images, same count and order")->required();
  stereo->add_option("--left-name", left_name, "first camera's name")->capture_default_str();
  stereo->add_option("--right-name", right_name, "second camera's name")->capture_default_str();

  auto* projector = app.add_subcommand("projector", "calibrate a camera and a projector from fringe captures of the board");
  proj_common.Add(projector);
  proj_common.AddSelectModel(projector);
  projector->add_option("--patterns", patterns_path, "pattern spec YAML (docs/formats.md \"Pattern spec\"), must code x and y and have a white frame")->required();
  projector->add_option("--captures", captures, "one folder per board pose with the camera's images in sequence (name) order")->required();
  projector->add_option("--camera-name", camera_name, "camera name in the rig")->capture_default_str();
  projector->add_option("--camera-rig", camera_rig, "rig file whose first camera's intrinsics are held fixed (else estimated jointly)");
  projector->add_option("--shadow-threshold", shadow_threshold, "decode: minimum white - black, grey levels (8-bit scale)")->capture_default_str();
  projector->add_option("--contrast-threshold", contrast_threshold, "decode: minimum |bit - inverse|, grey levels")->capture_default_str();
  projector->add_option("--window", window, "local homography half window, camera px (window 2n+1)")->capture_default_str();

  auto* rig_cmd = app.add_subcommand("rig", "calibrate all cameras and the projector of a rig from ImageSets of the board");
  rig_common.Add(rig_cmd);
  rig_common.AddSelectModel(rig_cmd);
  rig_cmd->add_option("--imagesets", imagesets, "one ImageSet folder per board pose (manifest with rig and pattern spec)")->required();
  rig_cmd->add_option("--shadow-threshold", shadow_threshold, "decode: minimum white - black, grey levels")->capture_default_str();
  rig_cmd->add_option("--contrast-threshold", contrast_threshold, "decode: minimum |bit - inverse|, grey levels")->capture_default_str();
  rig_cmd->add_option("--window", window, "local homography half window, camera px")->capture_default_str();

  std::string refine_rig, refine_scan, refine_out, refine_camera;
  auto* refine = app.add_subcommand("refine", "check a rig against a scan and re-estimate the projector pose (self-calibration)");
  refine->add_option("--rig", refine_rig, "rig file to check")->required();
  refine->add_option("--imageset", refine_scan, "ImageSet of a scan (any object) with the rig's camera and a pattern spec coding x and y")->required();
  refine->add_option("--out", refine_out, "refined rig file to write")->required();
  refine->add_option("--camera", refine_camera, "camera to use (default: the rig's first camera)");
  std::string refine_stereo, known_distance;
  bool refine_focal = false;
  double known_baseline_mm = 0;
  refine->add_option("--stereo", refine_stereo,
                     "second camera: refine its pose relative to --camera from camera-camera correspondences "
                     "(default: none, refine the projector)");
  refine->add_option("--baseline-mm", known_baseline_mm,
                     "known baseline length between --camera and the refined device, mm: fixes the scale");
  refine->add_option("--known-distance", known_distance,
                     "U1,V1,U2,V2,MM: two pixels of --camera seeing scene points MM mm apart: fixes the scale");
  refine->add_flag("--refine-focal", refine_focal,
                   "also re-estimate the focal length of the projector (or of the --stereo camera); default off");

  std::string import_in, import_out, image_size, projector_size, import_map;
  auto* import = app.add_subcommand("import", "convert an OpenCV calibration file (calibrateCamera / stereoCalibrate / procam layout) to a rig");
  import->add_option("OPENCV", import_in, "OpenCV FileStorage file (.yml/.yaml/.xml)")->required();
  import->add_option("--out", import_out, "rig file to write")->required();
  import->add_option("--image-size", image_size, "camera image size WxH when the file has none");
  import->add_option("--projector-size", projector_size, "projector size WxH when the file has a projector without size");
  import->add_option("--map", import_map,
                     "node names of a layout slshadow does not know: K1=NODE,D1=NODE[,K2=,D2=,R=,T=,size1=,size2=]");

  std::string export_in, export_out;
  auto* exp = app.add_subcommand("export", "write a rig as an OpenCV calibration file (camera_matrix... or M1 D1 M2 D2 R T)");
  exp->add_option("RIG", export_in, "rig file")->required();
  exp->add_option("--out", export_out, "OpenCV FileStorage file (.yml/.xml)")->required();

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  nlohmann::json extra;
  std::string cmdline;
  for (int i = 0; i < argc; ++i) cmdline += (i ? " " : "") + std::string(argv[i]);
  extra["command"] = cmdline;

  if (camera->parsed()) {
    const TargetSpec spec = LoadTargetSpec(cam_common.target);
    const auto files = ImageFiles(images, "--images");
    CalibrationInput input;
    input.devices = {CalibrationDevice{camera_name, 0, 0, false, std::nullopt, false, {}}};
    input.num_poses = static_cast<int>(files.size());
    std::vector<ImageCheck> checks;
    DetectInto(spec, files, 0, &input, &checks);
    PrintMissed(checks);
    extra["target"] = cam_common.target;
    return CalibrateAndWrite(input, checks, cam_common, extra);
  }
  if (stereo->parsed()) {
    const TargetSpec spec = LoadTargetSpec(stereo_common.target);
    const auto lf = ImageFiles(left, "--left"), rf = ImageFiles(right, "--right");
    SLSHADOW_THROW_IF(lf.size() != rf.size(), "stereo: ", lf.size(), " left images but ", rf.size(),
                      " right images; give the same poses in the same (name) order");
    SLSHADOW_THROW_IF(left_name == right_name, "stereo: --left-name and --right-name must differ (got '", left_name, "')");
    CalibrationInput input;
    input.devices = {CalibrationDevice{left_name, 0, 0, false, std::nullopt, false, {}},
                     CalibrationDevice{right_name, 0, 0, false, std::nullopt, false, {}}};
    input.num_poses = static_cast<int>(lf.size());
    std::vector<ImageCheck> checks;
    DetectInto(spec, lf, 0, &input, &checks);
    DetectInto(spec, rf, 1, &input, &checks);
    PrintMissed(checks);
    extra["target"] = stereo_common.target;
    return CalibrateAndWrite(input, checks, stereo_common, extra);
  }
  DecodeOptions decode;
  decode.shadow_threshold = shadow_threshold;
  decode.contrast_threshold = contrast_threshold;
  decode.Check();
  LocalHomographyOptions local;
  local.half_window_px = window;
  local.min_valid_pixels = std::min(100, window * window);
  local.Check();
  if (projector->parsed()) {
    const TargetSpec spec = LoadTargetSpec(proj_common.target);
    const PatternSpec patterns = LoadPatternSpec(patterns_path);
    CalibrationInput input;
    input.devices = {CalibrationDevice{camera_name, 0, 0, false, std::nullopt, false, {}},
                     CalibrationDevice{"projector", patterns.projector_width, patterns.projector_height, true, std::nullopt, false, {}}};
    if (!camera_rig.empty()) {
      const Rig known = LoadRig(camera_rig);
      input.devices[0].initial = known.cameras.at(0).model;
      input.devices[0].hold_intrinsics = true;
    }
    input.num_poses = static_cast<int>(captures.size());
    std::vector<ImageCheck> checks;
    for (size_t p = 0; p < captures.size(); ++p) {
      const auto files = ImageFiles({captures[p]}, "--captures");
      SLSHADOW_THROW_IF(static_cast<int>(files.size()) != patterns.NumImages(), captures[p], ": ", files.size(),
                        " images but the pattern sequence ", patterns_path, " has ", patterns.NumImages());
      std::vector<cv::Mat> frames;
      for (const auto& f : files) frames.push_back(ReadGrayImage(f));
      if (input.devices[0].width == 0) {
        input.devices[0].width = frames[0].cols;
        input.devices[0].height = frames[0].rows;
      }
      const ProcamPose pose = MakeProcamPose(patterns, frames, spec, static_cast<int>(p), 0, 1, captures[p], decode, local);
      checks.push_back({captures[p], 0, pose.detection.found, pose.detection.reason, pose.detection.saturated_fraction});
      for (const auto& s : pose.projector.skipped) std::printf("%s: skipped %s\n", captures[p].c_str(), s.c_str());
      if (!pose.detection.found) continue;
      input.views.push_back(pose.camera_view);
      if (pose.projector_view.pixels_px.size() >= 4) input.views.push_back(pose.projector_view);
    }
    PrintMissed(checks);
    extra["target"] = proj_common.target;
    extra["patterns"] = PatternSpecToJson(patterns);
    return CalibrateAndWrite(input, checks, proj_common, extra);
  }
  if (rig_cmd->parsed()) {
    const TargetSpec spec = LoadTargetSpec(rig_common.target);
    CalibrationInput input;
    input.num_poses = static_cast<int>(imagesets.size());
    std::vector<ImageCheck> checks;
    std::vector<std::string> names;
    int projector_device = -1;
    for (size_t p = 0; p < imagesets.size(); ++p) {
      const ImageSet set = ImageSet::Open(imagesets[p]);
      const PatternSpec patterns =
          PatternSpecFromConfig(ConfigNode::FromJson(set.patterns(), (fs::path(imagesets[p]) / "manifest.json").string(), "patterns"));
      if (p == 0) {
        for (const auto& name : set.CameraNames()) {
          const auto& cam = set.rig().Camera(name);
          input.devices.push_back({name, cam.model.width, cam.model.height, false, std::nullopt, false, {}});
          names.push_back(name);
        }
        projector_device = static_cast<int>(input.devices.size());
        input.devices.push_back({set.rig().projector ? set.rig().projector->name : "projector", patterns.projector_width,
                                 patterns.projector_height, true, std::nullopt, false, {}});
      }
      SLSHADOW_THROW_IF(set.CameraNames() != names, imagesets[p], ": cameras differ from the first ImageSet's");
      for (size_t d = 0; d < names.size(); ++d) {
        const std::string label = imagesets[p] + "/" + names[d];
        const ProcamPose pose = MakeProcamPose(patterns, set.LoadCamera(names[d]), spec, static_cast<int>(p),
                                               static_cast<int>(d), projector_device, label, decode, local);
        checks.push_back({label, static_cast<int>(d), pose.detection.found, pose.detection.reason, pose.detection.saturated_fraction});
        if (!pose.detection.found) continue;
        input.views.push_back(pose.camera_view);
        if (pose.projector_view.pixels_px.size() >= 4) input.views.push_back(pose.projector_view);
      }
    }
    PrintMissed(checks);
    extra["target"] = rig_common.target;
    return CalibrateAndWrite(input, checks, rig_common, extra);
  }
  if (refine->parsed()) {
    const Rig rig = LoadRig(refine_rig);
    const ImageSet scan = ImageSet::Open(refine_scan);
    const std::string cam = refine_camera.empty() ? rig.cameras.at(0).name : refine_camera;
    const int index = rig.CameraIndex(cam);
    SLSHADOW_THROW_IF(index < 0, refine_rig, ": no camera named '", cam, "'");
    const PatternSpec patterns =
        PatternSpecFromConfig(ConfigNode::FromJson(scan.patterns(), (fs::path(refine_scan) / "manifest.json").string(), "patterns"));
    SLSHADOW_THROW_IF(!patterns.code_x || !patterns.code_y, refine_scan, ": patterns must code both projector axes to check the calibration");
    SLSHADOW_THROW_IF(refine_stereo.empty() && !rig.projector, refine_rig, ": rig '", rig.name,
                      "' has no projector: refine the pose of one camera against another with --stereo NAME");
    const ProjectorMap map = DecodePatterns(patterns, scan.LoadCamera(cam), decode);
    RefineOptions ro;
    ro.refine_focal = refine_focal;
    ro.known_baseline_mm = known_baseline_mm;
    std::optional<ProjectorMap> map_b;
    if (!refine_stereo.empty()) {
      const int index_b = rig.CameraIndex(refine_stereo);
      SLSHADOW_THROW_IF(index_b < 0, refine_rig, ": no camera named '", refine_stereo, "' (--stereo)");
      map_b = DecodePatterns(patterns, scan.LoadCamera(refine_stereo), decode);
    }
    if (!known_distance.empty()) {
      std::vector<double> v;
      std::stringstream in(known_distance);
      for (std::string item; std::getline(in, item, ',');) {
        try {
          v.push_back(std::stod(item));
        } catch (const std::exception&) {
          v.clear();
          break;
        }
      }
      SLSHADOW_THROW_IF(v.size() != 5, "--known-distance: expected U1,V1,U2,V2,MM (got '", known_distance, "')");
      KnownDistance k;
      k.distance_mm = v[4];
      for (int i = 0; i < 2; ++i) {
        const Eigen::Vector2d px(v[static_cast<size_t>(2 * i)], v[static_cast<size_t>(2 * i + 1)]);
        const auto c = CorrespondenceAt(map, map_b ? &*map_b : nullptr, px);
        SLSHADOW_THROW_IF(!c, "--known-distance: pixel (", px.x(), ", ", px.y(), ") of camera '", cam,
                          "' has no decoded correspondence", map_b ? " in both cameras" : "");
        (i == 0 ? k.first : k.second) = *c;
      }
      ro.known_distances.push_back(k);
    }
    RefineResult r;
    if (refine_stereo.empty()) {
      r = RefineProjectorPose(rig, index, SampleCorrespondences(map), ro);
    } else {
      r = RefineStereoPose(rig, index, rig.CameraIndex(refine_stereo), StereoCorrespondences(map, *map_b), ro);
    }
    // A refused solution writes nothing: the report says why.
    SLSHADOW_THROW_IF(r.rejected, refine_rig, ": calibrate refine: ", r.message);
    Rig out = r.rig;
    out.calibration["refine"] = {{"imageset", refine_scan}, {"camera", cam}, {"stereo", refine_stereo},
                                 {"focal_scale", r.focal_scale},
                                 {"before_median_px", r.before.median_px}, {"before_p95_px", r.before.p95_px},
                                 {"after_median_px", r.after.median_px}, {"after_p95_px", r.after.p95_px},
                                 {"rotation_change_rad", r.rotation_change_rad},
                                 {"direction_change_rad", r.direction_change_rad}, {"converged", r.converged},
                                 {"front_share", r.front_share}, {"inlier_share", r.inlier_share},
                                 {"baseline_mm", r.baseline_mm}, {"scale_verified", r.scale_verified}};
    SaveRig(out, refine_out);
    std::printf("%s\nwrote %s\n", r.message.c_str(), refine_out.c_str());
    return 0;
  }
  if (import->parsed()) {
    int w = 0, h = 0, pw = 0, ph = 0;
    if (!image_size.empty()) std::tie(w, h) = ParseSize(image_size, "--image-size");
    if (!projector_size.empty()) std::tie(pw, ph) = ParseSize(projector_size, "--projector-size");
    const OpenCvNodeMap node_map = import_map.empty() ? OpenCvNodeMap{} : ParseOpenCvNodeMap(import_map);
    const Rig rig = ReadOpenCvCalibration(import_in, w, h, pw, ph, node_map);
    SaveRig(rig, import_out);
    std::printf("%s", DescribeRig(rig).c_str());
    std::printf("wrote %s\n", import_out.c_str());
    return 0;
  }
  if (exp->parsed()) {
    WriteOpenCvCalibration(LoadRig(export_in), export_out);
    std::printf("wrote %s\n", export_out.c_str());
    return 0;
  }
  return 1;
}

}  // namespace slshadow::app
