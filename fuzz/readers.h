// One reader per input format slshadow reads, over raw bytes, shared by the libFuzzer harnesses
// (fuzz_<format>.cc) and the regression test that replays fuzz/regressions/ in the normal suite
// (tests/fuzz/regressions_test.cc). Each writes the bytes to a scratch file and calls the
// library's reader exactly as the tool does. Bad input must throw slshadow::Error; anything
// else (another exception type, a crash, a leak, undefined behaviour, an allocation beyond the
// fuzzer's RSS limit, a hang) is a finding. docs/fuzzing.md lists the harnesses.
#pragma once

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "calib/calibration_io.h"
#include "calib/target.h"
#include "capture/devices.h"
#include "core/error.h"
#include "core/image_io.h"
#include "core/image_set.h"
#include "core/mesh.h"
#include "core/npy.h"
#include "core/point_cloud.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "sim/scene.h"

namespace slshadow::fuzz {

// A folder private to this process: /dev/shm when it exists (no disk writes), else the system
// temporary folder; removed when the process exits normally.
inline const std::filesystem::path& ScratchDir() {
  struct Scratch {
    std::filesystem::path dir;
    Scratch() {
      const std::filesystem::path base = std::filesystem::exists("/dev/shm")
                                             ? std::filesystem::path("/dev/shm")
                                             : std::filesystem::temp_directory_path();
      dir = base / ("slshadow-fuzz-" + std::to_string(::getpid()));
      std::filesystem::create_directories(dir);
    }
    ~Scratch() {
      std::error_code ec;
      std::filesystem::remove_all(dir, ec);
    }
  };
  static const Scratch scratch;
  return scratch.dir;
}

// Writes the bytes to ScratchDir()/name and returns that path.
inline std::filesystem::path WriteInput(const uint8_t* data, size_t size, const std::string& name) {
  const std::filesystem::path path = ScratchDir() / name;
  std::filesystem::create_directories(path.parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  out.close();
  if (!out) {
    std::fprintf(stderr, "fuzz: cannot write %s\n", path.c_str());
    std::abort();
  }
  return path;
}

// Config files are read as JSON when their name ends in .json, else as YAML: inputs whose first
// byte is '{' go through the JSON parser, the rest through yaml-cpp.
inline std::string ConfigName(const uint8_t* data, size_t size, const std::string& stem) {
  return stem + (size > 0 && data[0] == '{' ? ".json" : ".yaml");
}

inline void ReadRigBytes(const uint8_t* data, size_t size) {
  (void)RigToJson(LoadRig(WriteInput(data, size, ConfigName(data, size, "rig"))));
}

// Relative mesh, cloud and texture paths resolve in the scratch folder (which holds none).
inline void ReadSceneBytes(const uint8_t* data, size_t size) {
  (void)SceneToJson(LoadScene(WriteInput(data, size, ConfigName(data, size, "scene"))));
}

inline void ReadPatternSpecBytes(const uint8_t* data, size_t size) {
  const PatternSpec spec =
      LoadPatternSpec(WriteInput(data, size, ConfigName(data, size, "patterns")));
  (void)PatternSpecToJson(spec);
}

inline void ReadTargetBytes(const uint8_t* data, size_t size) {
  (void)BoardPoints(LoadTargetSpec(WriteInput(data, size, ConfigName(data, size, "target"))));
}

inline void ReadDevicesBytes(const uint8_t* data, size_t size) {
  (void)capture::LoadDevices(WriteInput(data, size, ConfigName(data, size, "devices")));
}

// The ImageSet folder holds fixed images the manifest can name: left|right/0000.png and
// 0001.png (8 x 6, 8-bit), 0002.png (8 x 6, 16-bit), 0003.png (4 x 4, 8-bit). The manifest is
// opened and every camera's images loaded.
inline void ReadManifestBytes(const uint8_t* data, size_t size) {
  const std::filesystem::path set = ScratchDir() / "set";
  static const bool images_written = [&] {
    for (const char* camera : {"left", "right"}) {
      std::filesystem::create_directories(set / camera);
      cv::Mat a(6, 8, CV_8U), b(6, 8, CV_8U, cv::Scalar(200));
      cv::randu(a, 0, 255);
      const cv::Mat wide(6, 8, CV_16U, cv::Scalar(40000)), small(4, 4, CV_8U, cv::Scalar(7));
      WriteImage(set / camera / "0000.png", a);
      WriteImage(set / camera / "0001.png", b);
      WriteImage(set / camera / "0002.png", wide);
      WriteImage(set / camera / "0003.png", small);
    }
    return true;
  }();
  (void)images_written;
  WriteInput(data, size, "set/manifest.json");
  const ImageSet images = ImageSet::Open(set);
  for (const std::string& camera : images.CameraNames()) (void)images.LoadCamera(camera);
}

// Runs every reader; succeeds when one of them does, else rethrows the last error.
inline void ReadAsAnyOf(const std::vector<std::function<void()>>& readers) {
  std::optional<Error> last;
  bool any = false;
  for (const auto& read : readers) {
    try {
      read();
      any = true;
    } catch (const Error& e) {
      last = e;
    }
  }
  if (!any && last) throw *last;
}

// PLY, ASCII and binary, read as a point cloud and as a mesh.
inline void ReadPlyBytes(const uint8_t* data, size_t size) {
  const std::filesystem::path path = WriteInput(data, size, "input.ply");
  ReadAsAnyOf({[&] { (void)ReadPly(path); }, [&] { (void)ReadMesh(path); }});
}

inline void ReadStlBytes(const uint8_t* data, size_t size) {
  (void)ReadMesh(WriteInput(data, size, "input.stl"));
}

inline void ReadObjBytes(const uint8_t* data, size_t size) {
  (void)ReadMesh(WriteInput(data, size, "input.obj"));
}

// The .npy float-map reader, as one and as three channels.
inline void ReadNpyBytes(const uint8_t* data, size_t size) {
  const std::filesystem::path path = WriteInput(data, size, "input.npy");
  ReadAsAnyOf({[&] { (void)ReadNpy(path, 1); }, [&] { (void)ReadNpy(path, 3); }});
}

// Image files (core/image_io.h): PNG, JPEG, TIFF, BMP, PGM / PPM, found from the content, read
// as stored, as gray and as colour (the three modes take different decoder paths).
inline void ReadImageBytes(const uint8_t* data, size_t size) {
  const std::filesystem::path path = WriteInput(data, size, "input.image");
  ReadAsAnyOf({[&] { (void)ReadImage(path, ImageReadMode::kUnchanged); },
               [&] { (void)ReadImage(path, ImageReadMode::kGrayscale); },
               [&] { (void)ReadImage(path, ImageReadMode::kColor); }});
}

// OpenCV FileStorage calibration import: YAML; XML when the input starts with '<', JSON with '{'.
inline void ReadOpenCvCalibrationBytes(const uint8_t* data, size_t size) {
  const char* ext = size > 0 && data[0] == '<'   ? ".xml"
                    : size > 0 && data[0] == '{' ? ".json"
                                                 : ".yml";
  (void)ReadOpenCvCalibration(WriteInput(data, size, std::string("calibration") + ext), 640, 480);
}

// Format name (the fuzz/regressions/ and fuzz/seeds/ folder names) -> reader.
inline const std::map<std::string, std::function<void(const uint8_t*, size_t)>>& Readers() {
  static const std::map<std::string, std::function<void(const uint8_t*, size_t)>> readers = {
      {"rig", ReadRigBytes},
      {"scene", ReadSceneBytes},
      {"pattern_spec", ReadPatternSpecBytes},
      {"target", ReadTargetBytes},
      {"devices", ReadDevicesBytes},
      {"manifest", ReadManifestBytes},
      {"ply", ReadPlyBytes},
      {"stl", ReadStlBytes},
      {"obj", ReadObjBytes},
      {"npy", ReadNpyBytes},
      {"image", ReadImageBytes},
      {"opencv_calibration", ReadOpenCvCalibrationBytes}};
  return readers;
}

}  // namespace slshadow::fuzz

// Defines the libFuzzer entry point over one reader: slshadow::Error is expected bad input.
#define SLSHADOW_FUZZ_HARNESS(reader)                                       \
  extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) { \
    try {                                                                   \
      ::slshadow::fuzz::reader(data, size);                                 \
    } catch (const ::slshadow::Error&) {}                                   \
    return 0;                                                               \
  }
