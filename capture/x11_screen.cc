#include "capture/x11_screen.h"

#include <sys/ipc.h>
#include <sys/shm.h>

#include <X11/Xlib.h>
#include <X11/Xutil.h>
#include <X11/extensions/XShm.h>

#include <cstdint>
#include <cstdlib>

#include "core/error.h"

namespace slshadow::capture {

// One connection; MIT-SHM when the server offers it (a local Xvfb does), else XGetImage. The
// shared-memory image is kept for the last size read.
struct XScreenReader::Impl {
  std::string name;
  Display* display = nullptr;
  Window root = 0;
  int width = 0, height = 0;
  bool use_shm = false;
  XImage* shm_image = nullptr;
  XShmSegmentInfo shm_info{};

  void FreeShm() {
    if (!shm_image) return;
    XShmDetach(display, &shm_info);
    XSync(display, False);
    XDestroyImage(shm_image);
    shmdt(shm_info.shmaddr);
    shm_image = nullptr;
  }

  // An XImage of rect's size holding the screen content; owned by the caller unless shm.
  XImage* Read(const cv::Rect& rect, bool* owned) {
    if (use_shm) {
      if (!shm_image || shm_image->width != rect.width || shm_image->height != rect.height) {
        FreeShm();
        Visual* visual = DefaultVisual(display, DefaultScreen(display));
        const int depth = DefaultDepth(display, DefaultScreen(display));
        shm_image = XShmCreateImage(display, visual, static_cast<unsigned>(depth), ZPixmap, nullptr,
                                    &shm_info, static_cast<unsigned>(rect.width),
                                    static_cast<unsigned>(rect.height));
        if (shm_image) {
          shm_info.shmid = shmget(
              IPC_PRIVATE,
              static_cast<size_t>(shm_image->bytes_per_line) * static_cast<size_t>(rect.height),
              IPC_CREAT | 0600);
          shm_info.shmaddr = shm_image->data =
              static_cast<char*>(shmat(shm_info.shmid, nullptr, 0));
          shm_info.readOnly = False;
          const bool attached =
              shm_info.shmaddr != reinterpret_cast<char*>(-1) && XShmAttach(display, &shm_info);
          XSync(display, False);
          shmctl(shm_info.shmid, IPC_RMID, nullptr);  // freed when both sides detach
          if (!attached) {
            XDestroyImage(shm_image);
            shm_image = nullptr;
          }
        }
        if (!shm_image) use_shm = false;
      }
      if (shm_image && XShmGetImage(display, root, shm_image, rect.x, rect.y, AllPlanes)) {
        *owned = false;
        return shm_image;
      }
    }
    *owned = true;
    return XGetImage(display, root, rect.x, rect.y, static_cast<unsigned>(rect.width),
                     static_cast<unsigned>(rect.height), AllPlanes, ZPixmap);
  }
};

XScreenReader::XScreenReader(const std::string& display_name, bool allow_shm)
    : impl_(std::make_unique<Impl>()) {
  const char* env = std::getenv("DISPLAY");
  impl_->name = !display_name.empty() ? display_name : (env ? env : "");
  SLSHADOW_THROW_IF(impl_->name.empty(), "X screen: no display given and $DISPLAY is not set");
  impl_->display = XOpenDisplay(impl_->name.c_str());
  SLSHADOW_THROW_IF(!impl_->display, "X screen: cannot connect to X display '", impl_->name, "'");
  const int screen = DefaultScreen(impl_->display);
  impl_->root = RootWindow(impl_->display, screen);
  impl_->width = DisplayWidth(impl_->display, screen);
  impl_->height = DisplayHeight(impl_->display, screen);
  Visual* visual = DefaultVisual(impl_->display, screen);
  const int depth = DefaultDepth(impl_->display, screen);
  if ((depth != 24 && depth != 32) || visual->red_mask != 0xff0000 ||
      visual->green_mask != 0x00ff00 || visual->blue_mask != 0x0000ff) {
    XCloseDisplay(impl_->display);
    SLSHADOW_THROW(
        "X screen '", impl_->name, "': depth ", depth,
        " is not 24-bit TrueColor with 8-bit R, G, B (start the server with -screen 0 WxHx24)");
  }
  // Shared memory only with a local server (":N", "unix:N"): for a remote one XShmAttach fails with
  // an X error, which Xlib's default handler turns into exit().
  const bool local = impl_->name[0] == ':' || impl_->name.rfind("unix:", 0) == 0;
  impl_->use_shm = allow_shm && local && XShmQueryExtension(impl_->display);
}

XScreenReader::~XScreenReader() {
  impl_->FreeShm();
  XCloseDisplay(impl_->display);
}

const std::string& XScreenReader::display_name() const { return impl_->name; }
int XScreenReader::width() const { return impl_->width; }
bool XScreenReader::uses_shm() const { return impl_->use_shm; }
int XScreenReader::height() const { return impl_->height; }

namespace {

void CheckRect(const cv::Rect& rect, const std::string& name, int width, int height) {
  SLSHADOW_THROW_IF(rect.width <= 0 || rect.height <= 0 || rect.x < 0 || rect.y < 0 ||
                        rect.x + rect.width > width || rect.y + rect.height > height,
                    "X screen '", name, "': region ", rect.x, ",", rect.y, ",", rect.width, ",",
                    rect.height, " is not inside the ", width, "x", height, " screen");
}

}  // namespace

cv::Mat XScreenReader::ReadBgr(const cv::Rect& rect) { return Read(rect, 3); }
cv::Mat XScreenReader::ReadGrey(const cv::Rect& rect) { return Read(rect, 1); }

cv::Mat XScreenReader::Read(const cv::Rect& rect, int channels) {
  CheckRect(rect, impl_->name, impl_->width, impl_->height);
  bool owned = false;
  XImage* image = impl_->Read(rect, &owned);
  SLSHADOW_THROW_IF(!image, "X screen '", impl_->name, "': XGetImage failed");
  SLSHADOW_CHECK(image->bits_per_pixel == 32 && image->byte_order == LSBFirst);
  cv::Mat out(rect.height, rect.width, channels == 3 ? CV_8UC3 : CV_8UC1);
  for (int y = 0; y < rect.height; ++y) {
    const auto* src = reinterpret_cast<const uint8_t*>(image->data + static_cast<ptrdiff_t>(y) *
                                                                         image->bytes_per_line);
    auto* dst = out.ptr<uint8_t>(y);
    if (channels == 3) {
      for (int x = 0; x < rect.width; ++x) {  // LSB-first 0x00RRGGBB: bytes B, G, R, X
        dst[3 * x + 0] = src[4 * x + 0];
        dst[3 * x + 1] = src[4 * x + 1];
        dst[3 * x + 2] = src[4 * x + 2];
      }
    } else {
      for (int x = 0; x < rect.width; ++x) dst[x] = src[4 * x + 1];
    }
  }
  if (owned) XDestroyImage(image);
  return out;
}

}  // namespace slshadow::capture
