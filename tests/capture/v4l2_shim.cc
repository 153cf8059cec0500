// An LD_PRELOAD shim that plays a UVC camera for tests of capture/v4l2_camera.cc (no V4L2 kernel
// route exists on CI machines: ../shared/DEVICE-MOCKS.md). open() of the device path returns a
// memfd; buffers live in it at page-aligned offsets index * stride, so mmap and poll work natively;
// ioctl() on that fd implements QUERYCAP, ENUM_FMT, G/S/TRY_FMT, G/S_PARM, REQBUFS(MMAP), QUERYBUF,
// QBUF, DQBUF, STREAMON/OFF, QUERYCTRL, G/S_CTRL. Every other fd goes to libc.
//
// Configured through the environment, read at open():
//   V4L2_SHIM_DEVICE   device path (default /dev/video0)
//   V4L2_SHIM_FORMAT   GREY | Y16 | YUYV: the one format the device offers
//   V4L2_SHIM_WIDTH, V4L2_SHIM_HEIGHT
//   V4L2_SHIM_FRAMES   a file of raw frames back to back in that format; served once, in order,
//                      after which DQBUF says EAGAIN for ever (a device that stopped delivering)
//   V4L2_SHIM_CONTROLS "exposure,gain" (default): the controls the device has
//   V4L2_SHIM_ERROR_FRAME, V4L2_SHIM_SHORT_FRAME: the sequence number of one frame delivered with
//                      V4L2_BUF_FLAG_ERROR, resp. with half its bytes
#include <dlfcn.h>
#include <fcntl.h>
#include <linux/videodev2.h>
#include <sys/mman.h>
#include <unistd.h>

#include <cerrno>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <mutex>
#include <string>
#include <vector>

