// Calibration results in and out: the rig they make, the evidence kept with it (so covariance,
// projection uncertainty and cross-validation can be recomputed later, as mrcal's
// optimization_inputs), and OpenCV cv::FileStorage files (YAML or XML) so users move between
// slshadow and OpenCV tools. Formats: docs/formats.md, "Calibration evidence" and "OpenCV
// calibration files".
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include <nlohmann/json.hpp>

#include "calib/calibration.h"
#include "calib/uncertainty.h"
#include "core/rig.h"

namespace slshadow {

// A rig from a calibration: devices marked is_projector become the rig's projector (at most one;
// throws otherwise), the others its cameras in input order; the rig frame is device 0's frame.
Rig RigFromCalibration(const CalibrationInput& input, const CalibrationResult& result,
                       const std::string& name);

// Everything needed to recompute a calibration and its uncertainty: the options, the devices,
// every observation (board points in mm and pixels), and the results derived from them (board
// poses, intrinsics covariance, summary, uncertainty and cross-validation statistics).
nlohmann::json CalibrationEvidenceToJson(
    const CalibrationInput& input, const CalibrationOptions& options,
    const CalibrationResult& result,
    const std::optional<CrossValidation>& cross_validation = std::nullopt);

struct CalibrationEvidence {
  CalibrationInput input;
  CalibrationOptions options;
};
// Reads the inputs back (the derived results are recomputed by calling Calibrate). `file` names
// the source in error messages. Throws slshadow::Error naming the field on malformed evidence.
CalibrationEvidence CalibrationEvidenceFromJson(const nlohmann::json& json,
                                                const std::string& file);

nlohmann::json CalibrationOptionsToJson(const CalibrationOptions& options);
CalibrationOptions CalibrationOptionsFromJson(const nlohmann::json& json, const std::string& file);

// OpenCV calibration files (cv::FileStorage, .yml/.yaml/.xml/.json).
//
// Writing: one camera as OpenCV's calibration sample writes it (image_width, image_height,
// camera_matrix, distortion_coefficients); two or more devices as stereo_calib.cpp names them
// (M1, D1, M2, D2, R, T with x_in_2 = R x_in_1 + T in the rig's length unit, mm), plus
// image_width_<i>/image_height_<i>; devices beyond the second as M3/D3/R3/T3 and so on, each
// relative to device 1. The projector, when present, is the last device.
void WriteOpenCvCalibration(const Rig& rig, const std::filesystem::path& path);

// Node names of a one- or two-camera calibration file, for ReadOpenCvCalibration: the built-in
// layouts are such maps, and a user names the nodes of any other layout with one.
struct OpenCvNodeMap {
  std::string k1, d1;  // first camera: 3x3 camera matrix, distortion (k1 k2 p1 p2 [k3]); required
  std::string k2, d2;  // second camera (both or neither)
  std::string r, t;    // x_in_2 = R x_in_1 + T: 3x3 matrix or Rodrigues vector, 3-vector (mm)
  std::string size1, size2;  // image sizes as [width, height] (cv::Size) or a 1x2 matrix; optional,
                             // size2 defaults to size1
  bool Empty() const { return k1.empty(); }
};
// Parses "K1=cam_K,D1=cam_D,K2=...,D2=...,R=...,T=...,size1=...,size2=..." (keys as shown, any
// order). Throws slshadow::Error naming the bad entry and the known keys.
OpenCvNodeMap ParseOpenCvNodeMap(const std::string& text);

// Reading accepts those layouts and others in common use:
//   - kamino410/procam-calibration's procam layout (cam_int, cam_dist, proj_int, proj_dist,
//     rotation or its misspelling roration, translation, img_shape);
//   - the stereo structured-light sample's (cam1_intrinsics, cam1_distorsion or cam1_distortion,
//     cam2_*, R, T, cam1_size / cam2_size);
//   - a binocular layout (M1, D1, M2, D2, Rlr, Tlr, image size in S);
//   - any layout of one or two cameras whose nodes `node_map` names (it then takes precedence).
// Matrices may be !!opencv-matrix nodes or plain number lists. Image sizes come from the file
// when present, else from `default_width` x `default_height` (throws when neither gives one). A
// file of no known layout throws an error that lists the nodes it has. Throws slshadow::Error
// naming the file and the missing or malformed node.
Rig ReadOpenCvCalibration(const std::filesystem::path& path, int default_width = 0,
                          int default_height = 0, int projector_width = 0, int projector_height = 0,
                          const OpenCvNodeMap& node_map = {});

}  // namespace slshadow
