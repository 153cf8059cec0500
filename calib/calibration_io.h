// Calibration results in and out: the rig they make, the evidence kept with it (so covariance,
// projection uncertainty and cross-validation can be recomputed later, as mrcal's
// optimization_inputs), and OpenCV cv::FileStorage files (YAML or XML) so users move between
// slshadow and OpenCV tools. Formats: docs/formats.md, "Calibration evidence" and "OpenCV
// calibration files".
#pragma once

#include <filesystem>
#include <optional>
#include <string>
#include <vector>

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

// The p95 projection uncertainty (px) the evidence keeps for `device`: the larger of
// `projection_uncertainty` and `projection_uncertainty_view_correlated` (docs/formats.md
// "Calibration evidence"); NaN when the evidence has neither (e.g. a rig written by hand).
double EvidenceProjectionUncertaintyP95Px(const nlohmann::json& evidence,
                                          const std::string& device);

// OpenCV calibration files (cv::FileStorage, .yml/.yaml/.xml/.json).
//
// Writing: one camera as OpenCV's calibration sample writes it (image_width, image_height,
// camera_matrix, distortion_coefficients); two or more devices as stereo_calib.cpp names them
// (M1, D1, M2, D2, R, T with x_in_2 = R x_in_1 + T in the rig's length unit, mm), plus
// image_width_<i>/image_height_<i>; devices beyond the second as M3/D3/R3/T3 and so on, each
// relative to device 1. The projector, when present, is the last device.
void WriteOpenCvCalibration(const Rig& rig, const std::filesystem::path& path);

// Node names of a calibration file of one or two cameras and optionally a projector, for
// ReadOpenCvCalibration: the built-in layouts are such maps, and a user names the nodes of any
// other layout with one.
struct OpenCvNodeMap {
  std::string k1, d1;  // first camera: 3x3 camera matrix, distortion (k1 k2 p1 p2 [k3]); required
  std::string k2, d2;  // second camera (both or neither)
  std::string r, t;    // x_in_2 = R x_in_1 + T: 3x3 matrix or Rodrigues vector, 3-vector (mm)
  std::string size1, size2;  // image sizes as [width, height] (cv::Size) or a 1x2 matrix; optional,
                             // size2 defaults to size1
  // The projector, an inverse camera (both or neither), its pose x_in_proj = RP x_in_1 + TP
  // (required with KP) and its size (optional: else the projector size given to the reader).
  std::string kp, dp, rp, tp, size_p;
  bool Empty() const { return k1.empty(); }
};
// Parses "K1=cam_K,D1=cam_D,K2=...,D2=...,R=...,T=...,size1=...,size2=...,KP=...,DP=...,RP=...,
// TP=...,sizeP=..." (keys as shown, any order). Throws slshadow::Error naming the bad entry and the
// known keys.
OpenCvNodeMap ParseOpenCvNodeMap(const std::string& text);

// Reading accepts those layouts and others in common use:
//   - kamino410/procam-calibration's procam layout (cam_int, cam_dist, proj_int, proj_dist,
//     rotation or its misspelling roration, translation, img_shape);
//   - the stereo structured-light sample's (cam1_intrinsics, cam1_distorsion or cam1_distortion,
//     cam2_*, R, T, cam1_size / cam2_size);
//   - a binocular layout (M1, D1, M2, D2, Rlr, Tlr, image size in S), and its camera + projector
//     form: Rlp, Tlp the projector's pose, the projector the one M<k>, D<k> (k = 2..9) that is
//     not a camera's (e.g. M4, D4); several candidates throw (name them with the node map);
//   - any layout whose nodes `node_map` names (it then takes precedence).
// Matrices may be !!opencv-matrix nodes or plain number lists. Image sizes come from the file
// when present (stereo_calib's layout: image_width_<i>, else S), else from `default_width` x
// `default_height`, a projector's from `projector_width` x `projector_height` (throws when
// neither gives one). The working distance is derived as OpenCvImportOptions below says, when
// the rig's devices allow it, else Rig's default. A file of no known layout throws an error
// that lists the nodes it has. Throws slshadow::Error naming the file and the missing or
// malformed node.
Rig ReadOpenCvCalibration(const std::filesystem::path& path, int default_width = 0,
                          int default_height = 0, int projector_width = 0, int projector_height = 0,
                          const OpenCvNodeMap& node_map = {});

// `slshadow calibrate import`: ReadOpenCvCalibration, and what a user must hear about it.
struct OpenCvImportOptions {
  int image_width = 0, image_height = 0;  // camera image size where the file has none; 0: none
  int projector_width = 0, projector_height = 0;  // projector size where the file has none
  OpenCvNodeMap node_map;                         // empty: the known layouts
  // The rig's working distance, mm; 0: derived. Derived: the depth along the first camera's axis
  // of the midpoint of the shortest segment between the rays through the image centres of the
  // first camera and of the projector (else the second camera), when they are not parallel
  // (0.01 degree) and meet in front of both; else Rig's default, with a warning.
  double working_distance_mm = 0;
  void Check() const;  // throws slshadow::Error naming the field
};
struct OpenCvImport {
  Rig rig;
  // Top-level nodes of the file the rig was not read from, with their shapes: "M4 (3x3 matrix)".
  std::vector<std::string> unused_nodes;
  // Lines for the user, each starting "warning: ": the unused nodes, a working distance that
  // could not be derived.
  std::vector<std::string> warnings;
  std::string working_distance_source;  // "given (--working-distance-mm)", "where the rays ..."
};
// Reads the file as ReadOpenCvCalibration does, and refuses (slshadow::Error naming the file and
// both sizes) an image or projector size that a device's size in the file contradicts, and a
// projector size when no projector was imported (listing the nodes not read). Nothing is written.
OpenCvImport ImportOpenCvCalibration(const std::filesystem::path& path,
                                     const OpenCvImportOptions& options);

}  // namespace slshadow
