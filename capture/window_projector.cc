#include "capture/window_projector.h"

#include <SDL.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <functional>
#include <future>
#include <mutex>
#include <thread>

#include "capture/x11_screen.h"
#include "core/error.h"
#include "core/statistics.h"

namespace slshadow::capture {

namespace {

std::atomic<bool> g_window_open{false};  // one window projector per process

std::string SdlError() {
  const char* e = SDL_GetError();
  return e && *e ? e : "no SDL error message";
}

// SDL_InitSubSystem(VIDEO), tried three times 200 ms apart: the X connection (XOpenDisplay inside
// SDL) was seen failing once, transiently, on a loaded machine with a running server.
bool InitVideo() {
  for (int attempt = 0; attempt < 3; ++attempt) {
    if (attempt > 0) std::this_thread::sleep_for(std::chrono::milliseconds(200));
    if (SDL_InitSubSystem(SDL_INIT_VIDEO) == 0) return true;
  }
  return false;
}

double Ms(std::chrono::steady_clock::duration d) {
  return std::chrono::duration<double, std::milli>(d).count();
}

}  // namespace

WindowGeometry ParseWindowGeometry(const std::string& text) {
  WindowGeometry g;
  int consumed = -1;
  const int fields = std::sscanf(text.c_str(), " %d , %d , %d , %d %n", &g.x, &g.y, &g.width,
                                 &g.height, &consumed);
  SLSHADOW_THROW_IF(fields != 4 || consumed != static_cast<int>(text.size()), "geometry: '", text,
                    "' is not x,y,w,h (four integers, e.g. 1920,0,1280,800)");
  SLSHADOW_THROW_IF(g.width <= 0 || g.height <= 0, "geometry: '", text,
                    "': width and height must be positive");
  return g;
}

void WindowProjectorOptions::Check() const {
  SLSHADOW_THROW_IF(display_index < 0, "window projector: display_index must not be negative (got ",
                    display_index, ")");
  if (geometry) {
    SLSHADOW_THROW_IF(geometry->width <= 0 || geometry->height <= 0,
                      "window projector: geometry: width and height must be ", "positive (got ",
                      geometry->width, "x", geometry->height, ")");
  }
  SLSHADOW_THROW_IF(renderer != "software" && renderer != "opengl" && renderer != "auto",
                    "window projector: renderer: '", renderer, "' is not software, opengl or auto");
  SLSHADOW_THROW_IF(latency.count() < 0, "window projector: latency must not be negative (got ",
                    latency.count(), " us)");
  SLSHADOW_THROW_IF(!(fallback_refresh_hz > 0 && fallback_refresh_hz <= 1000),
                    "window projector: fallback_refresh_hz must be in (0, 1000] (got ",
                    fallback_refresh_hz, ")");
}

std::string PresentLatency::BriefReport() const {
  char line[320];
  std::snprintf(line, sizeof line,
                "present latency over %d frames: call to screen median %.2f ms (max %.2f), return "
                "to screen median %.2f ms "
                "(max %.2f), Show() median %.2f ms",
                samples, call_to_screen_ms_median, call_to_screen_ms_max,
                return_to_screen_ms_median, return_to_screen_ms_max, show_ms_median);
  return line;
}

// Everything SDL lives on `thread`; Run() hands it a task and waits for it.
struct WindowProjector::Impl {
  WindowProjectorOptions options;
  ProjectorInfo info;
  WindowGeometry geometry;
  std::string renderer_name;
  std::atomic<int64_t> latency_us{0};
  int num_images = 0;  // guarded by the calling side's Run (tasks run one at a time)

  // Render thread state (touched only on `thread`).
  SDL_Window* window = nullptr;
  SDL_Renderer* renderer = nullptr;
  std::vector<SDL_Texture*> textures;
  int current = -1;  // image on screen; -1 black, -2 white
  bool video_initialised = false;
  bool sdl_vsync = false, own_pacing = false;
  std::chrono::steady_clock::duration period{};
  std::chrono::steady_clock::time_point last_tick{};

  // Hand-over.
  std::thread thread;
  std::mutex mutex;
  std::condition_variable cv;
  std::function<void()> task;
  bool task_done = false;
  bool quit = false;
  std::exception_ptr task_error;
  std::mutex run_mutex;  // one caller at a time

  void Run(std::function<void()> fn) {
    std::lock_guard<std::mutex> caller(run_mutex);
    std::unique_lock<std::mutex> lock(mutex);
    task = std::move(fn);
    task_done = false;
    task_error = nullptr;
    cv.notify_all();
    cv.wait(lock, [&] { return task_done; });
    if (task_error) std::rethrow_exception(task_error);
  }

