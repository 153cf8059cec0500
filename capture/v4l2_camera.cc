#include "capture/v4l2_camera.h"

#include <fcntl.h>
#include <linux/videodev2.h>
#include <poll.h>
#include <sys/ioctl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <thread>

#include "core/error.h"

namespace slshadow::capture {
namespace {

std::string FourCc(uint32_t f) {
  std::string s(4, ' ');
  for (int i = 0; i < 4; ++i) s[i] = static_cast<char>((f >> (8 * i)) & 0xFF);
  return s;
}

int Xioctl(int fd, unsigned long request, void* arg) {
  int rc;
  do {
    rc = ::ioctl(fd, request, arg);
  } while (rc == -1 && errno == EINTR);
  return rc;
}

}  // namespace

std::vector<std::string> ListV4l2Nodes(const std::string& dir) {
  std::vector<std::pair<int, std::string>> found;
  std::error_code ec;
  for (const auto& e : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name.size() <= 5 || name.compare(0, 5, "video") != 0) continue;
    const std::string digits = name.substr(5);
    if (digits.size() > 6 ||
        !std::all_of(digits.begin(), digits.end(), [](char c) { return c >= '0' && c <= '9'; }))
      continue;
    found.emplace_back(std::stoi(digits), e.path().string());
  }
  std::sort(found.begin(), found.end());
  std::vector<std::string> out;
  for (auto& f : found) out.push_back(f.second);
  return out;
}

void V4l2CameraOptions::Check() const {
  SLSHADOW_THROW_IF(buffers < 2 || buffers > 32, "v4l2 camera: buffers: must be 2..32 (got ",
                    buffers, ")");
}

struct V4l2Camera::Impl {
  std::string device;
  int fd = -1;
  V4l2CameraOptions options;
  CameraInfo info;
  CameraSettings settings;
  std::vector<uint32_t> formats;  // fourccs the device offers
  uint32_t fourcc = 0;
  int width = 0, height = 0, bytesperline = 0;
  uint32_t sizeimage = 0;
  struct Buffer {
    void* data = MAP_FAILED;
    size_t length = 0;
  };
  std::vector<Buffer> buffers;
  bool streaming = false;
  StreamStatistics stats;
  std::vector<std::string> warnings;
  int64_t last_sequence = -1;

  [[noreturn]] void Fail(const std::string& what, const std::string& why) const {
    SLSHADOW_THROW(device, ": ", what, ": ", why);
  }
  std::string Errno() const { return std::string(std::strerror(errno)); }

  bool HasControl(uint32_t id) {
    v4l2_queryctrl q{};
    q.id = id;
    return Xioctl(fd, VIDIOC_QUERYCTRL, &q) == 0 && !(q.flags & V4L2_CTRL_FLAG_DISABLED);
  }
  void SetControl(uint32_t id, int32_t value, const std::string& what) {
    v4l2_control c{};
    c.id = id;
    c.value = value;
    if (Xioctl(fd, VIDIOC_S_CTRL, &c) != 0)
      Fail(what, "the device refused value " + std::to_string(value) + " (" + Errno() + ")");
  }
  std::optional<int32_t> GetControl(uint32_t id) const {
    v4l2_control c{};
    c.id = id;
    if (Xioctl(fd, VIDIOC_G_CTRL, &c) != 0) return std::nullopt;
    return c.value;
  }

  void FreeBuffers() {
    for (auto& b : buffers) {
      if (b.data != MAP_FAILED) munmap(b.data, b.length);
    }
    buffers.clear();
    if (fd >= 0) {
      v4l2_requestbuffers r{};
      r.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      r.memory = V4L2_MEMORY_MMAP;
      r.count = 0;
      Xioctl(fd, VIDIOC_REQBUFS, &r);
    }
  }

