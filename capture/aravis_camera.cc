#include "capture/aravis_camera.h"

#include <arpa/inet.h>
#include <dirent.h>
#include <netinet/in.h>
#include <sys/socket.h>

#include <arv.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <fstream>

#include "core/error.h"

namespace slshadow::capture {

void AravisOpenOptions::Check() const {
  SLSHADOW_THROW_IF(device.empty(),
                    "aravis: device: an IPv4 address, serial or device id is needed");
  SLSHADOW_THROW_IF(n_buffers < 2 || n_buffers > 256, "aravis ", device,
                    ": n_buffers: must be in 2..256 (got ", n_buffers, ")");
}

bool IsIpv4Address(const std::string& text) {
  in_addr address{};
  return inet_pton(AF_INET, text.c_str(), &address) == 1;
}

uint64_t FrameIdsSkipped(uint64_t before, uint64_t after) {
  if (before == 0 || after == 0) return 0;
  if (before > 0xFFFF || after > 0xFFFF) return after > before ? after - before - 1 : 0;
  // Positions 0..65534 on the ring of valid 16-bit ids 1..65535.
  const uint64_t step = (after - 1 + 65535 - (before - 1)) % 65535;
  return step == 0 ? 0 : step - 1;
}

namespace {

constexpr uint32_t kGvcpVersionRegister = 0x0000;  // GigE Vision bootstrap "Version"

// Takes the message out of a GError and frees it.
std::string TakeMessage(GError*& error) {
  std::string message = error != nullptr ? error->message : "unknown error";
  g_clear_error(&error);
  return message;
}

std::string Str(const char* text) { return text != nullptr ? text : ""; }

// Owns the string array Aravis's dup_* functions return (the strings themselves are not owned).
std::vector<std::string> TakeStrings(const char** strings, guint n) {
  std::vector<std::string> out;
  for (guint i = 0; i < n && strings != nullptr; ++i) out.push_back(Str(strings[i]));
  g_free(strings);
  return out;
}

std::string Join(const std::vector<std::string>& items) {
  std::string out;
  for (const auto& s : items) out += (out.empty() ? "" : ", ") + s;
  return out;
}

long ReadRmemMax() {
  std::ifstream in("/proc/sys/net/core/rmem_max");
  long value = 0;
  in >> value;
  return value;
}

// The receive buffer of this process's UDP socket bound to `port`, as the kernel granted it
// (getsockopt reports twice the usable size on Linux), or 0 when no such socket is found.
int GrantedReceiveBuffer(uint16_t port) {
  DIR* dir = opendir("/proc/self/fd");
  if (dir == nullptr) return 0;
  int granted = 0;
  while (dirent* entry = readdir(dir)) {
    char* end = nullptr;
    const long fd = std::strtol(entry->d_name, &end, 10);
    if (end == entry->d_name || *end != '\0') continue;
    sockaddr_in address{};
    socklen_t length = sizeof(address);
    if (getsockname(static_cast<int>(fd), reinterpret_cast<sockaddr*>(&address), &length) != 0 ||
        address.sin_family != AF_INET || ntohs(address.sin_port) != port) {
      continue;
    }
    int type = 0;
    socklen_t type_length = sizeof(type);
    if (getsockopt(static_cast<int>(fd), SOL_SOCKET, SO_TYPE, &type, &type_length) != 0 ||
        type != SOCK_DGRAM) {
      continue;
    }
    int size = 0;
    socklen_t size_length = sizeof(size);
    if (getsockopt(static_cast<int>(fd), SOL_SOCKET, SO_RCVBUF, &size, &size_length) == 0) {
      granted = size / 2;
      break;
    }
  }
  closedir(dir);
  return granted;
}

std::string StatusName(ArvBufferStatus status) {
  switch (status) {
    case ARV_BUFFER_STATUS_SUCCESS:
      return "success";
    case ARV_BUFFER_STATUS_CLEARED:
      return "cleared";
    case ARV_BUFFER_STATUS_TIMEOUT:
      return "timeout";
    case ARV_BUFFER_STATUS_MISSING_PACKETS:
      return "missing packets";
    case ARV_BUFFER_STATUS_WRONG_PACKET_ID:
      return "wrong packet id";
    case ARV_BUFFER_STATUS_SIZE_MISMATCH:
      return "size mismatch";
    case ARV_BUFFER_STATUS_FILLING:
      return "filling";
    case ARV_BUFFER_STATUS_ABORTED:
      return "aborted";
    default:
      return "unknown";
  }
}

class AravisCamera final : public Camera {
 public:
  AravisCamera(ArvCamera* camera, std::string opened_by, int n_buffers)
      : camera_(camera), device_(arv_camera_get_device(camera)), n_buffers_(n_buffers) {
    is_gv_ = arv_camera_is_gv_device(camera_);
    GError* error = nullptr;
    info_.backend = "aravis";
    info_.id = std::move(opened_by);
    info_.vendor = Str(arv_camera_get_vendor_name(camera_, &error));
    g_clear_error(&error);
    info_.model = Str(arv_camera_get_model_name(camera_, &error));
    g_clear_error(&error);
    info_.serial = Str(arv_camera_get_device_serial_number(camera_, &error));
    g_clear_error(&error);
    arv_camera_get_sensor_size(camera_, &info_.sensor_width, &info_.sensor_height, &error);
    g_clear_error(&error);
    guint n = 0;
    const char** formats = arv_camera_dup_available_pixel_formats_as_strings(camera_, &n, &error);
    const auto offered = TakeStrings(formats, n);
    g_clear_error(&error);
    for (PixelFormat f : {PixelFormat::kMono8, PixelFormat::kMono12, PixelFormat::kMono16}) {
      if (std::find(offered.begin(), offered.end(), ToString(f)) != offered.end()) {
        info_.pixel_formats.push_back(f);
      }
    }
    offered_formats_ = offered;
    exposure_feature_ = FirstAvailable({"ExposureTime", "ExposureTimeAbs"});
    gain_feature_ = FirstAvailable({"Gain", "GainAbs", "GainRaw"});
    control_lost_handler_ =
        g_signal_connect(device_, "control-lost", G_CALLBACK(&AravisCamera::OnControlLost), this);
  }