namespace {

struct Device {
  int fd = -1;
  uint32_t pixelformat = V4L2_PIX_FMT_GREY;
  uint32_t width = 0, height = 0, bpp = 1;
  std::vector<uint32_t> buffers_len;  // count of buffers
  std::deque<uint32_t> queued;
  bool streaming = false;
  FILE* frames = nullptr;
  uint32_t sequence = 0;
  bool has_exposure = true, has_gain = true;
  int32_t exposure_auto = V4L2_EXPOSURE_APERTURE_PRIORITY, exposure = 100, gain = 0;
  uint32_t fps = 30;
  int64_t error_frame = -1, short_frame = -1;
  uint32_t sizeimage() const { return width * height * bpp; }
  // Buffer offsets are page-aligned, as a driver's are (mmap needs it).
  uint32_t stride() const { return (sizeimage() + 4095u) / 4096u * 4096u; }
};

std::mutex g_mutex;
Device g_dev;

const char* Env(const char* name, const char* fallback) {
  const char* v = std::getenv(name);
  return v ? v : fallback;
}

template <typename F>
F Next(const char* name) {
  return reinterpret_cast<F>(dlsym(RTLD_NEXT, name));
}

int OpenShim() {
  std::lock_guard lock(g_mutex);
  if (g_dev.fd >= 0) {
    errno = EBUSY;
    return -1;
  }
  g_dev = Device{};
  const std::string format = Env("V4L2_SHIM_FORMAT", "GREY");
  if (format == "Y16") {
    g_dev.pixelformat = V4L2_PIX_FMT_Y16;
    g_dev.bpp = 2;
  } else if (format == "YUYV") {
    g_dev.pixelformat = V4L2_PIX_FMT_YUYV;
    g_dev.bpp = 2;
  }
  g_dev.width = static_cast<uint32_t>(std::atoi(Env("V4L2_SHIM_WIDTH", "64")));
  g_dev.height = static_cast<uint32_t>(std::atoi(Env("V4L2_SHIM_HEIGHT", "48")));
  const std::string controls = Env("V4L2_SHIM_CONTROLS", "exposure,gain");
  g_dev.has_exposure = controls.find("exposure") != std::string::npos;
  g_dev.has_gain = controls.find("gain") != std::string::npos;
  g_dev.error_frame = std::atoll(Env("V4L2_SHIM_ERROR_FRAME", "-1"));
  g_dev.short_frame = std::atoll(Env("V4L2_SHIM_SHORT_FRAME", "-1"));
  const char* frames = std::getenv("V4L2_SHIM_FRAMES");
  if (frames) g_dev.frames = std::fopen(frames, "rb");
  g_dev.fd = memfd_create("v4l2-shim", 0);
  return g_dev.fd;
}

bool IsShimPath(const char* path) {
  return path && std::strcmp(path, Env("V4L2_SHIM_DEVICE", "/dev/video0")) == 0;
}

void FillFormat(v4l2_format* f) {
  f->type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  f->fmt.pix.width = g_dev.width;
  f->fmt.pix.height = g_dev.height;
  f->fmt.pix.pixelformat = g_dev.pixelformat;
  f->fmt.pix.field = V4L2_FIELD_NONE;
  f->fmt.pix.bytesperline = g_dev.width * g_dev.bpp;
  f->fmt.pix.sizeimage = g_dev.sizeimage();
}

int Fail(int e) {
  errno = e;
  return -1;
}

int ShimIoctl(unsigned long request, void* arg) {
  std::lock_guard lock(g_mutex);
  switch (request) {
    case VIDIOC_QUERYCAP: {
      auto* c = static_cast<v4l2_capability*>(arg);
      std::memset(c, 0, sizeof *c);
      std::snprintf(reinterpret_cast<char*>(c->driver), sizeof c->driver, "uvcvideo");
      std::snprintf(reinterpret_cast<char*>(c->card), sizeof c->card, "Shim UVC Camera");
      std::snprintf(reinterpret_cast<char*>(c->bus_info), sizeof c->bus_info, "usb-shim-1");
      c->capabilities = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING | V4L2_CAP_DEVICE_CAPS;
      c->device_caps = V4L2_CAP_VIDEO_CAPTURE | V4L2_CAP_STREAMING;
      return 0;
    }
    case VIDIOC_ENUM_FMT: {
      auto* f = static_cast<v4l2_fmtdesc*>(arg);
      if (f->index != 0 || f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return Fail(EINVAL);
      f->pixelformat = g_dev.pixelformat;
      f->flags = 0;
      return 0;
    }
    case VIDIOC_G_FMT:
    case VIDIOC_S_FMT:
    case VIDIOC_TRY_FMT: {
      auto* f = static_cast<v4l2_format*>(arg);
      if (f->type != V4L2_BUF_TYPE_VIDEO_CAPTURE) return Fail(EINVAL);
      if (request == VIDIOC_S_FMT && !g_dev.buffers_len.empty()) return Fail(EBUSY);
      FillFormat(f);  // one fixed mode: the driver adjusts every request to it
      return 0;
    }
    case VIDIOC_G_PARM:
    case VIDIOC_S_PARM: {
      auto* p = static_cast<v4l2_streamparm*>(arg);
      if (request == VIDIOC_S_PARM && p->parm.capture.timeperframe.numerator > 0) {
        g_dev.fps =
            p->parm.capture.timeperframe.denominator / p->parm.capture.timeperframe.numerator;
      }
      p->parm.capture.capability = V4L2_CAP_TIMEPERFRAME;
      p->parm.capture.timeperframe = {1, g_dev.fps};
      return 0;
    }
    case VIDIOC_REQBUFS: {
      auto* r = static_cast<v4l2_requestbuffers*>(arg);
      if (r->memory != V4L2_MEMORY_MMAP) return Fail(EINVAL);
      if (g_dev.streaming) return Fail(EBUSY);
      g_dev.queued.clear();
      g_dev.buffers_len.assign(std::min<uint32_t>(r->count, 8), g_dev.sizeimage());
      r->count = static_cast<uint32_t>(g_dev.buffers_len.size());
      if (ftruncate(g_dev.fd, static_cast<off_t>(r->count) * g_dev.stride()) != 0) return -1;
      return 0;
    }
    case VIDIOC_QUERYBUF:
    case VIDIOC_QBUF: {
      auto* b = static_cast<v4l2_buffer*>(arg);
      if (b->index >= g_dev.buffers_len.size() || b->memory != V4L2_MEMORY_MMAP)
        return Fail(EINVAL);
      if (request == VIDIOC_QBUF) {
        g_dev.queued.push_back(b->index);
        return 0;
      }
      b->length = g_dev.sizeimage();
      b->m.offset = b->index * g_dev.stride();
      b->flags = 0;
      return 0;
    }
    case VIDIOC_DQBUF: {
      auto* b = static_cast<v4l2_buffer*>(arg);
      if (!g_dev.streaming) return Fail(EINVAL);
      if (g_dev.queued.empty() || g_dev.frames == nullptr) return Fail(EAGAIN);
      const uint32_t index = g_dev.queued.front();
      std::vector<char> frame(g_dev.sizeimage());
      if (std::fread(frame.data(), 1, frame.size(), g_dev.frames) != frame.size())
        return Fail(EAGAIN);  // stopped
      if (pwrite(g_dev.fd, frame.data(), frame.size(),
                 static_cast<off_t>(index) * g_dev.stride()) !=
          static_cast<ssize_t>(frame.size())) {
        return Fail(EIO);
      }
      g_dev.queued.pop_front();
      b->index = index;
      b->bytesused = g_dev.sizeimage();
      b->length = g_dev.sizeimage();
      b->sequence = g_dev.sequence++;
      b->flags = V4L2_BUF_FLAG_MAPPED | V4L2_BUF_FLAG_DONE | V4L2_BUF_FLAG_TIMESTAMP_MONOTONIC;
      if (int64_t(b->sequence) == g_dev.error_frame) b->flags |= V4L2_BUF_FLAG_ERROR;
      if (int64_t(b->sequence) == g_dev.short_frame) b->bytesused /= 2;
      b->field = V4L2_FIELD_NONE;
      b->timestamp.tv_sec = 1000 + b->sequence / g_dev.fps;
      b->timestamp.tv_usec = static_cast<long>((b->sequence % g_dev.fps) * (1000000 / g_dev.fps));
      return 0;
    }
    case VIDIOC_STREAMON:
      g_dev.streaming = true;
      return 0;
    case VIDIOC_STREAMOFF:
      g_dev.streaming = false;
      g_dev.queued.clear();
      return 0;
    case VIDIOC_QUERYCTRL: {
      auto* q = static_cast<v4l2_queryctrl*>(arg);
      const uint32_t id = q->id;
      std::memset(q, 0, sizeof *q);
      q->id = id;
      if (id == V4L2_CID_EXPOSURE_ABSOLUTE && g_dev.has_exposure) {
        q->type = V4L2_CTRL_TYPE_INTEGER, q->minimum = 1, q->maximum = 10000, q->step = 1,
        q->default_value = 100;
      } else if (id == V4L2_CID_EXPOSURE_AUTO && g_dev.has_exposure) {
        q->type = V4L2_CTRL_TYPE_MENU, q->minimum = 0, q->maximum = 3, q->step = 1,
        q->default_value = 3;
      } else if (id == V4L2_CID_GAIN && g_dev.has_gain) {
        q->type = V4L2_CTRL_TYPE_INTEGER, q->minimum = 0, q->maximum = 255, q->step = 1,
        q->default_value = 0;
      } else {
        return Fail(EINVAL);
      }
      return 0;
    }
    case VIDIOC_G_CTRL:
    case VIDIOC_S_CTRL: {
      auto* c = static_cast<v4l2_control*>(arg);
      int32_t* slot = nullptr;
      if (c->id == V4L2_CID_EXPOSURE_ABSOLUTE && g_dev.has_exposure) slot = &g_dev.exposure;
      if (c->id == V4L2_CID_EXPOSURE_AUTO && g_dev.has_exposure) slot = &g_dev.exposure_auto;
      if (c->id == V4L2_CID_GAIN && g_dev.has_gain) slot = &g_dev.gain;
      if (slot == nullptr) return Fail(EINVAL);
      if (request == VIDIOC_G_CTRL) {
        c->value = *slot;
        return 0;
      }
      // UVC: absolute exposure only in manual mode.
      if (slot == &g_dev.exposure && g_dev.exposure_auto != V4L2_EXPOSURE_MANUAL)
        return Fail(EACCES);
      if (c->value < 0 || (slot == &g_dev.exposure && (c->value < 1 || c->value > 10000)) ||
          (slot == &g_dev.gain && c->value > 255)) {
        return Fail(ERANGE);
      }
      *slot = c->value;
      return 0;
    }
    default:
      return Fail(ENOTTY);
  }
}

bool IsShimFd(int fd) {
  std::lock_guard lock(g_mutex);
  return fd >= 0 && fd == g_dev.fd;
}

}  // namespace

extern "C" {

int open(const char* path, int flags, ...) {
  if (IsShimPath(path)) return OpenShim();
  va_list ap;
  va_start(ap, flags);
  const mode_t mode = (flags & (O_CREAT | O_TMPFILE)) ? va_arg(ap, mode_t) : 0;
  va_end(ap);
  static auto real = Next<int (*)(const char*, int, ...)>("open");
  return real(path, flags, mode);
}

int open64(const char* path, int flags, ...) {
  if (IsShimPath(path)) return OpenShim();
  va_list ap;
  va_start(ap, flags);
  const mode_t mode = (flags & (O_CREAT | O_TMPFILE)) ? va_arg(ap, mode_t) : 0;
  va_end(ap);
  static auto real = Next<int (*)(const char*, int, ...)>("open64");
  return real(path, flags, mode);
}

int openat(int dirfd, const char* path, int flags, ...) {
  if (IsShimPath(path)) return OpenShim();
  va_list ap;
  va_start(ap, flags);
  const mode_t mode = (flags & (O_CREAT | O_TMPFILE)) ? va_arg(ap, mode_t) : 0;
  va_end(ap);
  static auto real = Next<int (*)(int, const char*, int, ...)>("openat");
  return real(dirfd, path, flags, mode);
}

int close(int fd) {
  {
    std::lock_guard lock(g_mutex);
    if (fd >= 0 && fd == g_dev.fd) {
      g_dev.fd = -1;
      if (g_dev.frames) std::fclose(g_dev.frames);
      g_dev.frames = nullptr;
    }
  }
  static auto real = Next<int (*)(int)>("close");
  return real(fd);
}

int ioctl(int fd, unsigned long request, ...) {
  va_list ap;
  va_start(ap, request);
  void* arg = va_arg(ap, void*);
  va_end(ap);
  if (IsShimFd(fd)) return ShimIoctl(request, arg);
  static auto real = Next<int (*)(int, unsigned long, ...)>("ioctl");
  return real(fd, request, arg);
}

}  // extern "C"
