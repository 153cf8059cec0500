// devices.yaml: which physical (or recorded) device plays each camera of a rig, and which
// projector shows the patterns, with typed settings. Format: docs/formats.md, "Devices YAML";
// examples in config/devices/. Read through ConfigNode: a missing field, an unknown key or a bad
// value is one error naming the file, the field and the value.
//
//   format: slshadow-devices
//   version: 1
//   cameras:
//     - name: left               # a camera name of the rig
//       backend: aravis          # aravis | replay | sim | ... (the factory says which are built)
//       address: 192.168.1.20    # aravis: one of id / address / serial
//       settings: {exposure_us: 8000, gain_db: 0, pixel_format: Mono8, trigger: software}
//       grab_timeout_ms: 1000
//   projector:
//     backend: window            # window | none | ...
//     display: 1                 # window: display index, or "x,y,w,h"
//     latency_us: 35000          # present-to-light latency waited after each Show
//     settle_us: 2000            # extra settling time after the latency
//   (or, a LightCrafter running the sequence itself: backend: lightcrafter, mode: pattern-sequence,
//    frame_period_us: 16667; the cameras then take trigger: hardware, config/devices/)
//   turntable:                   # optional; absent: backend none (one view)
//     backend: grbl              # grbl | manual | none (capture/turntable.h)
//     port: /dev/ttyUSB0
//     axis: X
#pragma once

#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "capture/camera.h"
#include "capture/turntable.h"

namespace slshadow {
class ConfigNode;
struct Rig;
}  // namespace slshadow

namespace slshadow::capture {

struct CameraEntry {
  std::string name;     // the rig's camera this device plays
  std::string backend;  // "aravis", "replay", "sim", ...
  // How to find the device; which of them a backend needs is its own affair (aravis: any one).
  std::string id, address, serial;
  CameraSettings settings;
  int grab_timeout_ms = 1000;  // per Grab, milliseconds, > 0
  // replay: the ImageSet to play (relative paths are resolved against the devices file's folder),
  // the camera in it (default: `name`), and the first 16-bit frame id it reports (1..65535).
  std::filesystem::path imageset;
  std::string imageset_camera;
  int first_frame_id = 1;
  std::string where;  // "FILE: cameras[i]" for messages
};

struct ProjectorEntry {
  std::string backend = "none";  // "window", "none", ...
  std::string display;           // window: display index ("1") or geometry ("x,y,w,h")
  int64_t latency_us = 0;        // present-to-light latency, microseconds, >= 0
  int64_t settle_us = 0;         // extra wait after the latency, microseconds, >= 0
  // lightcrafter: "video" (HDMI input shown through a window on `display`) or "pattern-sequence"
  // (the device runs the sequence from flash, TRIG_OUT1 triggers cameras set to trigger: hardware).
  std::string mode = "video";
  std::string usb;                  // lightcrafter: BUS:ADDRESS; empty: the only one
  int64_t frame_period_us = 16667;  // pattern-sequence: one pattern every this many us
  int64_t exposure_us = 0;          // pattern-sequence: LED time per pattern; 0: the whole period
  int bit_depth = 0;                // pattern-sequence: 1..8; 0: 1 for binary patterns, else 8
  bool trigger_inverted = false;    // pattern-sequence: TRIG_OUT1 active low
  std::string where;                // "FILE: projector" for messages
};

struct DevicesConfig {
  std::filesystem::path file;  // where it was read from (empty when built in code)
  std::vector<CameraEntry> cameras;
  ProjectorEntry projector;
  TurntableConfig turntable;  // backend none when the file has no turntable entry
  // The entry of a camera, or nullptr.
  const CameraEntry* Camera(const std::string& name) const;
  // Every entry names a camera of the rig (a capture takes the rig cameras that have an entry, in
  // rig order); throws slshadow::Error naming the file, the entry and the name otherwise.
  void CheckAgainst(const Rig& rig) const;
};

// Camera and projector backend names the schema knows (the factory may not build all of them).
const std::vector<std::string>& KnownCameraBackends();
const std::vector<std::string>& KnownProjectorBackends();

DevicesConfig DevicesFromConfig(const ConfigNode& node);
DevicesConfig LoadDevices(const std::filesystem::path& path);
CameraSettings CameraSettingsFromConfig(const ConfigNode& node, const std::string& where);

}  // namespace slshadow::capture
