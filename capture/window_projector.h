// The HDMI projector as a window: an SDL2 fullscreen borderless window on one display (by SDL
// display index), or a borderless window at an explicit X geometry `x,y,w,h` (for one wide X
// screen spanning a monitor and the projector). Patterns are uploaded once as textures (Load) and
// drawn 1:1, no scaling or filtering, so the framebuffer holds the pattern's grey value in R, G
// and B; Show presents with vsync and returns after the swap.
//
// Threading: SDL wants a window and its renderer used from one thread. The projector owns that
// thread: the constructor starts it and creates the window there, and every public method hands
// its work to it and waits. So any thread (e.g. the sequencer's) may call Show. One window
// projector per process at a time (SDL's video subsystem is process-wide): a second one throws.
//
// The X display is $DISPLAY (set it before constructing). SDL's hint
// SDL_VIDEO_MINIMIZE_ON_FOCUS_LOSS is set to "0", so the window stays up when another monitor
// takes the focus. SDL types never leave window_projector.cc.
#pragma once

#include <chrono>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "capture/projector.h"

namespace slshadow::capture {

// A window rectangle in X screen pixels.
struct WindowGeometry {
  int x = 0, y = 0, width = 0, height = 0;
};
// Parses "x,y,w,h" (integers, w and h positive). Throws slshadow::Error quoting `text`.
WindowGeometry ParseWindowGeometry(const std::string& text);

struct WindowProjectorOptions {
  int display_index = 0;                   // SDL display for the fullscreen window
  std::optional<WindowGeometry> geometry;  // set: a borderless window here instead
  // SDL render driver: "software" (default; pixel-exact, needs no GPU), "opengl", or "auto"
  // (SDL's choice).
  std::string renderer = "software";
  // Present synchronised to the display refresh. OpenGL: the swap interval. Software renderer:
  // the projector waits for the next tick of a fixed grid at the refresh rate before presenting.
  bool vsync = true;
  // Refresh rate assumed when the display reports none (Xvfb reports 0 Hz), Hz.
  double fallback_refresh_hz = 60;
  std::chrono::microseconds latency{0};  // initial Latency() (configured or measured)
  void Check() const;                    // throws slshadow::Error naming the field
};

// Present latency of the window measured through the X server (MeasurePresentLatency): from the
// start of the present and from Show()'s return until a read-back of the screen shows the new
// frame. Under Xvfb the X framebuffer is the projector's output; on a real HDMI projector the
// display's own delay comes on top (measure that with a camera: `slshadow latency`).
struct PresentLatency {
  int samples = 0;
  double call_to_screen_ms_median = 0, call_to_screen_ms_max = 0;  // from Show()'s call
  double return_to_screen_ms_median = 0,
         return_to_screen_ms_max = 0;  // from Show()'s return (<= 0: on screen before it returned)
  double show_ms_median = 0;           // duration of Show() itself (vsync wait included)
  std::string BriefReport() const;
};

// One display as SDL sees it on $DISPLAY (for `slshadow devices`).
struct DisplayEntry {
  int index = 0;
  std::string name;
  WindowGeometry bounds;  // position and size on the X screen
  double refresh_hz = 0;  // 0 when the display reports none (Xvfb)
};
// Lists the displays. Throws slshadow::Error when there is no display (no X server), or while a
// WindowProjector is open in this process.
std::vector<DisplayEntry> ListDisplays();

class WindowProjector : public Projector {
 public:
  // Opens the window and shows black. Throws slshadow::Error when SDL has no video device (no X
  // display), the display index does not exist (naming the number of displays), the geometry does
  // not lie on the screen, or the window did not get the requested size.
  explicit WindowProjector(const WindowProjectorOptions& options = {});
  ~WindowProjector() override;
  WindowProjector(const WindowProjector&) = delete;
  WindowProjector& operator=(const WindowProjector&) = delete;

  // backend "window", id "display:N" or "geometry:x,y,w,h", the window's size and the display's
  // refresh rate (fallback_refresh_hz when the display reports none).
  ProjectorInfo Info() const override;
  // Upload as textures; replaces any earlier sequence. Every image must be CV_8UC1 of
  // Info().width x Info().height (throws naming the index otherwise, nothing is replaced).
  void Load(const std::vector<cv::Mat>& images) override;
  // Draws image i 1:1, presents, returns after the present (with vsync: after the swap
  // interval). Throws slshadow::Error for an index outside [0, size()).
  std::chrono::steady_clock::time_point Show(int index) override;
  std::chrono::steady_clock::time_point ShowBlack() override;
  std::chrono::microseconds Latency() const override;
  void SetLatency(std::chrono::microseconds latency) override;
  int size() const override;

  // The window's position on the X screen (for reading it back).
  WindowGeometry Geometry() const;
  // SDL's name of the renderer in use ("software", "opengl", ...).
  std::string RendererName() const;

  // Alternates black and white `samples` times and reads the window back through the X server
  // ($DISPLAY) until each frame is there. Shows black at the end; the loaded sequence is kept.
  // Does not change Latency(): SetLatency with what fits (e.g. return_to_screen_ms_max, at
  // least 0).
  PresentLatency MeasurePresentLatency(int samples = 20);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace slshadow::capture