  ~AravisCamera() override {
    if (running_) Stop();
    if (control_lost_handler_ != 0) g_signal_handler_disconnect(device_, control_lost_handler_);
    g_clear_object(&camera_);
  }

  CameraInfo Info() const override { return info_; }

  void Configure(const CameraSettings& settings) override {
    const std::string& who = Who();
    settings.Check(who);
    SLSHADOW_THROW_IF(running_, who, ": Configure: call Stop() first");
    configured_ = false;  // until every setting is applied
    GError* error = nullptr;

    // Pixel format.
    const std::string format = ToString(settings.pixel_format);
    SLSHADOW_THROW_IF(std::find(offered_formats_.begin(), offered_formats_.end(), format) ==
                          offered_formats_.end(),
                      who, ": pixel_format: ", format, " is not offered (the device offers ",
                      Join(offered_formats_), ")");
    arv_camera_set_pixel_format_from_string(camera_, format.c_str(), &error);
    ThrowOn(error, "pixel_format", format);

    // Region of interest.
    Roi roi = settings.roi;
    if (roi.Full()) roi = Roi{0, 0, info_.sensor_width, info_.sensor_height};
    SLSHADOW_THROW_IF(
        roi.x + roi.width > info_.sensor_width || roi.y + roi.height > info_.sensor_height, who,
        ": roi: ", roi.x, ",", roi.y, ",", roi.width, ",", roi.height, " exceeds the sensor (",
        info_.sensor_width, "x", info_.sensor_height, ")");
    arv_camera_set_region(camera_, roi.x, roi.y, roi.width, roi.height, &error);
    ThrowOn(error, "roi", roi.width, "x", roi.height, "+", roi.x, "+", roi.y);
    int x = 0, y = 0, w = 0, h = 0;
    arv_camera_get_region(camera_, &x, &y, &w, &h, &error);
    ThrowOn(error, "roi", "read back");
    SLSHADOW_THROW_IF(x != roi.x || y != roi.y || w != roi.width || h != roi.height, who,
                      ": roi: the device adjusted ", roi.width, "x", roi.height, "+", roi.x, "+",
                      roi.y, " to ", w, "x", h, "+", x, "+", y,
                      " (sizes and offsets must respect its increments)");

    // Exposure (µs).
    if (settings.exposure_us) {
      SLSHADOW_THROW_IF(exposure_feature_.empty(), who,
                        ": exposure_us: the device has neither ExposureTime nor ExposureTimeAbs");
      SwitchOff("ExposureAuto");  // an automatic exposure would override the value
      SetFloatChecked(exposure_feature_, *settings.exposure_us, "exposure_us");
    }
    // Gain (dB).
    if (settings.gain_db) {
      SLSHADOW_THROW_IF(gain_feature_.empty(), who,
                        ": gain_db: the device has none of Gain, GainAbs, GainRaw");
      SwitchOff("GainAuto");
      if (gain_feature_ == "GainRaw") {
        const double raw = std::round(*settings.gain_db);
        SetIntegerChecked("GainRaw", static_cast<int64_t>(raw), "gain_db");
        AddWarning(who + ": gain_db " + std::to_string(*settings.gain_db) +
                   " written to GainRaw as " + std::to_string(static_cast<int64_t>(raw)) +
                   " device units (the device has no Gain in dB)");
      } else {
        SetFloatChecked(gain_feature_, *settings.gain_db, "gain_db");
      }
    }

    // Trigger.
    arv_camera_set_acquisition_mode(camera_, ARV_ACQUISITION_MODE_CONTINUOUS, &error);
    ThrowOn(error, "trigger", "AcquisitionMode Continuous");
    arv_camera_clear_triggers(camera_, &error);
    ThrowOn(error, "trigger", "TriggerMode Off");
    if (settings.trigger != TriggerMode::kFreeRun) {
      const std::string source = settings.trigger == TriggerMode::kSoftware
                                     ? std::string("Software")
                                     : settings.trigger_line;
      if (IsAvailable("TriggerSelector")) {
        arv_camera_set_string(camera_, "TriggerSelector", "FrameStart", &error);
        ThrowOn(error, "trigger", "TriggerSelector FrameStart");
      }
      guint n = 0;
      const char** names =
          arv_camera_dup_available_enumerations_as_strings(camera_, "TriggerSource", &n, &error);
      const auto sources = TakeStrings(names, n);
      ThrowOn(error, "trigger", "TriggerSource");
      SLSHADOW_THROW_IF(
          std::find(sources.begin(), sources.end(), source) == sources.end(), who,
          settings.trigger == TriggerMode::kSoftware ? ": trigger: " : ": trigger_line: ", source,
          " is not a trigger source of the device (it offers ", Join(sources), ")");
      arv_camera_set_string(camera_, "TriggerMode", "On", &error);
      ThrowOn(error, "trigger", "TriggerMode On");
      arv_camera_set_string(camera_, "TriggerSource", source.c_str(), &error);
      ThrowOn(error, "trigger", source);
      if (IsAvailable("TriggerActivation") &&
          arv_camera_is_enumeration_entry_available(camera_, "TriggerActivation", "RisingEdge",
                                                    &error)) {
        arv_camera_set_string(camera_, "TriggerActivation", "RisingEdge", &error);
      }
      g_clear_error(&error);
    }

    // Transport (GigE Vision only; the stream options are applied by Start()).
    if (is_gv_) {
      if (settings.packet_size_bytes > 0) {
        arv_camera_gv_set_packet_size_adjustment(camera_, ARV_GV_PACKET_SIZE_ADJUSTMENT_NEVER);
        arv_camera_gv_set_packet_size(camera_, settings.packet_size_bytes, &error);
        ThrowOn(error, "packet_size_bytes", settings.packet_size_bytes);
        const guint granted = arv_camera_gv_get_packet_size(camera_, &error);
        ThrowOn(error, "packet_size_bytes", "read back");
        SLSHADOW_THROW_IF(granted != static_cast<guint>(settings.packet_size_bytes), who,
                          ": packet_size_bytes: the device took ", granted, " instead of ",
                          settings.packet_size_bytes);
      }
    } else if (settings.packet_size_bytes > 0 || settings.socket_buffer_bytes > 0) {
      AddWarning(who +
                 ": packet_size_bytes / socket_buffer_bytes apply to GigE Vision only; ignored");
    }
    settings_ = settings;
    configured_ = true;
  }

