#include "tests/capture/fake_gv_camera.h"

#include <unistd.h>

#include <arv.h>

#include <atomic>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <stdexcept>
#include <utility>
#include <vector>

namespace slshadow::testing {
namespace {

// Registers of Aravis's fake camera (arvfakecamera.h).
constexpr guint32 kTriggerSoftwareRegister = ARV_FAKE_CAMERA_REGISTER_TRIGGER_SOFTWARE;
constexpr guint32 kFramePeriodRegister = ARV_FAKE_CAMERA_REGISTER_ACQUISITION_FRAME_PERIOD_US;
constexpr guint32 kMono12 = 0x01100005;  // PFNC Mono12 (unpacked, 16 bits per pixel)

// Replaces the single occurrence of `from` in `text`; throws when it occurs 0 or 2+ times, so a
// changed built-in XML fails loudly instead of yielding a camera without the test's features.
void ReplaceOnce(std::string& text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  if (at == std::string::npos || text.find(from, at + 1) != std::string::npos) {
    throw std::runtime_error("FakeGvCamera: the built-in GenICam XML has not exactly one '" + from +
                             "'");
  }
  text.replace(at, from.size(), to);
}

// Aravis's built-in fake-camera XML with the SFNC names of real cameras and an emulated line.
std::string SfncXml() {
  ArvFakeCamera* source = arv_fake_camera_new("XMLSOURCE");
  size_t size = 0;
  const char* xml = arv_fake_camera_get_genicam_xml(source, &size);
  std::string text(xml, size);
  g_object_unref(source);

  ReplaceOnce(text, "<pFeature>ExposureTimeAbs</pFeature>", "<pFeature>ExposureTime</pFeature>");
  ReplaceOnce(text, "<Float Name=\"ExposureTimeAbs\"", "<Float Name=\"ExposureTime\"");
  ReplaceOnce(text, "<pFeature>GainRaw</pFeature>", "<pFeature>Gain</pFeature>");
  const size_t gain_begin = text.find("<Integer Name=\"GainRaw\"");
  const size_t gain_end = text.find("</Integer>", gain_begin);
  if (gain_begin == std::string::npos || gain_end == std::string::npos) {
    throw std::runtime_error("FakeGvCamera: the built-in GenICam XML has no GainRaw");
  }
  text.replace(gain_begin, gain_end + std::strlen("</Integer>") - gain_begin,
               "<Float Name=\"Gain\" NameSpace=\"Standard\">\n"
               "\t\t<Description>Gain, in dB.</Description>\n"
               "\t\t<pValue>GainConverter</pValue>\n"
               "\t\t<Min>0.0</Min>\n\t\t<Max>10.0</Max>\n\t</Float>\n\n"
               "\t<Converter Name=\"GainConverter\" NameSpace=\"Custom\">\n"
               "\t\t<FormulaTo>FROM</FormulaTo>\n\t\t<FormulaFrom>TO</FormulaFrom>\n"
               "\t\t<pValue>GainRawRegister</pValue>\n\t</Converter>");
  ReplaceOnce(text, "<pValue>PixelFormatRegister</pValue>",
              "<EnumEntry Name=\"Mono12\" NameSpace=\"Standard\">\n\t\t\t<Value>" +
                  std::to_string(kMono12) +
                  "</Value>\n\t\t</EnumEntry>\n\t\t<pValue>PixelFormatRegister</pValue>");
  // Line1 carries the software source's value: the camera then fires when the test writes its
  // trigger register (PulseLine), without any TriggerSoftware command from the client.
  ReplaceOnce(text, "<EnumEntry Name=\"Software\"",
              "<EnumEntry Name=\"Line1\" NameSpace=\"Standard\">\n\t\t\t<Value>1</Value>\n"
              "\t\t</EnumEntry>\n\t\t<EnumEntry Name=\"Software\"");
  return text;
}

capture::PixelFormat FormatOf(guint32 pixel_format) {
  if (pixel_format == kMono12) return capture::PixelFormat::kMono12;
  if (pixel_format == ARV_PIXEL_FORMAT_MONO_16) return capture::PixelFormat::kMono16;
  return capture::PixelFormat::kMono8;
}

}  // namespace

struct FakeGvCamera::Impl {
  FakeGvCameraOptions options;
  ArvGvFakeCamera* gv = nullptr;
  ArvFakeCamera* fake = nullptr;  // owned by gv
  mutable std::mutex mutex;
  FakeFill fill;
  std::deque<std::pair<uint64_t, cv::Mat>> served;
  std::vector<uint64_t> served_ids;
  std::atomic<uint64_t> n_served{0};
  // Latched line edges (PulseLine): time (ns since the epoch) and tag; `armed` while the trigger
  // register is set or the frame it fired is being filled.
  std::mutex line_mutex;
  std::deque<std::pair<uint64_t, int64_t>> edges;
  bool armed = false;

