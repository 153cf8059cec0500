#include "capture/devices.h"

#include <algorithm>

#include "core/config.h"
#include "core/error.h"
#include "core/rig.h"

namespace slshadow::capture {
namespace fs = std::filesystem;

const std::vector<std::string>& KnownCameraBackends() {
  static const std::vector<std::string> names = {"aravis", "replay", "sim", "v4l2"};
  return names;
}

const std::vector<std::string>& KnownProjectorBackends() {
  static const std::vector<std::string> names = {"window", "none", "lightcrafter"};
  return names;
}

namespace {

// "a", "a or b", "a, b or c" (as core/enum_names.h lists an enum's names).
std::string OneOf(const std::vector<std::string>& names) {
  std::string s;
  for (size_t i = 0; i < names.size(); ++i)
    s += (i == 0 ? "" : i + 1 == names.size() ? " or " : ", ") + names[i];
  return s;
}

std::string Backend(const ConfigNode& node, const std::vector<std::string>& known) {
  const std::string name = node.AsString();
  if (std::find(known.begin(), known.end(), name) == known.end())
    node.Fail("unknown backend (expected " + OneOf(known) + ")");
  return name;
}

// A string that YAML may have read as a number (display: 1, address without quotes).
std::string Text(const ConfigNode& node) {
  if (node.json().is_number_integer()) return std::to_string(node.AsInt());
  return node.AsString();
}

int64_t NonNegative(const ConfigNode& node, const std::string& key, int64_t fallback) {
  if (!node.Has(key)) return fallback;
  const int64_t v = node[key].AsInt();
  if (v < 0) node[key].Fail("must be >= 0");
  return v;
}

}  // namespace

CameraSettings CameraSettingsFromConfig(const ConfigNode& node, const std::string& where) {
  node.RejectUnknownKeys({"exposure_us", "gain_db", "pixel_format", "roi", "trigger",
                          "trigger_line", "packet_size_bytes", "socket_buffer_bytes",
                          "packet_resend"});
  CameraSettings s;
  if (node.Has("exposure_us")) {
    s.exposure_us = node["exposure_us"].AsDouble();
    if (!(*s.exposure_us > 0))
      node["exposure_us"].Fail("must be a positive number of microseconds");
  }
  if (node.Has("gain_db")) s.gain_db = node["gain_db"].AsDouble();
  if (node.Has("pixel_format"))
    s.pixel_format = EnumFromConfig(node["pixel_format"], kPixelFormatNames);
  if (node.Has("roi")) {
    const ConfigNode roi = node["roi"];
    if (!roi.IsArray() || roi.size() != 4)
      roi.Fail("expected [x, y, width, height] in sensor pixels");
    int v[4];
    for (size_t i = 0; i < 4; ++i) {
      const int64_t x = roi.at(i).AsInt();
      if (x < 0 || x > 1000000) roi.at(i).Fail("must be in [0, 1000000]");
      v[i] = static_cast<int>(x);
    }
    s.roi = {v[0], v[1], v[2], v[3]};
    if ((s.roi.width == 0) != (s.roi.height == 0))
      roi.Fail("width and height must both be 0 (full sensor) or both positive");
  }
  if (node.Has("trigger")) s.trigger = EnumFromConfig(node["trigger"], kTriggerModeNames);
  s.trigger_line = node.GetString("trigger_line", s.trigger_line);
  for (const char* key : {"packet_size_bytes", "socket_buffer_bytes"}) {
    const int64_t v = NonNegative(node, key, 0);
    if (v > 1 << 30) node[key].Fail("must be at most 2^30");
    (std::string(key) == "packet_size_bytes" ? s.packet_size_bytes : s.socket_buffer_bytes) =
        static_cast<int>(v);
  }
  s.packet_resend = node.GetBool("packet_resend", s.packet_resend);
  s.Check(where);
  return s;
}

DevicesConfig DevicesFromConfig(const ConfigNode& root) {
  root.RejectUnknownKeys({"format", "version", "cameras", "projector", "turntable"});
  if (root["format"].AsString() != "slshadow-devices")
    root["format"].Fail("expected \"slshadow-devices\"");
  if (root["version"].AsInt() != 1)
    root["version"].Fail("unsupported devices version (this slshadow reads version 1)");
  DevicesConfig config;
  config.file = root.file();
  const fs::path base = config.file.has_parent_path() ? config.file.parent_path() : fs::path(".");
  const ConfigNode cameras = root["cameras"];
  if (!cameras.IsArray() || cameras.size() == 0)
    cameras.Fail("expected a list of at least one camera");
  for (size_t i = 0; i < cameras.size(); ++i) {
    const ConfigNode n = cameras.at(i);
    n.RejectUnknownKeys({"name", "backend", "id", "address", "serial", "settings",
                         "grab_timeout_ms", "imageset", "imageset_camera", "first_frame_id"});
    CameraEntry e;
    e.where = root.file() + ": cameras[" + std::to_string(i) + "]";
    e.name = n["name"].AsString();
    if (e.name.empty()) n["name"].Fail("must not be empty");
    for (const auto& other : config.cameras) {
      if (other.name == e.name) n["name"].Fail("a second entry for the same camera");
    }
    e.backend = Backend(n["backend"], KnownCameraBackends());
    if (n.Has("id")) e.id = Text(n["id"]);
    if (n.Has("address")) e.address = Text(n["address"]);
    if (n.Has("serial")) e.serial = Text(n["serial"]);
    if (n.Has("settings"))
      e.settings = CameraSettingsFromConfig(n["settings"], e.where + ".settings");
    const int64_t timeout = n.GetInt("grab_timeout_ms", e.grab_timeout_ms);
    if (timeout <= 0 || timeout > 3600000)
      n["grab_timeout_ms"].Fail("must be in (0, 3600000] milliseconds");
    e.grab_timeout_ms = static_cast<int>(timeout);
    if (e.backend == "replay") {
      const fs::path set = n["imageset"].AsString();
      e.imageset = set.is_absolute() ? set : base / set;
      e.imageset_camera = n.GetString("imageset_camera", e.name);
      const int64_t first = n.GetInt("first_frame_id", 1);
      if (first < 1 || first > 65535)
        n["first_frame_id"].Fail("must be in [1, 65535] (16-bit frame ids, 0 is invalid)");
      e.first_frame_id = static_cast<int>(first);
    } else {
      for (const char* key : {"imageset", "imageset_camera", "first_frame_id"}) {
        if (n.Has(key)) n[key].Fail("only for backend replay");
      }
    }
    config.cameras.push_back(std::move(e));
  }
  if (root.Has("projector")) {
    const ConfigNode p = root["projector"];
    p.RejectUnknownKeys({"backend", "display", "latency_us", "settle_us", "mode", "usb",
                         "frame_period_us", "exposure_us", "bit_depth", "trigger_inverted"});
    config.projector.where = root.file() + ": projector";
    config.projector.backend = Backend(p["backend"], KnownProjectorBackends());
    ProjectorEntry& e = config.projector;
    if (e.backend == "lightcrafter") {
      e.mode = p.GetString("mode", e.mode);
      if (e.mode != "video" && e.mode != "pattern-sequence")
        p["mode"].Fail("expected video or pattern-sequence");
      if (p.Has("usb")) e.usb = Text(p["usb"]);
    }
    for (const char* key : {"mode", "usb"}) {
      if (p.Has(key) && e.backend != "lightcrafter") p[key].Fail("only for backend lightcrafter");
    }
    for (const char* key : {"frame_period_us", "exposure_us", "bit_depth", "trigger_inverted"}) {
      if (p.Has(key) && e.mode != "pattern-sequence")
        p[key].Fail("only for a lightcrafter in mode pattern-sequence");
    }
    e.frame_period_us = p.GetInt("frame_period_us", e.frame_period_us);
    if (e.frame_period_us < 235 || e.frame_period_us > 10000000)
      p["frame_period_us"].Fail("must be in [235, 10000000] us");
    e.exposure_us = NonNegative(p, "exposure_us", 0);
    if (e.exposure_us > e.frame_period_us) p["exposure_us"].Fail("must be at most frame_period_us");
    const int64_t depth = p.GetInt("bit_depth", 0);
    if (depth < 0 || depth > 8) p["bit_depth"].Fail("must be 1..8, or 0 for automatic");
    e.bit_depth = static_cast<int>(depth);
    e.trigger_inverted = p.GetBool("trigger_inverted", false);
    if (p.Has("display")) config.projector.display = Text(p["display"]);
    config.projector.latency_us = NonNegative(p, "latency_us", 0);
    config.projector.settle_us = NonNegative(p, "settle_us", 0);
    for (const char* key : {"latency_us", "settle_us"}) {
      if (NonNegative(p, key, 0) > 10000000) p[key].Fail("must be at most 10 s (10000000 us)");
    }
  } else {
    config.projector.where = root.file() + ": projector";
  }
  config.turntable.where = root.file() + ": turntable";
  if (root.Has("turntable"))
    config.turntable = TurntableConfigFromConfig(root["turntable"], config.turntable.where);
  return config;
}

DevicesConfig LoadDevices(const fs::path& path) {
  return DevicesFromConfig(ConfigNode::LoadFile(path));
}

const CameraEntry* DevicesConfig::Camera(const std::string& name) const {
  for (const auto& c : cameras) {
    if (c.name == name) return &c;
  }
  return nullptr;
}

void DevicesConfig::CheckAgainst(const Rig& rig) const {
  for (const auto& c : cameras) {
    SLSHADOW_THROW_IF(rig.CameraIndex(c.name) < 0, c.where, ".name: the rig '", rig.name,
                      "' has no camera '", c.name, "'");
  }
}

}  // namespace slshadow::capture