  CameraSettings Settings() const override {
    CameraSettings out = settings_;
    GError* error = nullptr;
    if (!exposure_feature_.empty()) {
      const double v = arv_camera_get_float(camera_, exposure_feature_.c_str(), &error);
      if (error == nullptr) out.exposure_us = v;
      g_clear_error(&error);
    }
    if (!gain_feature_.empty()) {
      const double v = gain_feature_ == "GainRaw"
                           ? static_cast<double>(arv_camera_get_integer(camera_, "GainRaw", &error))
                           : arv_camera_get_float(camera_, gain_feature_.c_str(), &error);
      if (error == nullptr) out.gain_db = v;
      g_clear_error(&error);
    }
    const char* format = arv_camera_get_pixel_format_as_string(camera_, &error);
    if (error == nullptr && format != nullptr) {
      for (PixelFormat f : {PixelFormat::kMono8, PixelFormat::kMono12, PixelFormat::kMono16}) {
        if (ToString(f) == format) out.pixel_format = f;
      }
    }
    g_clear_error(&error);
    arv_camera_get_region(camera_, &out.roi.x, &out.roi.y, &out.roi.width, &out.roi.height, &error);
    g_clear_error(&error);
    // Trigger: the mode is read back; the source is the one configured (two enumeration entries
    // may share a register value, so the device's name for it can be ambiguous).
    const std::string mode = Str(arv_camera_get_string(camera_, "TriggerMode", &error));
    g_clear_error(&error);
    if (mode == "Off") out.trigger = TriggerMode::kFreeRun;
    if (is_gv_) {
      out.packet_size_bytes = static_cast<int>(arv_camera_gv_get_packet_size(camera_, &error));
      g_clear_error(&error);
      out.socket_buffer_bytes = granted_socket_buffer_;  // 0 until the first frame arrived
    }
    return out;
  }