  static void Fill(ArvBuffer* buffer, void* data, guint32 exposure_us, guint32 gain,
                   ArvPixelFormat format) {
    auto* self = static_cast<Impl*>(data);
    FakeFrameRequest request;
    request.frame_id = arv_buffer_get_frame_id(buffer);
    request.width = arv_buffer_get_image_width(buffer);
    request.height = arv_buffer_get_image_height(buffer);
    request.format = FormatOf(format);
    request.exposure_us = exposure_us;
    request.gain_raw = gain;
    {
      std::lock_guard<std::mutex> lock(self->line_mutex);
      if (!self->edges.empty()) {
        arv_buffer_set_timestamp(buffer, self->edges.front().first);
        request.line_tag = self->edges.front().second;
        self->edges.pop_front();
        self->armed = !self->edges.empty();
        if (self->armed) arv_fake_camera_write_register(self->fake, kTriggerSoftwareRegister, 1);
      }
    }
    const int type = request.format == capture::PixelFormat::kMono8 ? CV_8UC1 : CV_16UC1;
    // The buffer was allocated by the fake camera with the payload of this region and format.
    auto* pixels = static_cast<uint8_t*>(const_cast<void*>(arv_buffer_get_data(buffer, nullptr)));
    cv::Mat target(request.height, request.width, type, pixels);
    std::lock_guard<std::mutex> lock(self->mutex);
    cv::Mat image;
    if (self->fill) image = self->fill(request);
    if (!image.empty() && image.rows == request.height && image.cols == request.width &&
        image.type() == type) {
      image.copyTo(target);
    } else {
      target.setTo(0);
    }
    if (self->options.keep_served > 0) {
      self->served.emplace_back(request.frame_id, target.clone());
      while (static_cast<int>(self->served.size()) > self->options.keep_served)
        self->served.pop_front();
    }
    self->served_ids.push_back(request.frame_id);
    self->n_served.fetch_add(1);
  }
};

FakeGvCamera::FakeGvCamera(const FakeGvCameraOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  std::string xml_path;
  if (options.sfnc_xml) {
    const auto dir = std::filesystem::temp_directory_path();
    xml_path =
        (dir / ("slshadow-fake-gv-" + std::to_string(getpid()) + "-" + options.serial + ".xml"))
            .string();
    std::ofstream(xml_path) << SfncXml();
  }
  impl_->gv = arv_gv_fake_camera_new_full(options.address.c_str(), options.serial.c_str(),
                                          xml_path.empty() ? nullptr : xml_path.c_str());
  if (!xml_path.empty()) std::filesystem::remove(xml_path);  // read by the constructor
  if (impl_->gv == nullptr || !arv_gv_fake_camera_is_running(impl_->gv)) {
    if (impl_->gv != nullptr) g_object_unref(impl_->gv);
    throw std::runtime_error("FakeGvCamera: cannot listen on " + options.address +
                             " (is it a local address, and free?)");
  }
  impl_->fake = arv_gv_fake_camera_get_fake_camera(impl_->gv);
  arv_fake_camera_set_trigger_frequency(impl_->fake, options.trigger_poll_hz);
  SetFrameRate(options.frame_rate_hz);
  arv_fake_camera_set_fill_pattern(impl_->fake, &Impl::Fill, impl_.get());
}

FakeGvCamera::~FakeGvCamera() { Destroy(); }

const std::string& FakeGvCamera::address() const { return impl_->options.address; }
const std::string& FakeGvCamera::serial() const { return impl_->options.serial; }

void FakeGvCamera::SetFill(FakeFill fill) {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  impl_->fill = std::move(fill);
}

void FakeGvCamera::SetLostPacketRatio(double ratio) {
  if (impl_->gv != nullptr) g_object_set(impl_->gv, "gvsp-lost-ratio", ratio, nullptr);
}

void FakeGvCamera::SeedLoss(uint32_t seed) { g_random_set_seed(seed); }

void FakeGvCamera::PulseLine(int64_t tag, std::chrono::system_clock::time_point edge) {
  if (impl_->fake == nullptr) return;
  if (edge.time_since_epoch().count() == 0) edge = std::chrono::system_clock::now();
  const auto ns =
      std::chrono::duration_cast<std::chrono::nanoseconds>(edge.time_since_epoch()).count();
  std::lock_guard<std::mutex> lock(impl_->line_mutex);
  impl_->edges.emplace_back(static_cast<uint64_t>(ns), tag);
  if (!impl_->armed) {
    impl_->armed = true;
    arv_fake_camera_write_register(impl_->fake, kTriggerSoftwareRegister, 1);
  }
}

void FakeGvCamera::SetFrameRate(double hz) {
  if (impl_->fake != nullptr && hz > 0) {
    arv_fake_camera_write_register(impl_->fake, kFramePeriodRegister,
                                   static_cast<guint32>(1e6 / hz));
  }
}

void FakeGvCamera::Destroy() {
  if (impl_->gv == nullptr) return;
  g_object_unref(impl_->gv);  // joins the camera's thread and closes its sockets
  impl_->gv = nullptr;
  impl_->fake = nullptr;
}

uint64_t FakeGvCamera::frames_served() const { return impl_->n_served.load(); }

std::vector<uint64_t> FakeGvCamera::served_ids() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->served_ids;
}