  void Loop() {
    std::unique_lock<std::mutex> lock(mutex);
    while (true) {
      cv.wait_for(lock, std::chrono::milliseconds(50), [&] { return task || quit; });
      if (task) {
        auto fn = std::move(task);
        task = nullptr;
        lock.unlock();
        std::exception_ptr error;
        try {
          fn();
        } catch (...) {
          error = std::current_exception();
        }
        lock.lock();
        task_error = error;
        task_done = true;
        cv.notify_all();
      } else if (quit) {
        return;
      } else if (window) {
        lock.unlock();
        PumpEvents();
        lock.lock();
      }
    }
  }

  // Keeps the window responsive; redraws what should be on screen when the X server lost it.
  void PumpEvents() {
    SDL_Event event;
    bool redraw = false;
    while (SDL_PollEvent(&event)) {
      if (event.type == SDL_WINDOWEVENT && (event.window.event == SDL_WINDOWEVENT_EXPOSED ||
                                            event.window.event == SDL_WINDOWEVENT_RESTORED)) {
        redraw = true;
      }
    }
    if (redraw) Draw(current);
  }

  // Draws image `index` (-1 black, -2 white) and presents. With own pacing (software renderer,
  // vsync on) the present waits for the next tick of a fixed grid at the refresh rate, like a
  // swap at vblank: the frame reaches the screen at the tick and Draw returns right after.
  void Draw(int index) {
    if (index >= 0) {
      SDL_RenderCopy(renderer, textures[static_cast<size_t>(index)], nullptr, nullptr);
    } else {
      const Uint8 level = index == -2 ? 255 : 0;
      SDL_SetRenderDrawColor(renderer, level, level, level, 255);
      SDL_RenderClear(renderer);
    }
    if (own_pacing) {
      const auto now = std::chrono::steady_clock::now();
      if (last_tick.time_since_epoch().count() == 0 || now - last_tick > std::chrono::seconds(1)) {
        last_tick = now;  // start (or restart after idling) the grid here
      } else {
        last_tick += period * ((now - last_tick) / period + 1);
        std::this_thread::sleep_until(last_tick);
      }
    }
    SDL_RenderPresent(renderer);
    current = index;
  }