  void Start() override {
    const std::string& who = Who();
    SLSHADOW_THROW_IF(!configured_, who, ": Start: call Configure() first");
    if (running_) return;
    GError* error = nullptr;
    payload_ = arv_camera_get_payload(camera_, &error);
    ThrowOn(error, "start", "PayloadSize");
    arv_camera_get_region(camera_, nullptr, nullptr, &width_, &height_, &error);
    ThrowOn(error, "start", "region");
    pixel_format_ = arv_camera_get_pixel_format(camera_, &error);
    ThrowOn(error, "start", "PixelFormat");
    const int bytes_per_pixel = settings_.pixel_format == PixelFormat::kMono8 ? 1 : 2;
    SLSHADOW_THROW_IF(payload_ != static_cast<size_t>(width_) * height_ * bytes_per_pixel, who,
                      ": pixel_format: payload of ", payload_, " bytes for ", width_, "x", height_,
                      " ", ToString(settings_.pixel_format),
                      " (a packed or padded format is not supported)");
    if (exposure_feature_.empty()) {
      exposure_us_ = 0;
    } else {
      exposure_us_ = arv_camera_get_float(camera_, exposure_feature_.c_str(), &error);
      g_clear_error(&error);
    }

    stream_ = arv_camera_create_stream(camera_, nullptr, nullptr, &error);
    ThrowOn(error, "start", "stream");
    if (is_gv_) {
      const bool fixed = settings_.socket_buffer_bytes > 0;
      g_object_set(stream_, "packet-resend",
                   settings_.packet_resend ? ARV_GV_STREAM_PACKET_RESEND_ALWAYS
                                           : ARV_GV_STREAM_PACKET_RESEND_NEVER,
                   "socket-buffer",
                   fixed ? ARV_GV_STREAM_SOCKET_BUFFER_FIXED : ARV_GV_STREAM_SOCKET_BUFFER_AUTO,
                   "socket-buffer-size", fixed ? settings_.socket_buffer_bytes : 0, nullptr);
      requested_socket_buffer_ = fixed ? settings_.socket_buffer_bytes : static_cast<int>(payload_);
    }
    for (int i = 0; i < n_buffers_; ++i)
      arv_stream_push_buffer(stream_, arv_buffer_new_allocate(payload_));
    arv_camera_start_acquisition(camera_, &error);
    if (error != nullptr) {
      g_clear_object(&stream_);
      ThrowOn(error, "start", "AcquisitionStart");
    }
    last_ok_id_ = 0;
    failed_since_ok_ = 0;
    vanished_frames_ = 0;
    granted_socket_buffer_ = 0;
    stopped_statistics_ = {};
    running_ = true;
  }

