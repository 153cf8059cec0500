// Calibration in Python: calibrate_camera | stereo | projector | rig (`slshadow calibrate ...`,
// the same library calls on the same inputs, so the same rig file and report folder),
// calibrate_corners (the same solve and files from corners the caller detected) and
// detect_target (the board detection those read images with).
#include <algorithm>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "calib/calibration_input.h"
#include "calib/calibration_io.h"
#include "calib/target.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "patterns/pattern_spec.h"
#include "python/bindings.h"
#include "python/convert.h"
#include "workflows/pipeline/calibrate.h"

namespace slshadow::python {

namespace {

namespace fs = std::filesystem;

std::string FsPath(const py::handle& object) {
  return py::str(py::module_::import("os").attr("fspath")(object));
}

// A path or a sequence of paths, as strings (the command line's arguments).
std::vector<std::string> PathList(const py::handle& object) {
  std::vector<std::string> out;
  if (py::isinstance<py::str>(object) || py::hasattr(object, "__fspath__")) {
    out.push_back(FsPath(object));
  } else {
    for (const py::handle item : object) out.push_back(FsPath(item));
  }
  return out;
}

// The options every calibrate_* call takes (the command line's CommonOptions), then the
// camera-projector ones (`calibrate projector | rig`).
struct Common {
  std::optional<fs::path> report;
  std::optional<fs::path> opencv_out;
  std::string name;
  bool fix_aspect, fix_principal_point, zero_tangential, fix_k3;
  std::string loss;
  double loss_scale_px;
  bool board_warp, cross_validate;
  int min_views;
  py::object progress;
};

struct Procam {
  double shadow_threshold, contrast_threshold;
  int window;
  bool select_model, principal_point_inside;