  void Open() {
    SDL_SetHint(SDL_HINT_VIDEO_MINIMIZE_ON_FOCUS_LOSS, "0");
    SDL_SetHint(SDL_HINT_RENDER_SCALE_QUALITY, "0");  // nearest: 1:1 anyway, never filtered
    // The software renderer has no vsync of its own (SDL would simulate it with millisecond
    // sleeps): the projector paces it itself (Draw). OpenGL uses the swap interval.
    sdl_vsync = options.vsync && options.renderer != "software";
    SDL_SetHint(SDL_HINT_RENDER_VSYNC, sdl_vsync ? "1" : "0");
    if (options.renderer == "software") {
      // Also keeps SDL from backing the window surface with a GL texture.
      SDL_SetHint(SDL_HINT_RENDER_DRIVER, "software");
      SDL_SetHint(SDL_HINT_FRAMEBUFFER_ACCELERATION, "0");
    } else if (options.renderer == "opengl") {
      SDL_SetHint(SDL_HINT_RENDER_DRIVER, "opengl");
    }
    // X11 unless the user chose another driver (SDL_VIDEODRIVER): the geometry is an X screen
    // position, and SDL's fallbacks (offscreen, ...) show nothing.
    if (!std::getenv("SDL_VIDEODRIVER")) SDL_SetHint(SDL_HINT_VIDEODRIVER, "x11");
    if (!InitVideo()) {
      const char* display = std::getenv("DISPLAY");
      SLSHADOW_THROW("window projector: no display: SDL cannot start video (DISPLAY='",
                     display ? display : "", "'): ", SdlError());
    }
    video_initialised = true;
    const std::string driver = SDL_GetCurrentVideoDriver() ? SDL_GetCurrentVideoDriver() : "";
    SLSHADOW_THROW_IF(driver == "offscreen" || driver == "dummy",
                      "window projector: no display: SDL video driver '", driver,
                      "' shows nothing");
    const int displays = SDL_GetNumVideoDisplays();
    SLSHADOW_THROW_IF(displays < 1, "window projector: SDL finds no display: ", SdlError());
    Uint32 flags = SDL_WINDOW_BORDERLESS | SDL_WINDOW_SHOWN;
    SDL_DisplayMode mode{};
    if (options.geometry) {
      geometry = *options.geometry;
      // The geometry must lie on one display's area of the X screen (one wide screen, typically).
      bool inside = false;
      for (int d = 0; d < displays && !inside; ++d) {
        SDL_Rect b;
        if (SDL_GetDisplayBounds(d, &b) != 0) continue;
        inside = geometry.x >= b.x && geometry.y >= b.y &&
                 geometry.x + geometry.width <= b.x + b.w &&
                 geometry.y + geometry.height <= b.y + b.h;
        if (inside) SDL_GetCurrentDisplayMode(d, &mode);
      }
      SLSHADOW_THROW_IF(!inside, "window projector: geometry ", geometry.x, ",", geometry.y, ",",
                        geometry.width, ",", geometry.height, " does not lie on a display (",
                        displays, " display(s); display 0 is ", DisplayText(0), ")");
      info.id = "geometry:" + std::to_string(geometry.x) + "," + std::to_string(geometry.y) + "," +
                std::to_string(geometry.width) + "," + std::to_string(geometry.height);
    } else {
      SLSHADOW_THROW_IF(options.display_index >= displays, "window projector: display_index ",
                        options.display_index, " does not exist (", displays, " display(s): 0..",
                        displays - 1, ")");
      SDL_Rect b;
      SLSHADOW_THROW_IF(SDL_GetDisplayBounds(options.display_index, &b) != 0,
                        "window projector: display ", options.display_index, ": ", SdlError());
      geometry = {b.x, b.y, b.w, b.h};
      SDL_GetCurrentDisplayMode(options.display_index, &mode);
      flags |= SDL_WINDOW_FULLSCREEN_DESKTOP;
      info.id = "display:" + std::to_string(options.display_index);
    }
    window = SDL_CreateWindow("slshadow projector", geometry.x, geometry.y, geometry.width,
                              geometry.height, flags);
    SLSHADOW_THROW_IF(!window, "window projector: cannot create the window (", info.id,
                      "): ", SdlError());
    SDL_ShowCursor(SDL_DISABLE);
    Uint32 renderer_flags = sdl_vsync ? SDL_RENDERER_PRESENTVSYNC : 0;
    renderer_flags |= options.renderer == "software" ? SDL_RENDERER_SOFTWARE : 0;
    renderer = SDL_CreateRenderer(window, -1, renderer_flags);
    SLSHADOW_THROW_IF(!renderer, "window projector: renderer '", options.renderer,
                      "' unavailable: ", SdlError());
    SDL_RendererInfo rinfo{};
    SDL_GetRendererInfo(renderer, &rinfo);
    renderer_name = rinfo.name ? rinfo.name : "";
    int w = 0, h = 0;
    SDL_GetRendererOutputSize(renderer, &w, &h);
    SLSHADOW_THROW_IF(w != geometry.width || h != geometry.height, "window projector: the window (",
                      info.id, ") is ", w, "x", h, ", not the requested ", geometry.width, "x",
                      geometry.height, " (a window manager resized it?)");
    int wx = 0, wy = 0;
    SDL_GetWindowPosition(window, &wx, &wy);
    SLSHADOW_THROW_IF(wx != geometry.x || wy != geometry.y, "window projector: the window (",
                      info.id, ") is at ", wx, ",", wy, ", not at the requested ", geometry.x, ",",
                      geometry.y, " (a window manager moved it?)");
    info.backend = "window";
    info.width = geometry.width;
    info.height = geometry.height;
    info.refresh_hz = mode.refresh_rate > 0 ? mode.refresh_rate : options.fallback_refresh_hz;
    own_pacing = options.vsync && !sdl_vsync;
    period = std::chrono::duration_cast<std::chrono::steady_clock::duration>(
        std::chrono::duration<double>(1.0 / info.refresh_hz));
    PumpEvents();
    Draw(-1);
  }

  static std::string DisplayText(int d) {
    SDL_Rect b;
    if (SDL_GetDisplayBounds(d, &b) != 0) return "unknown";
    return std::to_string(b.x) + "," + std::to_string(b.y) + "," + std::to_string(b.w) + "," +
           std::to_string(b.h);
  }

  void DestroyTextures() {
    for (SDL_Texture* t : textures) SDL_DestroyTexture(t);
    textures.clear();
  }

