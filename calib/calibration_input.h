// Building a CalibrationInput from images: the board detected in image files (one camera, or
// each camera of a stereo pair), and camera-projector poses decoded from fringe captures (folders
// of a camera's images, or ImageSets holding every camera). What `slshadow calibrate camera |
// stereo | projector | rig` read, so tests and other tools build the same input.
//
// Device and pose numbering: devices in the order they are added (device 0 defines the rig
// frame); pose p is the p-th file, capture folder or ImageSet of the list. Every image is checked
// (ImageCheck, one per image: board found or why not, saturation) for ReviewCalibration.
// Progress (core/progress.h, seen by an observer only): "detect" per image file, "decode" per
// capture folder or ImageSet.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "calib/calibration.h"
#include "calib/guidance.h"
#include "calib/projector.h"
#include "calib/target.h"
#include "patterns/codec.h"

namespace slshadow {

// The image files named by `args`: a file as given, a folder as its images (.png .jpg .jpeg .bmp
// .tif .tiff .pgm .ppm, extension case ignored) in name order. Throws slshadow::Error naming
// `what` (e.g. "--images") and the argument for a path that does not exist or a folder without
// images.
std::vector<std::filesystem::path> ImageFiles(const std::vector<std::string>& args,
                                              const std::string& what);

// Detects the target in each file and adds the found boards as views of `device` (pose = index in
// `files`); sets the device's image size from the first file when it is 0. Throws slshadow::Error
// when an image's size differs from the device's. Appends one ImageCheck per file.
void AddBoardViews(const TargetSpec& spec, const std::vector<std::filesystem::path>& files,
                   int device, CalibrationInput* input, std::vector<ImageCheck>* checks);

// One input per command of `slshadow calibrate`, from the image files its options name.
//
// camera: one camera `camera_name` from the board in `files` (pose p = files[p]).
CalibrationInput CameraInputFromImages(const TargetSpec& spec,
                                       const std::vector<std::filesystem::path>& files,
                                       const std::string& camera_name,
                                       std::vector<ImageCheck>* checks);
// stereo: two cameras, `left` defining the rig frame, from image pairs (pose p = left[p] and
// right[p]). Throws slshadow::Error when the lists differ in length or the names are equal.
CalibrationInput StereoInputFromImages(const TargetSpec& spec,
                                       const std::vector<std::filesystem::path>& left,
                                       const std::vector<std::filesystem::path>& right,
                                       const std::string& left_name, const std::string& right_name,
                                       std::vector<ImageCheck>* checks);

// Decoding and corner-carrying settings of the camera-projector inputs below.
struct ProcamInputOptions {
  DecodeOptions decode;
  LocalHomographyOptions local;
  void Check() const {
    decode.Check();
    local.Check();
  }
};

// A camera and a projector (devices 0 and 1; `input` must hold them) from one folder of images per
// board pose: `captures[p]` are the camera's images of `patterns` (read from `patterns_path`, named
// in errors) in sequence order, labelled `labels[p]`. The camera's image size is set from the first
// capture when it is 0. Throws slshadow::Error when a capture does not hold one image per pattern.
// Appends one ImageCheck per capture and prints nothing; corners skipped by the local homographies
// are returned in `skipped` ("<label>: skipped ...").
void AddProcamCaptures(const PatternSpec& patterns, const std::string& patterns_path,
                       const TargetSpec& spec,
                       const std::vector<std::vector<std::filesystem::path>>& captures,
                       const std::vector<std::string>& labels, const ProcamInputOptions& options,
                       CalibrationInput* input, std::vector<ImageCheck>* checks,
                       std::vector<std::string>* skipped);

// projector: a camera `camera_name` and a projector "projector" sized by `patterns`, from one
// folder (or file list, ImageFiles) per board pose in `capture_dirs` (pose p, labelled by its
// argument), as AddProcamCaptures reads them. With `known_camera` the camera's intrinsics are
// held at it (calibrate a projector against a calibrated camera), else estimated jointly.
CalibrationInput ProcamInputFromCaptures(
    const PatternSpec& patterns, const std::string& patterns_path, const TargetSpec& spec,
    const std::vector<std::string>& capture_dirs, const std::string& camera_name,
    const CameraModel* known_camera, const ProcamInputOptions& options,
    std::vector<ImageCheck>* checks, std::vector<std::string>* skipped);

// Every camera of the ImageSets and the projector, one ImageSet per board pose (each with its rig
// and pattern spec in its manifest): devices are the first ImageSet's cameras in its order, then
// the projector (named as in its rig, else "projector", sized by the pattern spec). Throws
// slshadow::Error when an ImageSet's cameras differ from the first one's.
CalibrationInput ProcamInputFromImageSets(const std::vector<std::string>& imagesets,
                                          const TargetSpec& spec, const ProcamInputOptions& options,
                                          std::vector<ImageCheck>* checks);

}  // namespace slshadow