  // What `calibrate projector | rig` build from --shadow-threshold, --contrast-threshold and
  // --window (apps/cmd_calibrate.cc ProcamArgs::Options).
  ProcamInputOptions Options() const {
    ProcamInputOptions o;
    o.decode.shadow_threshold = shadow_threshold;
    o.decode.contrast_threshold = contrast_threshold;
    o.decode.Check();
    o.local.half_window_px = window;
    o.local.min_valid_pixels = std::min(100, window * window);
    o.Check();
    return o;
  }
};

#define SLSHADOW_COMMON_PARAMS                                                                  \
  const std::optional<fs::path>&report, const std::optional<fs::path>&opencv_out,               \
      const std::string &name, bool fix_aspect, bool fix_principal_point, bool zero_tangential, \
      bool fix_k3, const std::string &loss, double loss_scale_px, bool board_warp,              \
      bool cross_validate, int min_views, const py::object &progress
#define SLSHADOW_COMMON_VALUES                                                                \
  Common {                                                                                    \
    report, opencv_out, name, fix_aspect, fix_principal_point, zero_tangential, fix_k3, loss, \
        loss_scale_px, board_warp, cross_validate, min_views, progress                        \
  }
#define SLSHADOW_COMMON_ARGS                                                                  \
  py::arg("report") = py::none(), py::arg("opencv_out") = py::none(),                         \
  py::arg("name") = "calibrated", py::arg("fix_aspect") = false,                              \
  py::arg("fix_principal_point") = false, py::arg("zero_tangential") = false,                 \
  py::arg("fix_k3") = false, py::arg("loss") = "none", py::arg("loss_scale_px") = 1.0,        \
  py::arg("board_warp") = false, py::arg("cross_validate") = true, py::arg("min_views") = 10, \
  py::arg("progress") = py::none()
#define SLSHADOW_PROCAM_PARAMS                                                       \
  double shadow_threshold, double contrast_threshold, int window, bool select_model, \
      bool principal_point_inside
#define SLSHADOW_PROCAM_VALUES \
  Procam { shadow_threshold, contrast_threshold, window, select_model, principal_point_inside }
#define SLSHADOW_PROCAM_ARGS                                                                       \
  py::arg("shadow_threshold") = 12.0, py::arg("contrast_threshold") = 4.0, py::arg("window") = 20, \
  py::arg("select_model") = false, py::arg("principal_point_inside") = false

constexpr const char* kCommonDoc =
    " Options (the command line's): report (folder; default <out without extension>_report), "
    "opencv_out, name (the rig's), fix_aspect, fix_principal_point, zero_tangential, fix_k3, "
    "loss ('none' | 'huber' | 'cauchy'), loss_scale_px, board_warp, cross_validate "
    "(--no-cross-validation is False), min_views. Returns a dict: rig (the Rig written to out, "
    "with its calibration evidence), calibration (rig.to_dict()['calibration']: the summary, "
    "options and observations), summary (the report folder's summary.json), log (what the "
    "command prints), report_dir. The GIL is released while it runs; progress(stage, done, "
    "total) is called per image or capture read ('detect' / 'decode') and around the solve "
    "('calibrate').";

// The workflow's options from the call's (apps/cmd_calibrate.cc CalibrateAndWrite).
pipeline::CalibrateWriteOptions WriteOptions(const Common& c, const fs::path& out,
                                             const Procam* procam) {
  pipeline::CalibrateWriteOptions o;
  o.solve.fix_aspect_ratio = c.fix_aspect;
  o.solve.fix_principal_point = c.fix_principal_point;
  o.solve.zero_tangential = c.zero_tangential;
  o.solve.fix_k3 = c.fix_k3;
  o.solve.loss = LossTypeFromString(c.loss);
  o.solve.loss_scale_px = c.loss_scale_px;
  o.solve.estimate_board_warp = c.board_warp;
  if (procam) o.solve.principal_point_inside = procam->principal_point_inside;
  o.solve.Check();
  o.select_model = procam && procam->select_model;
  o.cross_validate = c.cross_validate;
  o.min_views = c.min_views;
  o.rig_name = c.name;
  o.rig_out = out;
  o.report_dir = c.report ? *c.report : out.parent_path() / (out.stem().string() + "_report");
  if (c.opencv_out) o.opencv_out = *c.opencv_out;
  return o;
}

// Runs `read` (building the calibration input, the image checks and the lines printed before
// the solve), then CalibrateAndWrite, with the GIL released and the library's progress forwarded;
// returns the dict every calibrate_* call returns.
template <typename Read>
py::dict Solve(const Common& c, const fs::path& out, const Procam* procam, const std::string& call,
               nlohmann::json extra, Read&& read) {
  const pipeline::CalibrateWriteOptions o = WriteOptions(c, out, procam);
  const ProgressCallback report(c.progress);
  std::string log;
  {
    py::gil_scoped_release release;
    const ForwardLibraryProgress forward(report);
    CalibrationInput input;
    std::vector<ImageCheck> checks;
    read(&input, &checks, &log, &extra);
    report("calibrate", 0, 1);
    extra["command"] = "slshadow." + call + " (Python)";
    pipeline::CalibrateAndWrite(std::move(input), checks, o, extra,
                                [&log](const std::string& text) { log += text; });
    report("calibrate", 1, 1);
  }
  py::dict d;
  const Rig rig = LoadRig(out);
  d["rig"] = rig;
  d["calibration"] = FromJson(rig.calibration);
  const fs::path summary = o.report_dir / "summary.json";
  d["summary"] = fs::exists(summary)
                     ? py::module_::import("json").attr("loads")(py::str(ReadTextFile(summary)))
                     : py::object(py::none());
  d["log"] = log;
  d["report_dir"] = o.report_dir.string();
  return d;
}

// (N, cols) float64 rows of a Python array, copied.
template <typename Vector>
std::vector<Vector> Rows(const py::handle& object, int cols, const std::string& what) {
  const auto a = py::array_t<double, py::array::c_style | py::array::forcecast>::ensure(object);
  SLSHADOW_THROW_IF(!a || a.ndim() != 2 || a.shape(1) != cols, what, ": expected an (N, ", cols,
                    ") array of numbers (got ", std::string(py::repr(object)).substr(0, 80), ")");
  std::vector<Vector> rows(static_cast<size_t>(a.shape(0)));
  for (py::ssize_t i = 0; i < a.shape(0); ++i)
    for (int k = 0; k < cols; ++k) rows[static_cast<size_t>(i)][k] = a.at(i, k);
  return rows;
}

std::pair<int, int> SizeFrom(const py::handle& object, const std::string& what) {
  const auto a = py::array_t<int64_t, py::array::c_style | py::array::forcecast>::ensure(object);
  SLSHADOW_THROW_IF(!a || a.ndim() != 1 || a.shape(0) != 2 || a.at(0) <= 0 || a.at(1) <= 0, what,
                    ": expected (width, height) in pixels (got ", std::string(py::repr(object)),
                    ")");
  return {static_cast<int>(a.at(0)), static_cast<int>(a.at(1))};
}

// calibrate_corners' input: devices from image_points (a list per pose: one camera named
// `camera`; a dict name -> list per pose: those cameras in order), one view per (device, pose)
// whose entry is not None.
void CornersInput(const py::handle& object_points, const py::handle& image_points,
                  const py::handle& image_size, const std::string& camera, const py::object& labels,
                  CalibrationInput* input, std::vector<ImageCheck>* checks) {
  std::vector<std::pair<std::string, py::object>> per_device;
  if (py::isinstance<py::dict>(image_points)) {
    for (const auto& [key, value] : py::reinterpret_borrow<py::dict>(image_points))
      per_device.emplace_back(py::str(key), py::reinterpret_borrow<py::object>(value));
  } else {
    per_device.emplace_back(camera, py::reinterpret_borrow<py::object>(image_points));
  }
  SLSHADOW_THROW_IF(per_device.empty(), "calibrate_corners: image_points: no cameras");
  std::vector<std::vector<Eigen::Vector3d>> board;
  size_t pose = 0;
  for (const py::handle item : object_points) {
    board.push_back(Rows<Eigen::Vector3d>(
        item, 3, "calibrate_corners: object_points[" + std::to_string(pose) + "]"));
    ++pose;
  }
  input->num_poses = static_cast<int>(board.size());
  std::vector<std::string> pose_labels;
  if (!labels.is_none()) {
    for (const py::handle l : labels) pose_labels.push_back(py::str(l));
    SLSHADOW_THROW_IF(pose_labels.size() != board.size(),
                      "calibrate_corners: labels: ", pose_labels.size(), " labels for ",
                      board.size(), " poses");
  }
  for (size_t d = 0; d < per_device.size(); ++d) {
    const auto& [name, views] = per_device[d];
    const std::string what = "calibrate_corners: image_points['" + name + "']";
    const py::object size = py::isinstance<py::dict>(image_size)
                                ? py::object(image_size[py::str(name)])
                                : py::reinterpret_borrow<py::object>(image_size);
    const auto [width, height] = SizeFrom(size, "calibrate_corners: image_size");
    input->devices.push_back(CalibrationDevice::Camera(name, width, height));
    SLSHADOW_THROW_IF(static_cast<size_t>(py::len(views)) != board.size(), what, ": ",
                      py::len(views), " poses but object_points has ", board.size());
    size_t p = 0;
    for (const py::handle view : views) {
      const std::string label = pose_labels.empty() ? "pose_" + std::to_string(p) : pose_labels[p];
      checks->push_back(
          {label, static_cast<int>(d), !view.is_none(), view.is_none() ? "not given" : "", 0.0});
      if (!view.is_none()) {
        BoardView v;
        v.device = static_cast<int>(d);
        v.pose = static_cast<int>(p);
        v.label = label;
        v.points_in_board_mm = board[p];
        v.pixels_px = Rows<Eigen::Vector2d>(view, 2, what + "[" + std::to_string(p) + "]");
        SLSHADOW_THROW_IF(v.pixels_px.size() != v.points_in_board_mm.size(), what, "[", p,
                          "]: ", v.pixels_px.size(), " image points but object_points[", p,
                          "] has ", v.points_in_board_mm.size());
        input->views.push_back(std::move(v));
      }
      ++p;
    }
  }
}

}  // namespace

void BindCalibrate(py::module_& m) {
  m.def(
      "calibrate_camera",
      [](const py::object& images, const fs::path& target, const fs::path& out,
         const std::string& camera, SLSHADOW_COMMON_PARAMS) {
        const std::vector<std::string> args = PathList(images);
        nlohmann::json extra;
        extra["target"] = target.string();
        return Solve(SLSHADOW_COMMON_VALUES, out, nullptr, "calibrate_camera", extra,
                     [&](CalibrationInput* input, std::vector<ImageCheck>* checks, std::string* log,
                         nlohmann::json*) {
                       // apps/cmd_calibrate.cc RunCalibrateCamera
                       const TargetSpec spec = LoadTargetSpec(target);
                       const std::vector<fs::path> files = ImageFiles(args, "--images");
                       input->devices = {CalibrationDevice::Camera(camera)};
                       input->num_poses = static_cast<int>(files.size());
                       AddBoardViews(spec, files, 0, input, checks);
                       *log += pipeline::DescribeBoardDetections(*checks);
                     });
      },
      py::arg("images"), py::arg("target"), py::arg("out"), py::kw_only(),
      py::arg("camera") = "camera", SLSHADOW_COMMON_ARGS,
      (std::string("`slshadow calibrate camera`: detects the target (a target file, "
                   "docs/formats.md) in the board images (a folder or a list of files), "
                   "calibrates one camera and writes the rig (out), its report folder and "
                   "optionally an OpenCV file.") +
       kCommonDoc)
          .c_str());

  m.def(
      "calibrate_stereo",
      [](const py::object& left, const py::object& right, const fs::path& target,
         const fs::path& out, const std::string& left_name, const std::string& right_name,
         SLSHADOW_COMMON_PARAMS) {
        const std::vector<std::string> left_args = PathList(left), right_args = PathList(right);
        nlohmann::json extra;
        extra["target"] = target.string();
        return Solve(SLSHADOW_COMMON_VALUES, out, nullptr, "calibrate_stereo", extra,
                     [&](CalibrationInput* input, std::vector<ImageCheck>* checks, std::string* log,
                         nlohmann::json*) {
                       // apps/cmd_calibrate.cc RunCalibrateStereo
                       const TargetSpec spec = LoadTargetSpec(target);
                       const auto lf = ImageFiles(left_args, "--left"),
                                  rf = ImageFiles(right_args, "--right");
                       SLSHADOW_THROW_IF(
                           lf.size() != rf.size(), "stereo: ", lf.size(), " left images but ",
                           rf.size(),
                           " right images; give the same poses in the same (name) order");
                       SLSHADOW_THROW_IF(left_name == right_name,
                                         "stereo: --left-name and --right-name must differ (got '",
                                         left_name, "')");
                       input->devices = {CalibrationDevice::Camera(left_name),
                                         CalibrationDevice::Camera(right_name)};
                       input->num_poses = static_cast<int>(lf.size());
                       AddBoardViews(spec, lf, 0, input, checks);
                       AddBoardViews(spec, rf, 1, input, checks);
                       *log += pipeline::DescribeBoardDetections(*checks);
                     });
      },
      py::arg("left"), py::arg("right"), py::arg("target"), py::arg("out"), py::kw_only(),
      py::arg("left_name") = "left", py::arg("right_name") = "right", SLSHADOW_COMMON_ARGS,
      (std::string("`slshadow calibrate stereo`: two cameras and their relative pose from image "
                   "pairs (left and right: folders or lists of files, pairs in name order; the "
                   "left camera defines the rig frame).") +
       kCommonDoc)
          .c_str());

  m.def(
      "calibrate_projector",
      [](const py::object& captures, const py::handle& patterns_arg, const fs::path& target,
         const fs::path& out, const std::string& camera, const std::optional<fs::path>& camera_rig,
         SLSHADOW_PROCAM_PARAMS, SLSHADOW_COMMON_PARAMS) {
        const Procam procam = SLSHADOW_PROCAM_VALUES;
        const std::vector<std::string> folders = PathList(captures);
        std::string patterns_path = "patterns";
        if (py::isinstance<py::str>(patterns_arg) || py::hasattr(patterns_arg, "__fspath__"))
          patterns_path = FsPath(patterns_arg);
        const PatternSpec patterns = PatternSpecFromObject(patterns_arg, "patterns");
        nlohmann::json extra;
        extra["target"] = target.string();
        extra["patterns"] = PatternSpecToJson(patterns);
        return Solve(SLSHADOW_COMMON_VALUES, out, &procam, "calibrate_projector", extra,
                     [&](CalibrationInput* input, std::vector<ImageCheck>* checks, std::string* log,
                         nlohmann::json*) {
                       // apps/cmd_calibrate.cc RunCalibrateProjector
                       const ProcamInputOptions options = procam.Options();
                       const TargetSpec spec = LoadTargetSpec(target);
                       input->devices = {
                           CalibrationDevice::Camera(camera),
                           CalibrationDevice::Projector("projector", patterns.projector_width,
                                                        patterns.projector_height)};
                       if (camera_rig) {
                         const Rig known = LoadRig(*camera_rig);
                         input->devices[0].initial = known.cameras.at(0).model;
                         input->devices[0].hold_intrinsics = true;
                       }
                       input->num_poses = static_cast<int>(folders.size());
                       std::vector<std::vector<fs::path>> files;
                       for (const auto& folder : folders)
                         files.push_back(ImageFiles({folder}, "--captures"));
                       std::vector<std::string> skipped;
                       AddProcamCaptures(patterns, patterns_path, spec, files, folders, options,
                                         input, checks, &skipped);
                       for (const auto& s : skipped) *log += s + "\n";
                       *log += pipeline::DescribeBoardDetections(*checks);
                     });
      },
      py::arg("captures"), py::arg("patterns"), py::arg("target"), py::arg("out"), py::kw_only(),
      py::arg("camera") = "camera", py::arg("camera_rig") = py::none(), SLSHADOW_PROCAM_ARGS,
      SLSHADOW_COMMON_ARGS,
      (std::string("`slshadow calibrate projector`: a camera and the projector from fringe "
                   "captures of the board (captures: one folder per board pose with the camera's "
                   "images in sequence order; patterns: a PatternSpec, dict or spec file coding "
                   "x and y with a white frame). camera_rig: a rig whose first camera's "
                   "intrinsics are held. shadow_threshold, contrast_threshold: decoding; window: "
                   "the local homography's half window (camera px); select_model: choose the "
                   "distortion models by leave-one-pose-out; principal_point_inside: bound each "
                   "principal point to its image.") +
       kCommonDoc)
          .c_str());

  m.def(
      "calibrate_rig",
      [](const py::object& imagesets, const fs::path& target, const fs::path& out,
         SLSHADOW_PROCAM_PARAMS, SLSHADOW_COMMON_PARAMS) {
        const Procam procam = SLSHADOW_PROCAM_VALUES;
        std::vector<std::string> dirs;
        for (const py::handle item : imagesets) {
          dirs.push_back(py::isinstance<PyImageSet>(item)
                             ? item.cast<const PyImageSet&>().image_set.dir().string()
                             : FsPath(item));
        }
        nlohmann::json extra;
        extra["target"] = target.string();
        return Solve(SLSHADOW_COMMON_VALUES, out, &procam, "calibrate_rig", extra,
                     [&](CalibrationInput* input, std::vector<ImageCheck>* checks, std::string* log,
                         nlohmann::json*) {
                       // apps/cmd_calibrate.cc RunCalibrateRig
                       const ProcamInputOptions options = procam.Options();
                       const TargetSpec spec = LoadTargetSpec(target);
                       *input = ProcamInputFromImageSets(dirs, spec, options, checks);
                       *log += pipeline::DescribeBoardDetections(*checks);
                     });
      },
      py::arg("imagesets"), py::arg("target"), py::arg("out"), py::kw_only(), SLSHADOW_PROCAM_ARGS,
      SLSHADOW_COMMON_ARGS,
      (std::string("`slshadow calibrate rig`: every camera and the projector from ImageSets of "
                   "the board (imagesets: one ImageSet or folder per board pose, each with the "
                   "rig's cameras and a pattern spec in its manifest). Options as "
                   "calibrate_projector's.") +
       kCommonDoc)
          .c_str());

  m.def(
      "calibrate_corners",
      [](const py::object& object_points, const py::object& image_points,
         const py::object& image_size, const fs::path& out, const std::string& camera,
         const py::object& labels, SLSHADOW_COMMON_PARAMS) {
        // Read here, with the GIL (the arrays are Python's); solved as the commands solve.
        auto input = std::make_shared<CalibrationInput>();
        auto checks = std::make_shared<std::vector<ImageCheck>>();
        CornersInput(object_points, image_points, image_size, camera, labels, input.get(),
                     checks.get());
        return Solve(SLSHADOW_COMMON_VALUES, out, nullptr, "calibrate_corners", nlohmann::json{},
                     [&](CalibrationInput* in, std::vector<ImageCheck>* ch, std::string* log,
                         nlohmann::json*) {
                       *in = std::move(*input);
                       *ch = std::move(*checks);
                       *log += pipeline::DescribeBoardDetections(*ch);
                     });
      },
      py::arg("object_points"), py::arg("image_points"), py::arg("image_size"), py::arg("out"),
      py::kw_only(), py::arg("camera") = "camera", py::arg("labels") = py::none(),
      SLSHADOW_COMMON_ARGS,
      (std::string("Calibration from corners detected by the caller (OpenCV's calibrateCamera / "
                   "stereoCalibrate inputs), solved and written as `slshadow calibrate` does. "
                   "object_points: per board pose an (N, 3) array (board frame, mm); "
                   "image_points: per pose an (N, 2) array (px, OpenCV's convention) or None "
                   "(board not seen), for one camera named `camera`, or a dict camera name -> "
                   "such a list for several (the first defines the rig frame); image_size: "
                   "(width, height), or a dict per camera; labels: a name per pose for the "
                   "report (default pose_<i>).") +
       kCommonDoc)
          .c_str());

  m.def(
      "detect_target",
      [](const py::handle& image, const fs::path& target) {
        const TargetSpec spec = LoadTargetSpec(target);
        TargetDetection det;
        if (py::isinstance<py::array>(image)) {
          py::object keep;
          const py::array a = py::reinterpret_borrow<py::array>(image);
          const cv::Mat mat = ImageFromArray(a, "detect_target: image", &keep);
          py::gil_scoped_release release;
          det = DetectTarget(spec, mat);
        } else {
          const std::string path = FsPath(image);
          py::gil_scoped_release release;
          det = DetectTargetInFile(spec, path);
        }
        const std::vector<Eigen::Vector3d> board = BoardPoints(spec);
        std::vector<Eigen::Vector3d> object;
        for (const int id : det.point_ids) object.push_back(board[static_cast<size_t>(id)]);
        py::dict d;
        d["found"] = det.found;
        d["reason"] = det.reason;
        d["width"] = det.width;
        d["height"] = det.height;
        d["image_points"] = VectorToArray<double>(std::move(det.pixels_px), 2);
        d["object_points"] = VectorToArray<double>(std::move(object), 3);
        d["point_ids"] = VectorToArray<int>(std::move(det.point_ids), 0);
        d["saturated_fraction"] = det.saturated_fraction;
        return d;
      },
      py::arg("image"), py::arg("target"),
      "The target (a target file, docs/formats.md) found in one image (a 2-D uint8/uint16 array "
      "or an image file) as `slshadow calibrate` finds it: a dict with found, reason (why not), "
      "width, height, image_points (N, 2) px, object_points (N, 3) mm in the board frame, "
      "point_ids (N,) into the board's points, saturated_fraction. The GIL is released while it "
      "runs.");

  m.def(
      "calibrate_refine",
      [](const py::handle& rig, const py::handle& imageset, const fs::path& out,
         const std::string& camera, const std::string& stereo, double baseline_mm,
         const std::optional<std::vector<double>>& known_distance, bool refine_focal) {
        // apps/cmd_calibrate.cc RunCalibrateRefine
        pipeline::RefineFromScanRequest r;
        r.rig = FsPath(rig);
        r.scan = py::isinstance<PyImageSet>(imageset)
                     ? imageset.cast<const PyImageSet&>().image_set.dir()
                     : fs::path(FsPath(imageset));
        r.out = out;
        r.camera = camera;
        r.stereo = stereo;
        if (known_distance) {
          SLSHADOW_THROW_IF(known_distance->size() != 5,
                            "calibrate_refine: known_distance: expected (u1, v1, u2, v2, mm) (got ",
                            known_distance->size(), " numbers)");
          r.known_distance = *known_distance;
        }
        r.refine.refine_focal = refine_focal;
        r.refine.known_baseline_mm = baseline_mm;
        r.decode = DecodeOptions{};
        r.decode.shadow_threshold = 12;  // the command's --shadow-threshold default (ProcamArgs)
        r.decode.contrast_threshold = 4;
        r.decode.Check();
        RefineResult result;
        {
          py::gil_scoped_release release;
          result = pipeline::RefineRigFromScan(r);
        }
        py::dict d;
        d["rig"] = LoadRig(out);
        d["message"] = result.message;
        d["before"] = py::dict(
            py::arg("count") = result.before.count, py::arg("median_px") = result.before.median_px,
            py::arg("p95_px") = result.before.p95_px, py::arg("rms_px") = result.before.rms_px);
        d["after"] = py::dict(
            py::arg("count") = result.after.count, py::arg("median_px") = result.after.median_px,
            py::arg("p95_px") = result.after.p95_px, py::arg("rms_px") = result.after.rms_px);
        d["baseline_mm"] = result.baseline_mm;
        d["scale_verified"] = result.scale_verified;
        d["focal_scale"] = result.focal_scale;
        return d;
      },
      py::arg("rig"), py::arg("imageset"), py::arg("out"), py::kw_only(), py::arg("camera") = "",
      py::arg("stereo") = "", py::arg("baseline_mm") = 0.0, py::arg("known_distance") = py::none(),
      py::arg("refine_focal") = false,
      "`slshadow calibrate refine`: checks the rig file against a scan (an ImageSet or its "
      "folder) and re-estimates the projector's pose (or with stereo=NAME that camera's, "
      "relative to `camera`), writing the refined rig to out. baseline_mm or known_distance "
      "(u1, v1, u2, v2, mm) fix the scale. Returns a dict: rig (the written Rig), message (what "
      "the command prints), before / after (epipolar residuals: count, median_px, p95_px, "
      "rms_px), baseline_mm, scale_verified, focal_scale. The GIL is released while it runs.");

  m.def(
      "calibrate_import",
      [](const fs::path& opencv_file, const std::optional<fs::path>& out,
         const std::optional<std::pair<int, int>>& image_size,
         const std::optional<std::pair<int, int>>& projector_size,
         const std::optional<std::string>& map) {
        // apps/cmd_calibrate.cc RunCalibrateImport
        const auto [w, h] = image_size.value_or(std::pair<int, int>{0, 0});
        const auto [pw, ph] = projector_size.value_or(std::pair<int, int>{0, 0});
        const OpenCvNodeMap node_map = map ? ParseOpenCvNodeMap(*map) : OpenCvNodeMap{};
        const Rig rig = ReadOpenCvCalibration(opencv_file, w, h, pw, ph, node_map);
        if (out) SaveRig(rig, *out);
        return rig;
      },
      py::arg("opencv_file"), py::arg("out") = py::none(), py::kw_only(),
      py::arg("image_size") = py::none(), py::arg("projector_size") = py::none(),
      py::arg("map") = py::none(),
      "`slshadow calibrate import`: a rig from an OpenCV calibration file (calibrateCamera / "
      "stereoCalibrate / procam layouts; map: 'K1=NODE,D1=NODE,...' for another layout); "
      "image_size / projector_size (width, height) where the file has none. Writes it to out "
      "when given; returns the Rig.");

  m.def(
      "calibrate_export",
      [](const py::handle& rig, const fs::path& out) {
        // apps/cmd_calibrate.cc RunCalibrateExport
        WriteOpenCvCalibration(py::isinstance<Rig>(rig) ? rig.cast<Rig>() : LoadRig(FsPath(rig)),
                               out);
      },
      py::arg("rig"), py::arg("out"),
      "`slshadow calibrate export`: writes a rig (a Rig or a rig file) as an OpenCV "
      "calibration file (.yml / .xml: camera_matrix ... or M1 D1 M2 D2 R T).");
}

#undef SLSHADOW_COMMON_PARAMS
#undef SLSHADOW_COMMON_VALUES
#undef SLSHADOW_COMMON_ARGS
#undef SLSHADOW_PROCAM_PARAMS
#undef SLSHADOW_PROCAM_VALUES
#undef SLSHADOW_PROCAM_ARGS

}  // namespace slshadow::python