  void Queue(uint32_t index) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = index;
    if (Xioctl(fd, VIDIOC_QBUF, &b) != 0)
      Fail("QBUF", "buffer " + std::to_string(index) + " refused (" + Errno() + ")");
  }

  cv::Mat Convert(const uint8_t* data) const {
    if (fourcc == V4L2_PIX_FMT_GREY) {
      cv::Mat m(height, width, CV_8UC1);
      for (int y = 0; y < height; ++y)
        std::memcpy(m.ptr(y), data + size_t(y) * bytesperline, size_t(width));
      return m;
    }
    if (fourcc == V4L2_PIX_FMT_Y16) {  // little-endian 16-bit
      cv::Mat m(height, width, CV_16UC1);
      for (int y = 0; y < height; ++y) {
        const uint8_t* row = data + size_t(y) * bytesperline;
        uint16_t* out = m.ptr<uint16_t>(y);
        for (int x = 0; x < width; ++x)
          out[x] = static_cast<uint16_t>(row[2 * x] | row[2 * x + 1] << 8);
      }
      return m;
    }
    // YUYV: Y0 U Y1 V; the luma bytes are every other byte.
    cv::Mat m(height, width, CV_8UC1);
    for (int y = 0; y < height; ++y) {
      const uint8_t* row = data + size_t(y) * bytesperline;
      uint8_t* out = m.ptr<uint8_t>(y);
      for (int x = 0; x < width; ++x) out[x] = row[2 * x];
    }
    return m;
  }
};

V4l2Camera::V4l2Camera(const std::string& device, V4l2CameraOptions options)
    : impl_(std::make_unique<Impl>()) {
  options.Check();
  Impl& d = *impl_;
  d.device = device;
  d.options = options;
  d.fd = ::open(device.c_str(), O_RDWR | O_NONBLOCK | O_CLOEXEC);
  SLSHADOW_THROW_IF(d.fd < 0, device, ": cannot open the V4L2 device (", std::strerror(errno), ")");
  v4l2_capability cap{};
  if (Xioctl(d.fd, VIDIOC_QUERYCAP, &cap) != 0) {
    const std::string why = std::strerror(errno);
    ::close(d.fd);
    SLSHADOW_THROW(device, ": not a V4L2 device (VIDIOC_QUERYCAP: ", why, ")");
  }
  const uint32_t caps =
      (cap.capabilities & V4L2_CAP_DEVICE_CAPS) ? cap.device_caps : cap.capabilities;
  if (!(caps & V4L2_CAP_VIDEO_CAPTURE) || !(caps & V4L2_CAP_STREAMING)) {
    ::close(d.fd);
    SLSHADOW_THROW(device,
                   ": cannot capture video with streaming I/O (a metadata or output node?)");
  }
  d.info.backend = "v4l2";
  d.info.id = device;
  d.info.vendor = reinterpret_cast<const char*>(cap.driver);
  d.info.model = reinterpret_cast<const char*>(cap.card);
  d.info.serial = reinterpret_cast<const char*>(cap.bus_info);
  for (uint32_t i = 0;; ++i) {
    v4l2_fmtdesc f{};
    f.index = i;
    f.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    if (Xioctl(d.fd, VIDIOC_ENUM_FMT, &f) != 0) break;
    d.formats.push_back(f.pixelformat);
    if (f.pixelformat == V4L2_PIX_FMT_Y16) d.info.pixel_formats.push_back(PixelFormat::kMono16);
    if (f.pixelformat == V4L2_PIX_FMT_GREY || f.pixelformat == V4L2_PIX_FMT_YUYV)
      d.info.pixel_formats.push_back(PixelFormat::kMono8);
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(d.fd, VIDIOC_G_FMT, &fmt) == 0) {
    d.info.sensor_width = static_cast<int>(fmt.fmt.pix.width);
    d.info.sensor_height = static_cast<int>(fmt.fmt.pix.height);
  }
}

V4l2Camera::~V4l2Camera() {
  if (impl_->streaming) {
    int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    Xioctl(impl_->fd, VIDIOC_STREAMOFF, &type);
  }
  impl_->FreeBuffers();
  if (impl_->fd >= 0) ::close(impl_->fd);
}

CameraInfo V4l2Camera::Info() const { return impl_->info; }