  void Close() {
    DestroyTextures();
    if (renderer) SDL_DestroyRenderer(renderer);
    if (window) SDL_DestroyWindow(window);
    renderer = nullptr;
    window = nullptr;
    if (video_initialised) SDL_QuitSubSystem(SDL_INIT_VIDEO);
    video_initialised = false;
  }
};

WindowProjector::WindowProjector(const WindowProjectorOptions& options)
    : impl_(std::make_unique<Impl>()) {
  options.Check();
  bool expected = false;
  SLSHADOW_THROW_IF(
      !g_window_open.compare_exchange_strong(expected, true),
      "window projector: another window projector is open in this process (one at a time)");
  impl_->options = options;
  impl_->latency_us = options.latency.count();
  impl_->thread = std::thread([this] { impl_->Loop(); });
  try {
    impl_->Run([this] { impl_->Open(); });
  } catch (...) {
    try {
      impl_->Run([this] { impl_->Close(); });
    } catch (...) {}
    {
      std::lock_guard<std::mutex> lock(impl_->mutex);
      impl_->quit = true;
    }
    impl_->cv.notify_all();
    impl_->thread.join();
    g_window_open = false;
    throw;
  }
}

WindowProjector::~WindowProjector() {
  try {
    impl_->Run([this] { impl_->Close(); });
  } catch (...) {}
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    impl_->quit = true;
  }
  impl_->cv.notify_all();
  impl_->thread.join();
  g_window_open = false;
}

std::vector<DisplayEntry> ListDisplays() {
  bool expected = false;
  SLSHADOW_THROW_IF(
      !g_window_open.compare_exchange_strong(expected, true),
      "displays: a window projector is open in this process; list the displays before opening it");
  std::vector<DisplayEntry> out;
  std::string error;
  // SDL video on a thread of its own, initialised and shut down there (like the projector).
  std::thread([&] {
    if (!std::getenv("SDL_VIDEODRIVER")) SDL_SetHint(SDL_HINT_VIDEODRIVER, "x11");
    if (!InitVideo()) {
      const char* display = std::getenv("DISPLAY");
      error = "displays: no display: SDL cannot start video (DISPLAY='" +
              std::string(display ? display : "") + "'): " + SdlError();
      return;
    }
    for (int d = 0; d < SDL_GetNumVideoDisplays(); ++d) {
      DisplayEntry e;
      e.index = d;
      const char* name = SDL_GetDisplayName(d);
      e.name = name ? name : "";
      SDL_Rect b{};
      SDL_GetDisplayBounds(d, &b);
      e.bounds = {b.x, b.y, b.w, b.h};
      SDL_DisplayMode mode{};
      if (SDL_GetCurrentDisplayMode(d, &mode) == 0) e.refresh_hz = mode.refresh_rate;
      out.push_back(e);
    }
    SDL_QuitSubSystem(SDL_INIT_VIDEO);
  }).join();
  g_window_open = false;
  SLSHADOW_THROW_IF(!error.empty(), error);
  return out;
}

ProjectorInfo WindowProjector::Info() const { return impl_->info; }
WindowGeometry WindowProjector::Geometry() const { return impl_->geometry; }
std::string WindowProjector::RendererName() const { return impl_->renderer_name; }
std::chrono::microseconds WindowProjector::Latency() const {
  return std::chrono::microseconds(impl_->latency_us.load());
}
void WindowProjector::SetLatency(std::chrono::microseconds latency) {
  SLSHADOW_THROW_IF(latency.count() < 0, "window projector: latency must not be negative (got ",
                    latency.count(), " us)");
  impl_->latency_us = latency.count();
}
int WindowProjector::size() const { return impl_->num_images; }