  void Stop() override {
    if (!running_) return;
    running_ = false;
    GError* error = nullptr;
    if (!device_lost_) {
      arv_camera_stop_acquisition(camera_, &error);
      if (error != nullptr) AddWarning(Who() + ": AcquisitionStop failed: " + TakeMessage(error));
    }
    // Keep the counters of the stream that ends.
    stopped_statistics_ = ReadStatistics();
    g_clear_object(&stream_);
  }

  void Trigger() override {
    if (!running_ || device_lost_ || settings_.trigger != TriggerMode::kSoftware) return;
    GError* error = nullptr;
    arv_camera_software_trigger(camera_, &error);
    if (error != nullptr) {
      trigger_timed_out_ = g_error_matches(error, ARV_DEVICE_ERROR, ARV_DEVICE_ERROR_TIMEOUT);
      trigger_error_ = TakeMessage(error);
    }
  }

  Frame Grab(std::chrono::milliseconds timeout) override {
    Frame frame;
    if (!running_) return Failed(FrameStatus::kAborted, Who() + ": not started");
    if (device_lost_) return Failed(FrameStatus::kAborted, lost_message_);
    ArvBuffer* buffer =
        arv_stream_timeout_pop_buffer(stream_, static_cast<guint64>(timeout.count()) * 1000);
    if (buffer == nullptr) return NoFrame(timeout);
    frame = Convert(buffer);
    arv_stream_push_buffer(stream_, buffer);
    if (granted_socket_buffer_ == 0 && is_gv_) CheckSocketBuffer();
    return frame;
  }

  void Flush() override {
    if (!running_ || stream_ == nullptr) return;
    while (ArvBuffer* buffer = arv_stream_try_pop_buffer(stream_)) {
      Convert(buffer);  // accounts the frame id
      arv_stream_push_buffer(stream_, buffer);
    }
  }

  StreamStatistics Statistics() const override {
    return running_ ? ReadStatistics() : stopped_statistics_;
  }

  std::vector<std::string> Warnings() const override { return warnings_; }

 private:
  static void OnControlLost(ArvDevice* /*device*/, gpointer self) {
    static_cast<AravisCamera*>(self)->control_lost_.store(true);
  }

  const std::string& Who() const { return info_.id; }

  void AddWarning(std::string warning) {
    if (warnings_.size() < 100) warnings_.push_back(std::move(warning));
  }

  template <typename... Args>
  void ThrowOn(GError*& error, const std::string& field, const Args&... value) {
    if (error == nullptr) return;
    const std::string message = TakeMessage(error);
    SLSHADOW_THROW(Who(), ": ", field, ": the device refused ", value..., " (", message, ")");
  }

  bool IsAvailable(const char* feature) const {
    GError* error = nullptr;
    const bool available = arv_camera_is_feature_available(camera_, feature, &error);
    g_clear_error(&error);
    return available;
  }

  std::string FirstAvailable(std::initializer_list<const char*> names) const {
    for (const char* name : names) {
      if (IsAvailable(name)) return name;
    }
    return "";
  }

  // Sets an automatic-mode enumeration (ExposureAuto, GainAuto) to Off when the device has it.
  void SwitchOff(const char* feature) {
    if (!IsAvailable(feature)) return;
    GError* error = nullptr;
    if (arv_camera_is_enumeration_entry_available(camera_, feature, "Off", &error)) {
      arv_camera_set_string(camera_, feature, "Off", &error);
    }
    ThrowOn(error, feature, "Off");
  }

  void SetFloatChecked(const std::string& feature, double value, const char* field) {
    GError* error = nullptr;
    double lo = 0, hi = 0;
    arv_camera_get_float_bounds(camera_, feature.c_str(), &lo, &hi, &error);
    ThrowOn(error, field, feature, " bounds");
    SLSHADOW_THROW_IF(value < lo || value > hi, Who(), ": ", field, ": ", value,
                      " is outside the device's range [", lo, ", ", hi, "] (", feature, ")");
    arv_camera_set_float(camera_, feature.c_str(), value, &error);
    ThrowOn(error, field, value, " (", feature, ")");
  }

