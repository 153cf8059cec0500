#include "tests/testing/sim_camera.h"

#include <cmath>

#include "core/error.h"
#include "sim/raycaster.h"

namespace slshadow::testing {

void ShownPattern::Load(std::vector<cv::Mat> images) {
  std::lock_guard<std::mutex> lock(mutex_);
  images_ = std::move(images);
  black_ = images_.empty() ? cv::Mat() : cv::Mat::zeros(images_[0].size(), CV_8UC1);
  index_ = kBlack;
}

void ShownPattern::Show(int index) {
  std::lock_guard<std::mutex> lock(mutex_);
  SLSHADOW_THROW_IF(index != kBlack && (index < 0 || index >= static_cast<int>(images_.size())),
                    "projector: image ", index, " is not loaded (", images_.size(), " images)");
  index_ = index;
}

int ShownPattern::index() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return index_;
}

std::pair<int, cv::Mat> ShownPattern::Current() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return {index_, index_ == kBlack ? black_ : images_[static_cast<size_t>(index_)]};
}

int ShownPattern::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int>(images_.size());
}

SimProjector::SimProjector(const Rig& rig, std::shared_ptr<ShownPattern> shown)
    : shown_(std::move(shown)) {
  SLSHADOW_THROW_IF(!rig.projector, "sim projector: rig '", rig.name, "' has no projector");
  SLSHADOW_THROW_IF(!shown_, "sim projector: no shown-pattern object");
  width_ = rig.projector->model.width;
  height_ = rig.projector->model.height;
}

capture::ProjectorInfo SimProjector::Info() const {
  capture::ProjectorInfo info;
  info.backend = "sim";
  info.id = "simulated projector";
  info.width = width_;
  info.height = height_;
  return info;
}

void SimProjector::Load(const std::vector<cv::Mat>& images) {
  for (size_t i = 0; i < images.size(); ++i) {
    SLSHADOW_THROW_IF(
        images[i].type() != CV_8UC1 || images[i].cols != width_ || images[i].rows != height_,
        "sim projector: image ", i, ": must be CV_8UC1 of ", width_, "x", height_, " (got ",
        images[i].cols, "x", images[i].rows, ", type ", images[i].type(), ")");
  }
  shown_->Load(images);
}

std::chrono::steady_clock::time_point SimProjector::Show(int index) {
  SLSHADOW_THROW_IF(index < 0, "sim projector: image index must be >= 0 (got ", index, ")");
  shown_->Show(index);
  return std::chrono::steady_clock::now();
}

std::chrono::steady_clock::time_point SimProjector::ShowBlack() {
  shown_->Show(ShownPattern::kBlack);
  return std::chrono::steady_clock::now();
}

SimCamera::SimCamera(const Scene& scene, const Rig& rig, const std::string& camera,
                     std::shared_ptr<const ShownPattern> shown)
    : scene_(scene), rendered_scene_(scene), rig_(rig), camera_(camera), shown_(std::move(shown)) {
  SLSHADOW_THROW_IF(!shown_, "sim camera '", camera, "': no shown-pattern object");
  camera_index_ = rig_.CameraIndex(camera);
  SLSHADOW_THROW_IF(camera_index_ < 0, "sim camera: rig '", rig_.name, "' has no camera '", camera,
                    "'");
  SLSHADOW_THROW_IF(!rig_.projector, "sim camera: rig '", rig_.name, "' has no projector");
  scene_.Check("scene '" + scene_.name + "'");
  rig_.Check("rig '" + rig_.name + "'");
  {
    // The geometry pass, once (with ground truth, as RenderScan traces it).
    const RayCaster caster(scene_);
    const CameraRays rays = ComputeCameraRays(
        rig_.cameras[static_cast<size_t>(camera_index_)].model, scene_.layers.supersampling);
    geometry_ = TraceGeometry(caster, rig_, camera_index_, rays);
  }
  settings_.pixel_format = scene_.radiometry.adc_bits <= 8 ? capture::PixelFormat::kMono8
                                                           : capture::PixelFormat::kMono16;
  settings_.exposure_us = scene_.radiometry.exposure_us;
  settings_.gain_db = 0.0;
  renderer_ = std::make_unique<PatternRenderer>(rendered_scene_, rig_, camera_index_, geometry_);
}

SimCamera::~SimCamera() = default;

capture::CameraInfo SimCamera::Info() const {
  capture::CameraInfo info;
  info.backend = "sim";
  info.id = camera_;
  info.vendor = "slshadow";
  info.model = "simulator";
  info.serial = rig_.name + "/" + camera_;
  info.sensor_width = geometry_.width;
  info.sensor_height = geometry_.height;
  if (scene_.radiometry.adc_bits <= 8) {
    info.pixel_formats = {capture::PixelFormat::kMono8};
  } else {
    info.pixel_formats = {capture::PixelFormat::kMono12, capture::PixelFormat::kMono16};
  }
  return info;
}

