#include "workflows/pipeline/calibrate.h"

#include <algorithm>
#include <cstdio>
#include <optional>
#include <utility>

#include "calib/calibration_io.h"
#include "calib/model_selection.h"
#include "calib/report.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "core/string_printf.h"
#include "patterns/pattern_spec.h"

namespace slshadow::pipeline {
namespace {

namespace fs = std::filesystem;

std::string DescribeModelSelection(const ModelSelection& selection) {
  std::string text = "model selection (leave-one-pose-out, projector corners):\n";
  for (const auto& s : selection.scores) {
    text += StringPrintf("  %-45s fit %.4f px, predicted %.4f px (%d corners)\n", s.name.c_str(),
                         s.fit_rms_px, s.prediction_rms_px, s.num_predicted);
  }
  text += "  chosen: " + selection.scores[selection.chosen].name + "\n";
  return text;
}

}  // namespace

std::string DescribeBoardDetections(const std::vector<ImageCheck>& checks) {
  std::string text;
  int found = 0;
  for (const auto& c : checks) {
    if (c.found) {
      ++found;
    } else {
      text += "not found: " + c.label + ": " + c.reason + "\n";
    }
  }
  return text + StringPrintf("board found in %d of %zu images\n", found, checks.size());
}

void CalibrateAndWrite(CalibrationInput input, const std::vector<ImageCheck>& checks,
                       const CalibrateWriteOptions& options, nlohmann::json extra,
                       const PrintFn& print) {
  options.solve.Check();
  CalibrationResult result;
  if (options.select_model) {
    ModelSelection selection = SelectDistortionModels(&input, options.solve);
    print(DescribeModelSelection(selection));
    extra["model_selection"] = ModelSelectionToJson(selection);
    result = std::move(selection.scores[selection.chosen].result);
  } else {
    result = Calibrate(input, options.solve);
  }
  std::optional<CrossValidation> cv;
  if (options.cross_validate) {
    if (CanCrossValidate(input)) {
      cv = CrossValidate(input, options.solve);
    } else {
      print(
          "cross-validation skipped: needs at least 2 views per device among the even and among "
          "the odd poses\n");
    }
  }
  GuidanceOptions go;
  go.min_views = options.min_views;
  const std::vector<Finding> findings = ReviewCalibration(input, result, checks, go);
  Rig rig = RigFromCalibration(input, result, options.rig_name);
  rig.calibration = CalibrationEvidenceToJson(input, options.solve, result, cv);
  SaveRig(rig, options.rig_out);
  if (!options.opencv_out.empty()) WriteOpenCvCalibration(rig, options.opencv_out);
  CalibrationReport report;
  report.input = &input;
  report.options = &options.solve;
  report.result = &result;
  report.cross_validation = cv;
  report.findings = findings;
  report.extra = std::move(extra);
  WriteCalibrationReport(options.report_dir, report);

  std::string text = result.summary.BriefReport() + "\n";
  for (const auto& d : result.devices) {
    const auto& m = d.model;
    text += StringPrintf(
        "  %s: %dx%d fx %.3f fy %.3f cx %.3f cy %.3f k1 %.5f k2 %.5f p1 %.6f p2 %.6f k3 %.5f\n",
        d.name.c_str(), m.width, m.height, m.fx(), m.fy(), m.cx(), m.cy(), m.k1(), m.k2(), m.p1(),
        m.p2(), m.k3());
  }
  for (const auto& s : result.summary.devices) {
    text +=
        StringPrintf("  %s: RMS %.4f px over %d points\n", s.name.c_str(), s.rms_px, s.num_points);
  }
  for (const auto& b : result.summary.bounds_active) {
    text += "  --principal-point-inside: " + b +
            "; the data pull it outside the image (compare the fit without the flag)\n";
  }
  for (const auto& f : findings) text += f.Text() + "\n";
  text += "wrote " + options.rig_out.string() + " and report " + options.report_dir.string() + "\n";
  print(text);
}

RefineResult RefineRigFromScan(const RefineFromScanRequest& request) {
  const Rig rig = LoadRig(request.rig);
  const ImageSet scan = ImageSet::Open(request.scan);
  const std::string rig_file = request.rig.string(), scan_dir = request.scan.string();
  const std::string cam = request.camera.empty() ? rig.cameras.at(0).name : request.camera;
  const int index = rig.CameraIndex(cam);
  SLSHADOW_THROW_IF(index < 0, rig_file, ": no camera named '", cam, "'");
  const PatternSpec patterns = PatternSpecFromConfig(
      ConfigNode::FromJson(scan.patterns(), (request.scan / "manifest.json").string(), "patterns"));
  SLSHADOW_THROW_IF(!patterns.code_x || !patterns.code_y, scan_dir,
                    ": patterns must code both projector axes to check the calibration");
  SLSHADOW_THROW_IF(
      request.stereo.empty() && !rig.projector, rig_file, ": rig '", rig.name,
      "' has no projector: refine the pose of one camera against another with --stereo NAME");
  const ProjectorMap map = DecodePatterns(patterns, scan.LoadCamera(cam), request.decode);
  RefineOptions ro = request.refine;
  std::optional<ProjectorMap> map_b;
  if (!request.stereo.empty()) {
    const int index_b = rig.CameraIndex(request.stereo);
    SLSHADOW_THROW_IF(index_b < 0, rig_file, ": no camera named '", request.stereo, "' (--stereo)");
    map_b = DecodePatterns(patterns, scan.LoadCamera(request.stereo), request.decode);
  }
  if (!request.known_distance.empty()) {
    const std::vector<double>& v = request.known_distance;
    SLSHADOW_THROW_IF(v.size() != 5, "--known-distance: expected U1,V1,U2,V2,MM (got ", v.size(),
                      " numbers)");
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
  if (request.stereo.empty()) {
    r = RefineProjectorPose(rig, index, SampleCorrespondences(map), ro);
  } else {
    r = RefineStereoPose(rig, index, rig.CameraIndex(request.stereo),
                         StereoCorrespondences(map, *map_b), ro);
  }
  // A refused solution writes nothing: the error says why.
  SLSHADOW_THROW_IF(r.rejected, rig_file, ": calibrate refine: ", r.message);
  Rig out = r.rig;
  out.calibration["refine"] = RefineRecordToJson(r, scan_dir, cam, request.stereo);
  SaveRig(out, request.out);
  return r;
}

TurntableResult CalibrateTurntableAndWrite(const CalibrateTurntableRequest& request,
                                           const PrintFn& print) {
  Rig rig = LoadRig(request.rig);
  const TargetSpec spec = LoadTargetSpec(request.target);
  std::vector<double> angles = request.commanded_deg;
  if (angles.empty()) {
    for (const auto& f : request.folders) angles.push_back(CommandedAngleFromFolderName(f));
  }
  SLSHADOW_THROW_IF(angles.size() != request.folders.size(), "--angles: ", angles.size(),
                    " angle(s) for ", request.folders.size(), " --images folder(s)");
  request.options.Check();
  std::vector<ImageCheck> checks;
  const TurntableInput input =
      TurntableInputFromFolders(rig, spec, request.folders, angles, &checks);
  for (const auto& c : checks) {
    if (!c.found)
      print(StringPrintf("note: %s: no board (%s)\n", c.label.c_str(), c.reason.c_str()));
  }
  const TurntableResult result = CalibrateTurntable(input, request.options);
  print(result.FullReport());
  if (!result.converged)
    print("warning: the solver did not converge (" + result.termination + ")\n");
  if (result.rms_px > request.max_rms_px) {
    print(StringPrintf(
        "warning: RMS %.4f px is above %.4g px: did the board move on the table, is an angle "
        "wrong, or does the rig no longer fit the cameras?\n",
        result.rms_px, request.max_rms_px));
  }
  const TurntableAxis& a = result.axis;
  print(StringPrintf(
      "axis (rig frame, 1-sigma):\n"
      "  direction   %.6f %.6f %.6f  +- %.5f deg\n"
      "  point       %.4f %.4f %.4f mm  +- %.5f mm (perpendicular to the axis)\n"
      "  angle scale %.7f  +- %.2g (true degrees per commanded degree)\n"
      "  offset      0 deg (by definition: angles count from the table at commanded 0)\n",
      a.direction_in_rig.x(), a.direction_in_rig.y(), a.direction_in_rig.z(), a.sigma_direction_deg,
      a.point_in_rig_mm.x(), a.point_in_rig_mm.y(), a.point_in_rig_mm.z(), a.sigma_point_mm,
      a.angle_scale, a.sigma_angle_scale));
  rig.turntable = a;
  SaveRig(rig, request.out);
  print("wrote " + request.out.string() + "\n");
  return result;
}

}  // namespace slshadow::pipeline
