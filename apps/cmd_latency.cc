// slshadow latency: how long to wait after the projector's Show() before triggering cameras.
//   slshadow latency --devices DEVICES.yaml [--camera NAME]   (projector to camera)
//   slshadow latency [--display N | --geometry x,y,w,h]       (window: present to X framebuffer)
#include <CLI/CLI.hpp>
#include <chrono>
#include <cstdio>

#include "apps/commands.h"
#include "capture/devices.h"
#include "capture/factory.h"
#include "capture/latency.h"
#include "capture/window_projector.h"
#include "core/error.h"

namespace slshadow::app {

int RunLatency(int argc, char** argv) {
  CLI::App app{
      "Projector latency: how long `slshadow capture` must wait after showing a pattern before it\n"
      "triggers the cameras (the devices file's projector.latency_us).\n\n"
      "With --devices: the projector of DEVICES switches between full black and full white while a "
      "camera of\n"
      "DEVICES watches (--camera, default the first); with a software trigger, a binary search "
      "finds the\n"
      "shortest wait after which every repetition's frame shows the change (the camera's own "
      "trigger delay\n"
      "included); free-running cameras count frames instead. The camera must see the projected "
      "area.\n\n"
      "Without --devices: opens the window projector (an SDL2 fullscreen borderless window on the "
      "X display\n"
      "$DISPLAY), alternates black and white and reads the window back from the X server until "
      "each frame\n"
      "is there: the present-to-framebuffer latency (under Xvfb, the whole latency). A real "
      "projector adds\n"
      "its own input lag, which only a camera sees.\n\n"
      "Examples:\n"
      "  slshadow latency --devices config/devices/stereo_gige_hdmi.yaml --camera left\n"
      "  slshadow latency --geometry 1920,0,1280,800 --samples 50",
      argv[0]};
  int display = 0, samples = 20, repetitions = 5, max_ms = 500;
  double resolution_ms = 1;
  std::string geometry, renderer = "software", devices_path, camera_name;
  bool no_vsync = false;
  app.add_option("--devices", devices_path,
                 "devices file (docs/formats.md \"Devices YAML\"): its projector and a camera");
  app.add_option("--camera", camera_name,
                 "with --devices: the camera that watches (default: the first)");
  app.add_option("--repetitions", repetitions,
                 "with --devices: measurements; the largest is reported")
      ->capture_default_str();
  app.add_option("--max-ms", max_ms, "with --devices: longest latency searched, ms")
      ->capture_default_str();
  app.add_option("--resolution-ms", resolution_ms, "with --devices: resolution of the search, ms")
      ->capture_default_str();
  app.add_option("--display", display, "SDL display index of the projector (fullscreen window)")
      ->capture_default_str();
  app.add_option("--geometry", geometry,
                 "window at x,y,w,h on the X screen instead of a fullscreen display");
  app.add_option("--renderer", renderer, "SDL renderer")
      ->capture_default_str()
      ->check(CLI::IsMember({"software", "opengl", "auto"}));
  app.add_flag("--no-vsync", no_vsync, "present without waiting for the refresh");
  app.add_option("--samples", samples, "black/white pairs (window mode)")->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  if (!devices_path.empty()) {
    const capture::DevicesConfig devices = capture::LoadDevices(devices_path);
    SLSHADOW_THROW_IF(devices.cameras.empty(), devices_path,
                      ": cameras: the latency needs a camera that watches the projector");
    const capture::CameraEntry* entry =
        camera_name.empty() ? &devices.cameras[0] : devices.Camera(camera_name);
    SLSHADOW_THROW_IF(!entry, "--camera: '", camera_name, "' is not a camera of ", devices_path);
    capture::LatencyOptions options;
    options.repetitions = repetitions;
    options.max_latency = std::chrono::milliseconds(max_ms);
    options.resolution = std::chrono::microseconds(static_cast<int64_t>(resolution_ms * 1000));
    options.grab_timeout = std::chrono::milliseconds(entry->grab_timeout_ms);
    options.Check();
    const auto projector = capture::OpenProjector(devices.projector);
    const auto camera = capture::OpenCamera(*entry);
    camera->Configure(entry->settings);
    const capture::LatencyMeasurement m =
        capture::MeasureProjectorLatency(*camera, *projector, options);
    std::printf("projector %s %s, camera %s (%s): %s\n", projector->Info().backend.c_str(),
                projector->Info().id.c_str(), entry->name.c_str(), camera->Info().id.c_str(),
                m.BriefReport().c_str());
    std::printf("latency_us: %lld\n", static_cast<long long>(m.latency.count()));
    return 0;
  }
  SLSHADOW_THROW_IF(samples < 1, "--samples: must be positive (got ", samples, ")");
  capture::WindowProjectorOptions options;
  options.display_index = display;
  if (!geometry.empty()) options.geometry = capture::ParseWindowGeometry(geometry);
  options.renderer = renderer;
  options.vsync = !no_vsync;
  capture::WindowProjector projector(options);
  const capture::ProjectorInfo info = projector.Info();
  std::printf("projector: window %s, %dx%d, %.0f Hz, %s renderer, vsync %s\n", info.id.c_str(),
              info.width, info.height, info.refresh_hz, projector.RendererName().c_str(),
              options.vsync ? "on" : "off");
  std::printf("%s\n", projector.MeasurePresentLatency(samples).BriefReport().c_str());
  return 0;
}

}  // namespace slshadow::app