void SimCamera::Configure(const capture::CameraSettings& settings) {
  const std::string what = "sim camera '" + camera_ + "'";
  settings.Check(what);
  SLSHADOW_THROW_IF(started_, what, ": configure while stopped");
  const capture::CameraInfo info = Info();
  bool format_ok = false;
  for (const auto f : info.pixel_formats) format_ok = format_ok || f == settings.pixel_format;
  SLSHADOW_THROW_IF(!format_ok, what, ": pixel_format: ", capture::ToString(settings.pixel_format),
                    " is not offered (the scene has ", scene_.radiometry.adc_bits,
                    "-bit samples: ", capture::ToString(info.pixel_formats.front()), ")");
  SLSHADOW_THROW_IF(!settings.roi.Full() && !(settings.roi.x == 0 && settings.roi.y == 0 &&
                                              settings.roi.width == geometry_.width &&
                                              settings.roi.height == geometry_.height),
                    what, ": roi: only the full sensor is simulated (got ", settings.roi.width, "x",
                    settings.roi.height, "+", settings.roi.x, "+", settings.roi.y, ")");
  SLSHADOW_THROW_IF(settings.trigger == capture::TriggerMode::kHardware, what,
                    ": trigger: hardware trigger has no simulated input line");
  capture::CameraSettings applied = settings;
  if (!applied.exposure_us) applied.exposure_us = settings_.exposure_us;
  if (!applied.gain_db) applied.gain_db = settings_.gain_db;
  SLSHADOW_THROW_IF(!(*applied.exposure_us > 0), what, ": exposure_us: must be positive (got ",
                    *applied.exposure_us, ")");
  SLSHADOW_THROW_IF(
      !(scene_.radiometry.exposure_us > 0) && *applied.exposure_us != scene_.radiometry.exposure_us,
      what, ": exposure_us: the scene records no exposure time to scale from");
  const double time_ratio = scene_.radiometry.exposure_us > 0
                                ? *applied.exposure_us / scene_.radiometry.exposure_us
                                : 1.0;
  rendered_scene_ = scene_;
  rendered_scene_.radiometry.exposure_fraction =
      scene_.radiometry.exposure_fraction * time_ratio * std::pow(10.0, *applied.gain_db / 20);
  rendered_scene_.radiometry.exposure_us = *applied.exposure_us;
  renderer_ = std::make_unique<PatternRenderer>(rendered_scene_, rig_, camera_index_, geometry_);
  settings_ = applied;
  pending_.clear();
}

capture::CameraSettings SimCamera::Settings() const { return settings_; }

void SimCamera::Start() { started_ = true; }

void SimCamera::Stop() {
  started_ = false;
  pending_.clear();
}

capture::Frame SimCamera::Render(int index, const cv::Mat& projector_image) {
  capture::Frame frame;
  frame.host_timestamp = std::chrono::system_clock::now();
  if (projector_image.empty()) {
    frame.status = capture::FrameStatus::kOtherError;
    frame.message = "nothing loaded on the projector";
    ++statistics_.failed_frames;
    return frame;
  }
  frame.image = renderer_->Render(projector_image, index);
  frame.status = capture::FrameStatus::kOk;
  frame.frame_id = next_frame_id_++;
  frame.exposure_us = *settings_.exposure_us;
  ++statistics_.completed_frames;
  return frame;
}

void SimCamera::Trigger() {
  if (!started_ || settings_.trigger != capture::TriggerMode::kSoftware) return;
  const auto [index, image] = shown_->Current();
  pending_.push_back(Render(index, image));
}

capture::Frame SimCamera::Grab(std::chrono::milliseconds /*timeout*/) {
  capture::Frame frame;
  if (!started_) {
    frame.status = capture::FrameStatus::kAborted;
    frame.message = "acquisition not started";
    return frame;
  }
  if (settings_.trigger == capture::TriggerMode::kFreeRun) {
    const auto [index, image] = shown_->Current();
    return Render(index, image);
  }
  if (pending_.empty()) {
    frame.status = capture::FrameStatus::kTimeout;
    frame.message = "no frame triggered";
    ++statistics_.timeouts;
    return frame;
  }
  frame = std::move(pending_.front());
  pending_.pop_front();
  return frame;
}

void SimCamera::Flush() { pending_.clear(); }

capture::StreamStatistics SimCamera::Statistics() const { return statistics_; }

}  // namespace slshadow::testing