void V4l2Camera::Configure(const CameraSettings& s) {
  Impl& d = *impl_;
  s.Check(d.device);
  SLSHADOW_THROW_IF(d.streaming, d.device, ": Configure while streaming (call Stop first)");
  if (s.trigger == TriggerMode::kHardware) {
    d.Fail("settings.trigger",
           "UVC cameras have no trigger input (got hardware; use free-run or software)");
  }
  if (s.roi.x != 0 || s.roi.y != 0)
    d.Fail("settings.roi", "V4L2 capture sets a frame size, not an offset (x, y must be 0)");
  d.FreeBuffers();  // drivers refuse a new format while buffers are allocated
  // Pixel format: the device formats that give the requested one.
  std::vector<uint32_t> wanted;
  if (s.pixel_format == PixelFormat::kMono8) wanted = {V4L2_PIX_FMT_GREY, V4L2_PIX_FMT_YUYV};
  if (s.pixel_format == PixelFormat::kMono16) wanted = {V4L2_PIX_FMT_Y16};
  uint32_t fourcc = 0;
  for (uint32_t w : wanted) {
    if (fourcc == 0 && std::find(d.formats.begin(), d.formats.end(), w) != d.formats.end())
      fourcc = w;
  }
  if (fourcc == 0) {
    std::string offered;
    for (uint32_t f : d.formats) offered += (offered.empty() ? "" : ", ") + FourCc(f);
    d.Fail("settings.pixel_format",
           ToString(s.pixel_format) + " needs " +
               (s.pixel_format == PixelFormat::kMono16  ? "Y16"
                : s.pixel_format == PixelFormat::kMono8 ? "GREY or YUYV"
                                                        : "a format V4L2 UVC does not offer") +
               " but the device offers " + (offered.empty() ? "nothing" : offered));
  }
  v4l2_format fmt{};
  fmt.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(d.fd, VIDIOC_G_FMT, &fmt) != 0) d.Fail("VIDIOC_G_FMT", d.Errno());
  fmt.fmt.pix.pixelformat = fourcc;
  if (!s.roi.Full()) {
    fmt.fmt.pix.width = static_cast<uint32_t>(s.roi.width);
    fmt.fmt.pix.height = static_cast<uint32_t>(s.roi.height);
  }
  fmt.fmt.pix.field = V4L2_FIELD_NONE;
  if (Xioctl(d.fd, VIDIOC_S_FMT, &fmt) != 0)
    d.Fail("settings.pixel_format",
           "VIDIOC_S_FMT refused " + FourCc(fourcc) + " (" + d.Errno() + ")");
  if (fmt.fmt.pix.pixelformat != fourcc) {
    d.Fail("settings.pixel_format",
           "asked for " + FourCc(fourcc) + ", the device gave " + FourCc(fmt.fmt.pix.pixelformat));
  }
  if (!s.roi.Full() &&
      (int(fmt.fmt.pix.width) != s.roi.width || int(fmt.fmt.pix.height) != s.roi.height)) {
    d.Fail("settings.roi", "asked for " + std::to_string(s.roi.width) + "x" +
                               std::to_string(s.roi.height) + ", the device offers " +
                               std::to_string(fmt.fmt.pix.width) + "x" +
                               std::to_string(fmt.fmt.pix.height));
  }
  const int bpp = fourcc == V4L2_PIX_FMT_GREY ? 1 : 2;
  d.fourcc = fourcc;
  d.width = static_cast<int>(fmt.fmt.pix.width);
  d.height = static_cast<int>(fmt.fmt.pix.height);
  d.bytesperline = std::max<int>(static_cast<int>(fmt.fmt.pix.bytesperline), d.width * bpp);
  d.sizeimage =
      std::max<uint32_t>(fmt.fmt.pix.sizeimage, static_cast<uint32_t>(d.bytesperline * d.height));
  if (s.exposure_us) {
    if (!d.HasControl(V4L2_CID_EXPOSURE_ABSOLUTE))
      d.Fail("settings.exposure_us", "the device has no exposure control");
    if (d.HasControl(V4L2_CID_EXPOSURE_AUTO))
      d.SetControl(V4L2_CID_EXPOSURE_AUTO, V4L2_EXPOSURE_MANUAL, "exposure_auto");
    const long units = std::lround(*s.exposure_us / 100.0);  // V4L2 absolute exposure: 100 us units
    if (units < 1 || std::abs(units * 100.0 - *s.exposure_us) > 1e-6) {
      d.warnings.push_back(d.device + ": exposure " + std::to_string(*s.exposure_us) +
                           " us rounded to " + std::to_string(std::max<long>(units, 1) * 100) +
                           " us (V4L2 steps of 100 us)");
    }
    d.SetControl(V4L2_CID_EXPOSURE_ABSOLUTE, static_cast<int32_t>(std::max<long>(units, 1)),
                 "settings.exposure_us");
  }
  if (s.gain_db) {
    if (!d.HasControl(V4L2_CID_GAIN)) d.Fail("settings.gain_db", "the device has no gain control");
    // UVC gain has no unit: the value is passed as the device's own gain number.
    d.SetControl(V4L2_CID_GAIN, static_cast<int32_t>(std::lround(*s.gain_db)), "settings.gain_db");
    d.warnings.push_back(d.device + ": gain_db is sent as the UVC device's unitless gain value");
  }
  d.settings = s;
  d.settings.roi = Roi{0, 0, d.width, d.height};
  // Buffers.
  v4l2_requestbuffers req{};
  req.count = static_cast<uint32_t>(d.options.buffers);
  req.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  req.memory = V4L2_MEMORY_MMAP;
  if (Xioctl(d.fd, VIDIOC_REQBUFS, &req) != 0)
    d.Fail("VIDIOC_REQBUFS", "no mmap streaming (" + d.Errno() + ")");
  if (req.count < 2)
    d.Fail("VIDIOC_REQBUFS", "granted " + std::to_string(req.count) + " buffers, need at least 2");
  for (uint32_t i = 0; i < req.count; ++i) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    b.index = i;
    if (Xioctl(d.fd, VIDIOC_QUERYBUF, &b) != 0) d.Fail("VIDIOC_QUERYBUF", d.Errno());
    Impl::Buffer buf;
    buf.length = b.length;
    buf.data = mmap(nullptr, b.length, PROT_READ | PROT_WRITE, MAP_SHARED, d.fd, b.m.offset);
    if (buf.data == MAP_FAILED) d.Fail("mmap", "buffer " + std::to_string(i) + ": " + d.Errno());
    d.buffers.push_back(buf);
  }
}