  void SetIntegerChecked(const std::string& feature, int64_t value, const char* field) {
    GError* error = nullptr;
    gint64 lo = 0, hi = 0;
    arv_camera_get_integer_bounds(camera_, feature.c_str(), &lo, &hi, &error);
    ThrowOn(error, field, feature, " bounds");
    SLSHADOW_THROW_IF(value < lo || value > hi, Who(), ": ", field, ": ", value,
                      " is outside the device's range [", lo, ", ", hi, "] (", feature, ")");
    arv_camera_set_integer(camera_, feature.c_str(), value, &error);
    ThrowOn(error, field, value, " (", feature, ")");
  }

  static Frame Failed(FrameStatus status, std::string message) {
    Frame frame;
    frame.status = status;
    frame.message = std::move(message);
    frame.host_timestamp = std::chrono::system_clock::now();
    return frame;
  }

  // Nothing arrived: a timeout, unless the device stopped answering (then every later Grab is
  // kAborted at once).
  Frame NoFrame(std::chrono::milliseconds timeout) {
    std::string why;
    if (control_lost_.load()) {
      why = "the device reports that this host lost control of it";
    } else if (trigger_timed_out_) {  // every GVCP retry of the trigger went unanswered
      why = "it did not acknowledge the software trigger (" + trigger_error_ + ")";
    } else if (is_gv_) {
      GError* error = nullptr;
      guint32 value = 0;
      if (!arv_device_read_register(device_, kGvcpVersionRegister, &value, &error)) {
        why = "it no longer answers GVCP (" + TakeMessage(error) + ")";
      }
      g_clear_error(&error);
    }
    if (!why.empty()) {
      device_lost_ = true;
      lost_message_ = Who() + " (serial " + info_.serial + ") lost: " + why;
      return Failed(FrameStatus::kAborted, lost_message_);
    }
    std::string message = Who() + ": no frame within " + std::to_string(timeout.count()) + " ms (" +
                          ToString(settings_.trigger) + " trigger)";
    if (!trigger_error_.empty()) {
      message += "; the last software trigger failed: " + trigger_error_;
      trigger_error_.clear();
    }
    return Failed(FrameStatus::kTimeout, message);
  }

  Frame Convert(ArvBuffer* buffer) {
    Frame frame;
    frame.host_timestamp = std::chrono::system_clock::time_point(
        std::chrono::duration_cast<std::chrono::system_clock::duration>(
            std::chrono::nanoseconds(arv_buffer_get_system_timestamp(buffer))));
    if (arv_buffer_get_system_timestamp(buffer) == 0)
      frame.host_timestamp = std::chrono::system_clock::now();
    frame.exposure_us = exposure_us_;
    const ArvBufferStatus status = arv_buffer_get_status(buffer);
    if (status != ARV_BUFFER_STATUS_SUCCESS) {
      // The leader may be lost, so the buffer's id may be stale: a damaged frame has id 0.
      ++failed_since_ok_;
      switch (status) {
        case ARV_BUFFER_STATUS_MISSING_PACKETS:
          frame.status = FrameStatus::kMissingPackets;
          break;
        // Aravis's TIMEOUT is a frame that arrived but stayed incomplete until its retention
        // expired (missing packets not resent): kTimeout is reserved for "nothing arrived".
        case ARV_BUFFER_STATUS_TIMEOUT:
          frame.status = FrameStatus::kMissingPackets;
          break;
        case ARV_BUFFER_STATUS_SIZE_MISMATCH:
          frame.status = FrameStatus::kSizeMismatch;
          break;
        case ARV_BUFFER_STATUS_ABORTED:
          frame.status = FrameStatus::kAborted;
          break;
        default:
          frame.status = FrameStatus::kOtherError;
          break;
      }
      frame.message = Who() + ": damaged frame (Aravis buffer status: " + StatusName(status) + ")";
      if (status == ARV_BUFFER_STATUS_TIMEOUT) {
        frame.message += ": packets missing when the frame retention expired";
      }
      return frame;
    }
    size_t size = 0;
    const void* data = arv_buffer_get_image_data(buffer, &size);
    const int w = arv_buffer_get_image_width(buffer);
    const int h = arv_buffer_get_image_height(buffer);
    const ArvPixelFormat format = arv_buffer_get_image_pixel_format(buffer);
    if (data == nullptr || size != payload_ || w != width_ || h != height_ ||
        format != pixel_format_) {
      ++failed_since_ok_;
      frame.status = FrameStatus::kSizeMismatch;
      frame.message = Who() + ": frame of " + std::to_string(size) + " bytes, " +
                      std::to_string(w) + "x" + std::to_string(h) + ", pixel format 0x" +
                      Hex(format) + "; expected " + std::to_string(payload_) + " bytes, " +
                      std::to_string(width_) + "x" + std::to_string(height_) + ", 0x" +
                      Hex(pixel_format_);
      return frame;
    }
    frame.frame_id = arv_buffer_get_frame_id(buffer);
    frame.device_timestamp_ns = arv_buffer_get_timestamp(buffer);
    frame.image.create(h, w, settings_.pixel_format == PixelFormat::kMono8 ? CV_8UC1 : CV_16UC1);
    std::memcpy(frame.image.data, data, payload_);
    frame.status = FrameStatus::kOk;
    AccountOk(frame.frame_id);
    return frame;
  }

