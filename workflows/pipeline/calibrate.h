// The calibration workflows behind `slshadow calibrate` (apps/cmd_calibrate.cc only parses the
// arguments into these): solve a prepared calibration input and write the rig, its OpenCV file and
// the report folder; refine a calibrated rig's pose from one scan of a scene and write the rig.
#pragma once

#include <filesystem>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "calib/calibration.h"
#include "calib/calibration_input.h"
#include "calib/guidance.h"
#include "calib/refine.h"
#include "calib/turntable.h"
#include "patterns/codec.h"

namespace slshadow::pipeline {

// A line (or lines) of text for the user, as the work goes (the command line prints it).
using PrintFn = std::function<void(const std::string&)>;

struct CalibrateWriteOptions {
  CalibrationOptions solve;
  // Choose the distortion models by leave-one-pose-out (calib/model_selection.h
  // SelectDistortionModels; the chosen candidate's all-pose solve is kept).
  bool select_model = false;
  // Also calibrate the even and the odd poses apart (calib CrossValidate), when each half has
  // enough views; otherwise a line says it was skipped.
  bool cross_validate = true;
  int min_views = 10;  // fewer views per device are reported as too few (ReviewCalibration)
  std::string rig_name = "calibrated";
  std::filesystem::path rig_out;     // the rig YAML, with the calibration evidence
  std::filesystem::path report_dir;  // summary.json, report.txt, charts
  std::filesystem::path opencv_out;  // an OpenCV FileStorage file too; empty: none
};

// Calibrates `input` (its board detections `checks`, one per image, for the review), reviews the
// result, writes the rig, the OpenCV file and the report (`extra`: what the command adds to the
// report's JSON: target, patterns, ...), and prints as it goes: the model-selection table, the
// summary, each device's intrinsics and RMS, active principal-point bounds, the review's findings
// and what was written. Throws slshadow::Error on a calibration that cannot be solved or a file
// that cannot be written.
void CalibrateAndWrite(CalibrationInput input, const std::vector<ImageCheck>& checks,
                       const CalibrateWriteOptions& options, nlohmann::json extra,
                       const PrintFn& print);

// "not found: <image>: <reason>" for each image without a board, then "board found in N of M
// images".
std::string DescribeBoardDetections(const std::vector<ImageCheck>& checks);

struct RefineFromScanRequest {
  std::filesystem::path rig, scan, out;  // the rig YAML, the scan's image set, the rig to write
  std::string camera;  // the camera whose decoded scan is used; empty: the rig's first
  // A second camera: refine its pose against `camera` (stereo) instead of the projector's.
  std::string stereo;
  // Optional: two pixels of `camera` (u1, v1, u2, v2) and the distance (mm) between the scene
  // points they see, fixing the scale.
  std::vector<double> known_distance;
  RefineOptions refine;  // known_distances filled from `known_distance`
  DecodeOptions decode;
};

// Decodes the scan (its patterns must code both projector axes), refines the projector's (or
// the stereo camera's) pose, writes the refined rig with its record under calibration.refine and
// returns the result. Throws slshadow::Error naming the file and what is wrong for a missing
// camera, a scan coding one axis, a rig without projector and no stereo camera, a known-distance
// pixel without a decoded correspondence, or a refused solution (nothing written then).
RefineResult RefineRigFromScan(const RefineFromScanRequest& request);

struct CalibrateTurntableRequest {
  std::filesystem::path rig, target, out;      // the calibrated rig, the board, the rig to write
  std::vector<std::filesystem::path> folders;  // one per table angle, one image per camera
  std::vector<double> commanded_deg;           // one per folder; empty: from the folder names
  TurntableOptions options;
  double max_rms_px = 1.0;  // a fit above this RMS is warned about
};

// `slshadow calibrate turntable`: reads the rig, the target and the images, calibrates the axis
// (calib/turntable.h), prints the boards not found, the fit's report, warnings (no convergence,
// RMS above max_rms_px) and the axis with its 1-sigma, and writes the rig with `turntable:`
// filled, atomically. Throws slshadow::Error on bad input (e.g. a count of angles that does not
// match the folders); nothing is written then.
TurntableResult CalibrateTurntableAndWrite(const CalibrateTurntableRequest& request,
                                           const PrintFn& print);

}  // namespace slshadow::pipeline
