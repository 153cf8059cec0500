// Opens the device a devices.yaml entry names (capture/devices.h). One place chooses the backend
// by name; a backend this slshadow was built without is a clear error, not a silent fallback.
#pragma once

#include <memory>

#include "capture/camera.h"
#include "capture/devices.h"
#include "capture/projector.h"

namespace slshadow::capture {

// Opens (does not configure or start) the camera of `entry`. Throws slshadow::Error naming the
// entry when the backend is not built in or the device cannot be opened.
std::unique_ptr<Camera> OpenCamera(const CameraEntry& entry);
// Opens the projector of `entry` with its latency set. Throws like OpenCamera.
std::unique_ptr<Projector> OpenProjector(const ProjectorEntry& entry);

}  // namespace slshadow::capture