  static std::string Hex(uint32_t value) {
    char text[16];
    std::snprintf(text, sizeof(text), "%08x", value);
    return text;
  }

  // Frame ids that never arrived as a buffer (neither complete nor damaged) between two complete
  // frames are frames lost whole (dropped leader and trailer, or a buffer underrun).
  void AccountOk(uint64_t id) {
    if (last_ok_id_ != 0) {
      const uint64_t skipped = FrameIdsSkipped(last_ok_id_, id);
      const uint64_t vanished = skipped > failed_since_ok_ ? skipped - failed_since_ok_ : 0;
      if (vanished > 0) {
        vanished_frames_ += vanished;
        AddWarning(Who() + ": " + std::to_string(vanished) + " frame(s) between ids " +
                   std::to_string(last_ok_id_) + " and " + std::to_string(id) + " never arrived");
      }
    }
    last_ok_id_ = id;
    failed_since_ok_ = 0;
  }

  void CheckSocketBuffer() {
    if (stream_ == nullptr || !ARV_IS_GV_STREAM(stream_)) return;
    granted_socket_buffer_ = GrantedReceiveBuffer(arv_gv_stream_get_port(ARV_GV_STREAM(stream_)));
    if (granted_socket_buffer_ == 0) {
      granted_socket_buffer_ = -1;  // not found: do not look again
      AddWarning(Who() + ": socket_buffer_bytes: could not read back the stream socket's buffer");
      return;
    }
    if (granted_socket_buffer_ < requested_socket_buffer_) {
      AddWarning(Who() + ": socket_buffer_bytes: asked for " +
                 std::to_string(requested_socket_buffer_) + " bytes, the kernel granted " +
                 std::to_string(granted_socket_buffer_) + " (net.core.rmem_max = " +
                 std::to_string(ReadRmemMax()) + "; raise it with: sysctl -w net.core.rmem_max=" +
                 std::to_string(requested_socket_buffer_) + ")");
    }
  }

  StreamStatistics ReadStatistics() const {
    StreamStatistics s;
    if (stream_ == nullptr) return stopped_statistics_;
    auto info = [&](const char* name) { return arv_stream_get_info_uint64_by_name(stream_, name); };
    s.completed_frames = info("n_completed_buffers");
    s.failed_frames = info("n_failures");
    s.underruns = info("n_underruns");
    s.missing_frames = vanished_frames_;
    if (is_gv_) {
      s.missing_packets = info("n_missing_packets");
      s.resend_requests = info("n_resend_requests");
      s.timeouts = info("n_timeouts");
    }
    return s;
  }