CameraSettings V4l2Camera::Settings() const {
  CameraSettings s = impl_->settings;
  if (auto e = impl_->GetControl(V4L2_CID_EXPOSURE_ABSOLUTE)) s.exposure_us = *e * 100.0;
  if (auto g = impl_->GetControl(V4L2_CID_GAIN)) s.gain_db = *g;
  return s;
}

void V4l2Camera::Start() {
  Impl& d = *impl_;
  SLSHADOW_THROW_IF(d.buffers.empty(), d.device, ": Start before Configure");
  if (d.streaming) return;
  for (uint32_t i = 0; i < d.buffers.size(); ++i) d.Queue(i);
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  if (Xioctl(d.fd, VIDIOC_STREAMON, &type) != 0) d.Fail("VIDIOC_STREAMON", d.Errno());
  d.streaming = true;
  d.last_sequence = -1;
}

void V4l2Camera::Stop() {
  Impl& d = *impl_;
  if (!d.streaming) return;
  int type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
  Xioctl(d.fd, VIDIOC_STREAMOFF, &type);  // dequeues every buffer
  d.streaming = false;
}

void V4l2Camera::Trigger() {
  if (impl_->settings.trigger == TriggerMode::kSoftware) Flush();
}

void V4l2Camera::Flush() {
  Impl& d = *impl_;
  if (!d.streaming) return;
  // Drop the frames already delivered: at most one per buffer can be waiting.
  for (size_t i = 0; i < d.buffers.size(); ++i) {
    v4l2_buffer b{};
    b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
    b.memory = V4L2_MEMORY_MMAP;
    pollfd p{d.fd, POLLIN, 0};
    if (poll(&p, 1, 0) <= 0 || Xioctl(d.fd, VIDIOC_DQBUF, &b) != 0) return;
    d.Queue(b.index);
  }
}

