// Opens the device a devices.yaml entry names (capture/devices.h). One place chooses the backend
// by name; a backend this slshadow was built without is a clear error, not a silent fallback.
#pragma once

#include <chrono>
#include <filesystem>
#include <functional>
#include <memory>
#include <vector>

#include "capture/camera.h"
#include "capture/devices.h"
#include "capture/projector.h"
#include "capture/sequence_projector.h"
#include "capture/sequencer.h"

namespace slshadow::capture {

// Opens (does not configure or start) the camera of `entry`. Throws slshadow::Error naming the
// entry when the backend is not built in or the device cannot be opened.
std::unique_ptr<Camera> OpenCamera(const CameraEntry& entry);
// Opens the projector of `entry` with its latency set. Throws like OpenCamera, and for a projector
// that runs the sequence itself (RunsSequenceItself).
std::unique_ptr<Projector> OpenProjector(const ProjectorEntry& entry);
// True for a LightCrafter in mode pattern-sequence: opened by OpenSequenceProjector.
bool RunsSequenceItself(const ProjectorEntry& entry);
std::unique_ptr<SequenceProjector> OpenSequenceProjector(const ProjectorEntry& entry);

// Backend names this build can open (for --help and messages).
std::vector<std::string> BuiltInCameraBackends();
std::vector<std::string> BuiltInProjectorBackends();

// Everything a capture needs from a devices file: the cameras of the rig that have an entry (rig
// order), opened, with their settings and timeouts, and the projector. Owns the devices.
struct OpenedDevices {
  DevicesConfig config;  // the devices file as read (OpenDevicesFile; empty after OpenDevices)
  std::vector<std::unique_ptr<Camera>> owned;
  std::vector<CaptureCamera> cameras;                     // point into `owned`
  std::unique_ptr<Projector> projector;                   // null when sequence_projector is set
  std::unique_ptr<SequenceProjector> sequence_projector;  // RunsSequenceItself(entry)
  std::chrono::microseconds settle{0};
};
// Checks the entries against the rig (DevicesConfig::CheckAgainst) and opens every device.
OpenedDevices OpenDevices(const DevicesConfig& devices, const Rig& rig);
// What `slshadow capture` and `slshadow scan` do with their --devices file: LoadDevices, then
// `adjust` (when set) may change or check the entries before any device is opened (a throw leaves
// every device closed), then OpenDevices. The result keeps the entries as adjusted in `config`.
OpenedDevices OpenDevicesFile(const std::filesystem::path& devices_file, const Rig& rig,
                              const std::function<void(DevicesConfig&)>& adjust = {});

// Captures `spec` into the ImageSet `out` with the sequencer the projector calls for:
// CapturePatternSequence when `sequence_projector` is set (a projector that runs the sequence
// itself and triggers the cameras, a LightCrafter in pattern-sequence mode), else Capture with
// `projector`. Exactly one of the two must be set (else slshadow::Error). Throws like those.
CaptureSummary CaptureImageSet(const Rig& rig, const PatternSpec& spec,
                               const std::vector<CaptureCamera>& cameras, Projector* projector,
                               SequenceProjector* sequence_projector,
                               const std::filesystem::path& out, const SequencerOptions& options);
// The same with the devices OpenDevices opened.
CaptureSummary CaptureImageSet(const Rig& rig, const PatternSpec& spec,
                               const OpenedDevices& devices, const std::filesystem::path& out,
                               const SequencerOptions& options);

}  // namespace slshadow::capture