  ArvCamera* camera_ = nullptr;
  ArvDevice* device_ = nullptr;  // owned by camera_
  ArvStream* stream_ = nullptr;
  int n_buffers_ = 8;
  bool is_gv_ = false;
  CameraInfo info_;
  std::vector<std::string> offered_formats_;
  std::string exposure_feature_, gain_feature_;
  CameraSettings settings_;
  bool configured_ = false;
  bool running_ = false;
  size_t payload_ = 0;
  int width_ = 0, height_ = 0;
  ArvPixelFormat pixel_format_ = 0;
  double exposure_us_ = 0;
  int requested_socket_buffer_ = 0;
  int granted_socket_buffer_ = 0;
  uint64_t last_ok_id_ = 0;
  uint64_t failed_since_ok_ = 0;
  uint64_t vanished_frames_ = 0;
  std::atomic<bool> control_lost_{false};
  gulong control_lost_handler_ = 0;
  bool device_lost_ = false;
  std::string lost_message_;
  std::string trigger_error_;
  bool trigger_timed_out_ = false;
  StreamStatistics stopped_statistics_;
  std::vector<std::string> warnings_;
};

}  // namespace

std::unique_ptr<Camera> OpenAravisCamera(const AravisOpenOptions& options) {
  options.Check();
  GError* error = nullptr;
  ArvDevice* device = nullptr;
  std::string why;
  if (IsIpv4Address(options.device)) {
    // Direct GVCP to the address: no discovery broadcast.
    device =
        arv_interface_open_device(arv_gv_interface_get_instance(), options.device.c_str(), &error);
    if (device == nullptr)
      why = error != nullptr ? TakeMessage(error) : "no GigE Vision device answered";
  } else {
    // A serial number or device id is matched against the listed devices here, then opened by
    // the listing's own id (USB3 Vision) or address (GigE Vision): Aravis would otherwise try the
    // name as a host name (a DNS query) before broadcasting.
    auto find = [&](ArvInterface* iface, bool by_address) -> std::string {
      arv_interface_update_device_list(iface);
      for (unsigned i = 0; i < arv_interface_get_n_devices(iface); ++i) {
        if (options.device == Str(arv_interface_get_device_id(iface, i)) ||
            options.device == Str(arv_interface_get_device_serial_nbr(iface, i))) {
          return Str(by_address ? arv_interface_get_device_address(iface, i)
                                : arv_interface_get_device_id(iface, i));
        }
      }
      return "";
    };
    ArvInterface* usb = arv_uv_interface_get_instance();
    std::string key = find(usb, false);
    ArvInterface* iface = usb;
    if (key.empty() && options.allow_discovery) {
      iface = arv_gv_interface_get_instance();
      key = find(iface, true);
    }
    if (!key.empty()) {
      device = arv_interface_open_device(iface, key.c_str(), &error);
      if (device == nullptr) why = error != nullptr ? TakeMessage(error) : "it did not answer";
      g_clear_error(&error);
    } else {
      why =
          options.allow_discovery
              ? "no USB3 Vision or GigE Vision device has this id or serial"
              : "no USB3 Vision device has this id or serial; a GigE Vision camera is opened by "
                "its IP address (or allow discovery, which broadcasts on every network interface)";
    }
  }
  SLSHADOW_THROW_IF(device == nullptr, "aravis: device '", options.device, "': cannot open: ", why);
  ArvCamera* camera = arv_camera_new_with_device(device, &error);
  g_object_unref(device);  // the camera holds its own reference
  SLSHADOW_THROW_IF(camera == nullptr, "aravis: device '", options.device,
                    "': not usable as a camera: ", TakeMessage(error));
  return std::make_unique<AravisCamera>(camera, options.device, options.n_buffers);
}

std::vector<AravisDeviceEntry> ListAravisDevices(bool gige_discovery) {
  std::vector<AravisDeviceEntry> out;
  std::vector<ArvInterface*> interfaces = {arv_uv_interface_get_instance()};
  if (gige_discovery) interfaces.push_back(arv_gv_interface_get_instance());
  for (ArvInterface* iface : interfaces) {
    arv_interface_update_device_list(iface);
    const unsigned n = arv_interface_get_n_devices(iface);
    for (unsigned i = 0; i < n; ++i) {
      AravisDeviceEntry e;
      e.id = Str(arv_interface_get_device_id(iface, i));
      e.protocol = Str(arv_interface_get_device_protocol(iface, i));
      e.vendor = Str(arv_interface_get_device_vendor(iface, i));
      e.model = Str(arv_interface_get_device_model(iface, i));
      e.serial = Str(arv_interface_get_device_serial_nbr(iface, i));
      e.address = Str(arv_interface_get_device_address(iface, i));
      out.push_back(std::move(e));
    }
  }
  return out;
}

}  // namespace slshadow::capture