void WindowProjector::Load(const std::vector<cv::Mat>& images) {
  const int w = impl_->info.width, h = impl_->info.height;
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& m = images[i];
    SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.cols != w || m.rows != h, "window projector: image ",
                      i, " is ", m.cols, "x", m.rows,
                      (m.type() == CV_8UC1 ? " 8-bit grey" : " not 8-bit grey (CV_8UC1)"),
                      ", the projector window is ", w, "x", h, " 8-bit grey");
  }
  impl_->Run([&] {
    Impl& s = *impl_;
    std::vector<SDL_Texture*> textures;
    std::vector<uint32_t> argb(static_cast<size_t>(w) * static_cast<size_t>(h));
    for (size_t i = 0; i < images.size(); ++i) {
      SDL_Texture* t =
          SDL_CreateTexture(s.renderer, SDL_PIXELFORMAT_ARGB8888, SDL_TEXTUREACCESS_STATIC, w, h);
      if (!t) {
        for (SDL_Texture* u : textures) SDL_DestroyTexture(u);
        SLSHADOW_THROW("window projector: cannot create texture ", i, " (", w, "x", h,
                       "): ", SdlError());
      }
      SDL_SetTextureBlendMode(t, SDL_BLENDMODE_NONE);
      for (int y = 0; y < h; ++y) {
        const uint8_t* src = images[i].ptr<uint8_t>(y);
        uint32_t* dst = argb.data() + static_cast<size_t>(y) * static_cast<size_t>(w);
        for (int x = 0; x < w; ++x) dst[x] = 0xff000000u | 0x010101u * src[x];
      }
      SDL_UpdateTexture(t, nullptr, argb.data(), w * 4);
      textures.push_back(t);
    }
    s.DestroyTextures();
    s.textures = std::move(textures);
    if (s.current >= 0) s.current = -1;  // what was on screen is no longer a loaded image
    s.num_images = static_cast<int>(s.textures.size());
  });
}

std::chrono::steady_clock::time_point WindowProjector::Show(int index) {
  SLSHADOW_THROW_IF(index < 0 || index >= impl_->num_images, "window projector: Show(", index,
                    "): ", impl_->num_images, " image(s) loaded");
  std::chrono::steady_clock::time_point shown;
  impl_->Run([&] {
    impl_->Draw(index);
    shown = std::chrono::steady_clock::now();
    impl_->PumpEvents();
  });
  return shown;
}

std::chrono::steady_clock::time_point WindowProjector::ShowBlack() {
  std::chrono::steady_clock::time_point shown;
  impl_->Run([&] {
    impl_->Draw(-1);
    shown = std::chrono::steady_clock::now();
    impl_->PumpEvents();
  });
  return shown;
}

PresentLatency WindowProjector::MeasurePresentLatency(int samples) {
  SLSHADOW_THROW_IF(samples < 1,
                    "window projector: MeasurePresentLatency: samples must be positive (got ",
                    samples, ")");
  XScreenReader screen;
  const WindowGeometry g = impl_->geometry;
  // Five probes spread over the window: a frame counts as on screen when all have the new level.
  std::vector<cv::Rect> probes;
  for (auto [fx, fy] : {std::pair{0.5, 0.5}, {0.1, 0.1}, {0.9, 0.1}, {0.1, 0.9}, {0.9, 0.9}}) {
    probes.emplace_back(g.x + static_cast<int>(fx * (g.width - 1)),
                        g.y + static_cast<int>(fy * (g.height - 1)), 1, 1);
  }
  auto on_screen = [&](uint8_t level) {
    for (const cv::Rect& r : probes) {
      if (screen.ReadGrey(r).at<uint8_t>(0, 0) != level) return false;
    }
    return true;
  };
  auto wait_for = [&](uint8_t level) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(5);
    while (!on_screen(level)) {
      SLSHADOW_THROW_IF(std::chrono::steady_clock::now() > deadline, "window projector: level ",
                        int{level}, " did not reach the X screen '", screen.display_name(),
                        "' within 5 s");
    }
    return std::chrono::steady_clock::now();
  };
  std::vector<double> call_ms, return_ms, show_ms;
  for (int i = 0; i < 2 * samples; ++i) {
    const bool white = i % 2 == 0;
    // Present on the render thread while this thread polls the screen, so that a frame reaching
    // the screen before the present returns (software renderer: before the vsync wait) counts.
    const auto called = std::chrono::steady_clock::now();
    std::chrono::steady_clock::time_point returned;
    auto present = std::async(std::launch::async, [&] {
      impl_->Run([&] { impl_->Draw(white ? -2 : -1); });
      returned = std::chrono::steady_clock::now();
    });
    const auto seen = wait_for(white ? 255 : 0);
    present.get();
    call_ms.push_back(Ms(seen - called));
    return_ms.push_back(Ms(seen - returned));
    show_ms.push_back(Ms(returned - called));
  }
  if (impl_->current == -2) ShowBlack();
  PresentLatency r;
  r.samples = static_cast<int>(call_ms.size());
  r.call_to_screen_ms_median = Median(call_ms);
  r.call_to_screen_ms_max = *std::max_element(call_ms.begin(), call_ms.end());
  r.return_to_screen_ms_median = Median(return_ms);
  r.return_to_screen_ms_max = *std::max_element(return_ms.begin(), return_ms.end());
  r.show_ms_median = Median(show_ms);
  return r;
}

}  // namespace slshadow::capture
