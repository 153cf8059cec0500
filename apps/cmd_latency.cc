// slshadow latency: how long to wait after the projector's Show() before triggering cameras.
#include <CLI/CLI.hpp>
#include <cstdio>

#include "apps/commands.h"
#include "capture/window_projector.h"
#include "core/error.h"

namespace slshadow::app {

int RunLatency(int argc, char** argv) {
  CLI::App app{
      "Projector latency. Opens the window projector (an SDL2 fullscreen borderless window on the X display\n"
      "$DISPLAY), alternates black and white and reads the window back from the X server until each frame\n"
      "is there: the present-to-framebuffer latency (for Xvfb, the whole latency). A real projector adds its\n"
      "own input lag on top, which only a camera sees (capture/latency.h: MeasureProjectorLatency).\n"
      "Example:\n"
      "  slshadow latency --geometry 1920,0,1280,800 --samples 50",
      argv[0]};
  int display = 0, samples = 20;
  std::string geometry, renderer = "software";
  bool no_vsync = false;
  app.add_option("--display", display, "SDL display index of the projector (fullscreen window)")->capture_default_str();
  app.add_option("--geometry", geometry, "window at x,y,w,h on the X screen instead of a fullscreen display");
  app.add_option("--renderer", renderer, "SDL renderer")->capture_default_str()->check(
      CLI::IsMember({"software", "opengl", "auto"}));
  app.add_flag("--no-vsync", no_vsync, "present without waiting for the refresh");
  app.add_option("--samples", samples, "black/white pairs")->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  SLSHADOW_THROW_IF(samples < 1, "--samples: must be positive (got ", samples, ")");
  capture::WindowProjectorOptions options;
  options.display_index = display;
  if (!geometry.empty()) options.geometry = capture::ParseWindowGeometry(geometry);
  options.renderer = renderer;
  options.vsync = !no_vsync;
  capture::WindowProjector projector(options);
  const capture::ProjectorInfo info = projector.Info();
  std::printf("projector: window %s, %dx%d, %.0f Hz, %s renderer, vsync %s\n", info.id.c_str(), info.width, info.height,
              info.refresh_hz, projector.RendererName().c_str(), options.vsync ? "on" : "off");
  std::printf("%s\n", projector.MeasurePresentLatency(samples).BriefReport().c_str());
  return 0;
}

}  // namespace slshadow::app