cv::Mat FakeGvCamera::ServedImage(uint64_t frame_id) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  for (auto it = impl_->served.rbegin(); it != impl_->served.rend(); ++it) {
    if (it->first == frame_id) return it->second.clone();
  }
  return {};
}

void RunInPrivateNetwork(int argc, char** argv) {
  if (std::getenv("SLSHADOW_NETNS") != nullptr) return;
  const char* probe = "unshare -n sh -c 'ip link set lo up' >/dev/null 2>&1";
  if (std::system(probe) != 0) {
    setenv("SLSHADOW_NETNS_SKIP",
           "private network namespace unavailable (`unshare -n` with `ip` failed: needs root or "
           "user namespaces and iproute2)",
           1);
    return;
  }
  std::error_code ec;
  const std::string self = std::filesystem::read_symlink("/proc/self/exe", ec).string();
  setenv("SLSHADOW_NETNS", "1", 1);
  std::vector<std::string> args = {
      "unshare",
      "-n",
      "--",
      "sh",
      "-c",
      "ip link set lo up && ip addr add 127.0.0.2/8 dev lo && ip addr add 127.0.0.3/8 dev lo && "
      "exec \"$0\" \"$@\"",
      ec ? std::string(argv[0]) : self};
  for (int i = 1; i < argc; ++i) args.emplace_back(argv[i]);
  std::vector<char*> c_args;
  for (auto& a : args) c_args.push_back(a.data());
  c_args.push_back(nullptr);
  execvp("unshare", c_args.data());
  unsetenv("SLSHADOW_NETNS");
  setenv("SLSHADOW_NETNS_SKIP", "private network namespace unavailable (cannot execute unshare)",
         1);
}

std::string SkipReasonWithoutPrivateNetwork() {
  if (std::getenv("SLSHADOW_NETNS") != nullptr) return "";
  const char* reason = std::getenv("SLSHADOW_NETNS_SKIP");
  return reason != nullptr ? reason : "not inside RunInPrivateNetwork()";
}

}  // namespace slshadow::testing
