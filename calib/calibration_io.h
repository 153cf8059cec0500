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
Rig RigFromCalibration(const CalibrationInput& input, const CalibrationResult& result, const std::string& name);

// Everything needed to recompute a calibration and its uncertainty: the options, the devices,
// every observation (board points in mm and pixels), and the results derived from them (board
// poses, intrinsics covariance, summary, uncertainty and cross-validation statistics).
nlohmann::json CalibrationEvidenceToJson(const CalibrationInput& input, const CalibrationOptions& options,
                                         const CalibrationResult& result,
                                         const std::optional<CrossValidation>& cross_validation = std::nullopt);

struct CalibrationEvidence {
  CalibrationInput input;
  CalibrationOptions options;
};
// Reads the inputs back (the derived results are recomputed by calling Calibrate). `file` names
// the source in error messages. Throws slshadow::Error naming the field on malformed evidence.
CalibrationEvidence CalibrationEvidenceFromJson(const nlohmann::json& json, const std::string& file);

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

// Reading accepts those layouts, and the procam layout of kamino410/procam-calibration
// (cam_int, cam_dist, proj_int, proj_dist, rotation or its misspelling roration, translation,
// img_shape). Image sizes come from the file when present, else from `default_width` x
// `default_height` (throws when neither gives one). Throws slshadow::Error naming the file and
// the missing or malformed node.
Rig ReadOpenCvCalibration(const std::filesystem::path& path, int default_width = 0, int default_height = 0,
                          int projector_width = 0, int projector_height = 0);

}  // namespace slshadow
