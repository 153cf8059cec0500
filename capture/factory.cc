#include "capture/factory.h"

#include "capture/aravis_camera.h"
#include "capture/lightcrafter_projector.h"
#include "capture/none_projector.h"
#include "capture/pattern_sequence_capture.h"
#include "capture/replay_camera.h"
#include "capture/v4l2_camera.h"
#include "capture/window_projector.h"
#include "core/error.h"

namespace slshadow::capture {
namespace {

[[noreturn]] void NotBuilt(const std::string& where, const std::string& backend,
                           const std::string& what) {
  SLSHADOW_THROW(where, ".backend: backend '", backend, "' is not built into this slshadow (", what,
                 "; `slshadow capture --help` lists the backends built in)");
}

}  // namespace

std::vector<std::string> BuiltInCameraBackends() { return {"replay", "aravis", "v4l2"}; }
std::vector<std::string> BuiltInProjectorBackends() { return {"none", "window", "lightcrafter"}; }

// window: `display` is an SDL display index ("1") or a geometry on the X screen ("x,y,w,h").
static WindowProjectorOptions WindowOptionsOf(const ProjectorEntry& entry) {
  WindowProjectorOptions options;
  options.latency = std::chrono::microseconds(entry.latency_us);
  if (entry.display.find(',') != std::string::npos) {
    try {
      options.geometry = ParseWindowGeometry(entry.display);
    } catch (const Error& e) {
      SLSHADOW_THROW(entry.where, ".display: ", e.what());
    }
  } else if (!entry.display.empty()) {
    size_t used = 0;
    int index = -1;
    try {
      index = std::stoi(entry.display, &used);
    } catch (const std::exception&) {}
    SLSHADOW_THROW_IF(index < 0 || used != entry.display.size(), entry.where, ".display: '",
                      entry.display,
                      "' is neither a display index (0, 1, ...) nor a geometry x,y,w,h");
    options.display_index = index;
  }
  return options;
}

std::unique_ptr<Camera> OpenCamera(const CameraEntry& entry) {
  // One case per camera backend.
  if (entry.backend == "replay") {
    return std::make_unique<ReplayCamera>(
        entry.imageset,
        ReplayCameraOptions{entry.imageset_camera, entry.first_frame_id, entry.serial});
  }
  if (entry.backend == "aravis") {
    // The address opens a GigE Vision camera directly; an id or serial is looked up among USB3
    // Vision devices only: devices.yaml never makes slshadow broadcast a GigE Vision discovery.
    const std::string& device = !entry.address.empty() ? entry.address
                                : !entry.id.empty()    ? entry.id
                                                       : entry.serial;
    try {
      return OpenAravisCamera(AravisOpenOptions{.device = device});
    } catch (const Error& e) {
      SLSHADOW_THROW(entry.where, ": ", e.what());
    }
  }
  if (entry.backend == "v4l2") {  // id: the device node, default /dev/video0
    try {
      return std::make_unique<V4l2Camera>(entry.id.empty() ? "/dev/video0" : entry.id);
    } catch (const Error& e) {
      SLSHADOW_THROW(entry.where, ": ", e.what());
    }
  }
  if (entry.backend == "sim") {
    NotBuilt(entry.where, entry.backend,
             "a simulator camera is built by the workflow layer, not by capture/");
  }
  NotBuilt(entry.where, entry.backend, "no camera backend of this name");
}

bool RunsSequenceItself(const ProjectorEntry& entry) {
  return entry.backend == "lightcrafter" && entry.mode == "pattern-sequence";
}

std::unique_ptr<SequenceProjector> OpenSequenceProjector(const ProjectorEntry& entry) {
  SLSHADOW_THROW_IF(!RunsSequenceItself(entry), entry.where, ": backend '", entry.backend,
                    "' shows patterns one by one (only backend lightcrafter with mode: "
                    "pattern-sequence runs them itself)");
  return OpenLightCrafterSequenceProjector(entry);
}

std::unique_ptr<Projector> OpenProjector(const ProjectorEntry& entry) {
  const std::chrono::microseconds latency(entry.latency_us);
  SLSHADOW_THROW_IF(RunsSequenceItself(entry), entry.where,
                    ".mode: pattern-sequence: the LightCrafter runs the ",
                    "sequence itself and triggers the cameras; it is not shown pattern by pattern "
                    "(use mode: video ",
                    "for this command)");
  // One case per projector backend.
  if (entry.backend == "none") return std::make_unique<NoneProjector>(latency);
  if (entry.backend == "window") {
    const WindowProjectorOptions options = WindowOptionsOf(entry);
    try {
      return std::make_unique<WindowProjector>(options);
    } catch (const Error& e) {
      SLSHADOW_THROW(entry.where, ": ", e.what());
    }
  }
  if (entry.backend == "lightcrafter") {  // video mode; the HDMI output is a window on `display`
    ProjectorEntry hdmi = entry;
    hdmi.backend = "window";
    return OpenLightCrafterProjector(entry, OpenProjector(hdmi));
  }
  NotBuilt(entry.where, entry.backend, "no projector backend of this name");
}

OpenedDevices OpenDevices(const DevicesConfig& devices, const Rig& rig) {
  devices.CheckAgainst(rig);
  OpenedDevices opened;
  for (const auto& rig_camera : rig.cameras) {
    const CameraEntry* entry = devices.Camera(rig_camera.name);
    if (entry == nullptr) continue;
    opened.owned.push_back(OpenCamera(*entry));
    opened.cameras.push_back({entry->name, opened.owned.back().get(), entry->settings,
                              std::chrono::milliseconds(entry->grab_timeout_ms)});
  }
  if (RunsSequenceItself(devices.projector)) {
    opened.sequence_projector = OpenSequenceProjector(devices.projector);
  } else {
    opened.projector = OpenProjector(devices.projector);
  }
  opened.settle = std::chrono::microseconds(devices.projector.settle_us);
  return opened;
}

OpenedDevices OpenDevicesFile(const std::filesystem::path& devices_file, const Rig& rig,
                              const std::function<void(DevicesConfig&)>& adjust) {
  DevicesConfig devices = LoadDevices(devices_file);
  if (adjust) adjust(devices);
  OpenedDevices opened = OpenDevices(devices, rig);
  opened.config = std::move(devices);
  return opened;
}

CaptureSummary CaptureImageSet(const Rig& rig, const PatternSpec& spec,
                               const std::vector<CaptureCamera>& cameras, Projector* projector,
                               SequenceProjector* sequence_projector,
                               const std::filesystem::path& out, const SequencerOptions& options) {
  SLSHADOW_THROW_IF((projector == nullptr) == (sequence_projector == nullptr),
                    "capture: exactly one projector is needed (shown pattern by pattern, or "
                    "running the sequence itself)");
  if (sequence_projector)
    return CapturePatternSequence(rig, spec, cameras, *sequence_projector, out, options);
  return Capture(rig, spec, cameras, *projector, out, options);
}

CaptureSummary CaptureImageSet(const Rig& rig, const PatternSpec& spec,
                               const OpenedDevices& devices, const std::filesystem::path& out,
                               const SequencerOptions& options) {
  return CaptureImageSet(rig, spec, devices.cameras, devices.projector.get(),
                         devices.sequence_projector.get(), out, options);
}

}  // namespace slshadow::capture
