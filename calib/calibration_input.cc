#include "calib/calibration_input.h"

#include <algorithm>
#include <cctype>
#include <set>

#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/progress.h"
#include "patterns/pattern_spec.h"

namespace slshadow {

namespace fs = std::filesystem;

std::vector<fs::path> ImageFiles(const std::vector<std::string>& args, const std::string& what) {
  static const std::set<std::string> kExt = {".png", ".jpg",  ".jpeg", ".bmp",
                                             ".tif", ".tiff", ".pgm",  ".ppm"};
  std::vector<fs::path> files;
  for (const auto& a : args) {
    const fs::path p(a);
    SLSHADOW_THROW_IF(!fs::exists(p), what, ": ", a, ": no such file or folder");
    if (fs::is_directory(p)) {
      std::vector<fs::path> in_dir;
      for (const auto& e : fs::directory_iterator(p)) {
        std::string ext = e.path().extension().string();
        std::transform(ext.begin(), ext.end(), ext.begin(),
                       [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
        if (e.is_regular_file() && kExt.count(ext)) in_dir.push_back(e.path());
      }
      std::sort(in_dir.begin(), in_dir.end());
      SLSHADOW_THROW_IF(in_dir.empty(), what, ": ", a,
                        ": folder holds no images (.png .jpg .bmp .tif .pgm)");
      files.insert(files.end(), in_dir.begin(), in_dir.end());
    } else {
      files.push_back(p);
    }
  }
  return files;
}

void AddBoardViews(const TargetSpec& spec, const std::vector<fs::path>& files, int device,
                   CalibrationInput* input, std::vector<ImageCheck>* checks) {
  const auto board = BoardPoints(spec);
  auto& dev = input->devices[static_cast<size_t>(device)];
  Progress progress("detect", static_cast<int64_t>(files.size()), false);
  for (size_t p = 0; p < files.size(); ++p) {
    const TargetDetection det = DetectTargetInFile(spec, files[p]);
    if (dev.width == 0) {
      dev.width = det.width;
      dev.height = det.height;
    }
    SLSHADOW_THROW_IF(det.width != dev.width || det.height != dev.height, files[p].string(),
                      ": image is ", det.width, "x", det.height, " but the first image of '",
                      dev.name, "' is ", dev.width, "x", dev.height,
                      " (mismatched image sizes: one camera per list)");
    checks->push_back({files[p].string(), device, det.found, det.reason, det.saturated_fraction});
    progress.Advance();
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

CalibrationInput CameraInputFromImages(const TargetSpec& spec, const std::vector<fs::path>& files,
                                       const std::string& camera_name,
                                       std::vector<ImageCheck>* checks) {
  CalibrationInput input;
  input.devices = {CalibrationDevice::Camera(camera_name)};
  input.num_poses = static_cast<int>(files.size());
  AddBoardViews(spec, files, 0, &input, checks);
  return input;
}

CalibrationInput StereoInputFromImages(const TargetSpec& spec, const std::vector<fs::path>& left,
                                       const std::vector<fs::path>& right,
                                       const std::string& left_name, const std::string& right_name,
                                       std::vector<ImageCheck>* checks) {
  SLSHADOW_THROW_IF(left.size() != right.size(), "stereo: ", left.size(), " left images but ",
                    right.size(), " right images; give the same poses in the same (name) order");
  SLSHADOW_THROW_IF(left_name == right_name,
                    "stereo: --left-name and --right-name must differ (got '", left_name, "')");
  CalibrationInput input;
  input.devices = {CalibrationDevice::Camera(left_name), CalibrationDevice::Camera(right_name)};
  input.num_poses = static_cast<int>(left.size());
  AddBoardViews(spec, left, 0, &input, checks);
  AddBoardViews(spec, right, 1, &input, checks);
  return input;
}

namespace {

// Adds a decoded pose's views: the camera's, and the projector's when it has 4+ corners.
void AddProcamPose(const ProcamPose& pose, CalibrationInput* input) {
  if (!pose.detection.found) return;
  input->views.push_back(pose.camera_view);
  if (pose.projector_view.pixels_px.size() >= 4) input->views.push_back(pose.projector_view);
}

}  // namespace

void AddProcamCaptures(const PatternSpec& patterns, const std::string& patterns_path,
                       const TargetSpec& spec, const std::vector<std::vector<fs::path>>& captures,
                       const std::vector<std::string>& labels, const ProcamInputOptions& options,
                       CalibrationInput* input, std::vector<ImageCheck>* checks,
                       std::vector<std::string>* skipped) {
  options.Check();
  SLSHADOW_THROW_IF(labels.size() != captures.size(), "AddProcamCaptures: ", labels.size(),
                    " labels for ", captures.size(), " captures");
  Progress progress("decode", static_cast<int64_t>(captures.size()), false);
  for (size_t p = 0; p < captures.size(); ++p) {
    const auto& files = captures[p];
    SLSHADOW_THROW_IF(static_cast<int>(files.size()) != patterns.NumImages(), labels[p], ": ",
                      files.size(), " images but the pattern sequence ", patterns_path, " has ",
                      patterns.NumImages());
    std::vector<cv::Mat> frames;
    for (const auto& f : files) frames.push_back(ReadGrayImage(f));
    if (input->devices[0].width == 0) {
      input->devices[0].width = frames[0].cols;
      input->devices[0].height = frames[0].rows;
    }
    const ProcamPose pose = MakeProcamPose(patterns, frames, spec, static_cast<int>(p), 0, 1,
                                           labels[p], options.decode, options.local);
    checks->push_back({labels[p], 0, pose.detection.found, pose.detection.reason,
                       pose.detection.saturated_fraction});
    for (const auto& s : pose.projector.skipped) skipped->push_back(labels[p] + ": skipped " + s);
    AddProcamPose(pose, input);
    progress.Advance();
  }
}

CalibrationInput ProcamInputFromCaptures(
    const PatternSpec& patterns, const std::string& patterns_path, const TargetSpec& spec,
    const std::vector<std::string>& capture_dirs, const std::string& camera_name,
    const CameraModel* known_camera, const ProcamInputOptions& options,
    std::vector<ImageCheck>* checks, std::vector<std::string>* skipped) {
  CalibrationInput input;
  input.devices = {CalibrationDevice::Camera(camera_name),
                   CalibrationDevice::Projector("projector", patterns.projector_width,
                                                patterns.projector_height)};
  if (known_camera) {
    input.devices[0].initial = *known_camera;
    input.devices[0].hold_intrinsics = true;
  }
  input.num_poses = static_cast<int>(capture_dirs.size());
  std::vector<std::vector<fs::path>> files;
  for (const auto& capture : capture_dirs) files.push_back(ImageFiles({capture}, "--captures"));
  AddProcamCaptures(patterns, patterns_path, spec, files, capture_dirs, options, &input, checks,
                    skipped);
  return input;
}

CalibrationInput ProcamInputFromImageSets(const std::vector<std::string>& imagesets,
                                          const TargetSpec& spec, const ProcamInputOptions& options,
                                          std::vector<ImageCheck>* checks) {
  options.Check();
  CalibrationInput input;
  input.num_poses = static_cast<int>(imagesets.size());
  std::vector<std::string> names;
  int projector_device = -1;
  Progress progress("decode", static_cast<int64_t>(imagesets.size()), false);  // per ImageSet
  for (size_t p = 0; p < imagesets.size(); ++p) {
    const ImageSet set = ImageSet::Open(imagesets[p]);
    const PatternSpec patterns = PatternSpecFromConfig(ConfigNode::FromJson(
        set.patterns(), (fs::path(imagesets[p]) / "manifest.json").string(), "patterns"));
    if (p == 0) {
      for (const auto& name : set.CameraNames()) {
        const auto& cam = set.rig().Camera(name);
        input.devices.push_back(CalibrationDevice::Camera(name, cam.model.width, cam.model.height));
        names.push_back(name);
      }
      projector_device = static_cast<int>(input.devices.size());
      input.devices.push_back(CalibrationDevice::Projector(
          set.rig().projector ? set.rig().projector->name : "projector", patterns.projector_width,
          patterns.projector_height));
    }
    SLSHADOW_THROW_IF(set.CameraNames() != names, imagesets[p],
                      ": cameras differ from the first ImageSet's");
    for (size_t d = 0; d < names.size(); ++d) {
      const std::string label = imagesets[p] + "/" + names[d];
      const ProcamPose pose = MakeProcamPose(
          patterns, set.LoadCamera(names[d]), spec, static_cast<int>(p), static_cast<int>(d),
          projector_device, label, options.decode, options.local);
      checks->push_back({label, static_cast<int>(d), pose.detection.found, pose.detection.reason,
                         pose.detection.saturated_fraction});
      AddProcamPose(pose, &input);
    }
    progress.Advance();
  }
  return input;
}

}  // namespace slshadow