Frame V4l2Camera::Grab(std::chrono::milliseconds timeout) {
  Impl& d = *impl_;
  Frame frame;
  if (!d.streaming) {
    frame.status = FrameStatus::kAborted;
    frame.message = d.device + ": not streaming";
    return frame;
  }
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  for (;;) {
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
        deadline - std::chrono::steady_clock::now());
    pollfd p{d.fd, POLLIN, 0};
    const int ready = poll(&p, 1, static_cast<int>(std::max<int64_t>(0, left.count())));
    if (ready < 0 && errno != EINTR) {
      frame.status = FrameStatus::kAborted;
      frame.message = d.device + ": poll failed (" + d.Errno() + ")";
      return frame;
    }
    if (ready > 0 && (p.revents & (POLLERR | POLLHUP | POLLNVAL))) {
      frame.status = FrameStatus::kAborted;
      frame.message = d.device + ": device error or unplugged while streaming";
      return frame;
    }
    if (ready > 0) {
      v4l2_buffer b{};
      b.type = V4L2_BUF_TYPE_VIDEO_CAPTURE;
      b.memory = V4L2_MEMORY_MMAP;
      if (Xioctl(d.fd, VIDIOC_DQBUF, &b) == 0) {
        frame.frame_id = b.sequence;
        frame.host_timestamp = std::chrono::system_clock::now();
        frame.device_timestamp_ns =
            uint64_t(b.timestamp.tv_sec) * 1000000000ull + uint64_t(b.timestamp.tv_usec) * 1000ull;
        frame.exposure_us = d.settings.exposure_us.value_or(0);
        if (d.last_sequence >= 0 && int64_t(b.sequence) > d.last_sequence + 1) {
          d.stats.missing_frames += b.sequence - uint64_t(d.last_sequence) - 1;
        }
        d.last_sequence = b.sequence;
        if (b.flags & V4L2_BUF_FLAG_ERROR) {
          frame.status = FrameStatus::kOtherError;
          frame.message =
              d.device + ": the driver flagged frame " + std::to_string(b.sequence) + " as damaged";
        } else if (b.bytesused < static_cast<uint32_t>(d.bytesperline) * uint32_t(d.height) ||
                   b.index >= d.buffers.size()) {
          frame.status = FrameStatus::kSizeMismatch;
          frame.message = d.device + ": frame of " + std::to_string(b.bytesused) +
                          " bytes, expected " + std::to_string(d.bytesperline * d.height);
        } else {
          frame.image = d.Convert(static_cast<const uint8_t*>(d.buffers[b.index].data));
          frame.status = FrameStatus::kOk;
        }
        (frame.ok() ? d.stats.completed_frames : d.stats.failed_frames)++;
        d.Queue(b.index);
        return frame;
      }
      if (errno != EAGAIN) {
        frame.status = errno == ENODEV ? FrameStatus::kAborted : FrameStatus::kOtherError;
        frame.message = d.device + ": VIDIOC_DQBUF failed (" + d.Errno() + ")";
        ++d.stats.failed_frames;
        return frame;
      }
      // Ready but nothing to dequeue (spurious wake-up): wait a little before polling again.
      std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    if (std::chrono::steady_clock::now() >= deadline) {
      ++d.stats.timeouts;
      frame.status = FrameStatus::kTimeout;
      frame.message = d.device + ": no frame within " + std::to_string(timeout.count()) + " ms";
      return frame;
    }
  }
}

StreamStatistics V4l2Camera::Statistics() const { return impl_->stats; }
std::vector<std::string> V4l2Camera::Warnings() const { return impl_->warnings; }

}  // namespace slshadow::capture
