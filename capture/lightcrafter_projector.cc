#include "capture/lightcrafter_projector.h"

#include "capture/lightcrafter_usb.h"
#include "core/error.h"

namespace slshadow::capture {

LightCrafterProjector::LightCrafterProjector(std::unique_ptr<dlpc350::Transport> transport,
                                             std::unique_ptr<Projector> hdmi_output)
    : transport_(std::move(transport)), output_(std::move(hdmi_output)), client_(*transport_) {
  SLSHADOW_CHECK(output_ != nullptr);
  firmware_ = client_.GetVersion();
  client_.SetSequence(dlpc350::SequenceControl::kStop);
  client_.SetDisplayMode(dlpc350::DisplayMode::kVideo);
  SLSHADOW_THROW_IF(client_.GetDisplayMode() != dlpc350::DisplayMode::kVideo,
                    transport_->Describe(),
                    ": display mode reads back as pattern sequence after setting video mode");
}

ProjectorInfo LightCrafterProjector::Info() const {
  ProjectorInfo info = output_->Info();
  info.backend = "lightcrafter";
  info.id = transport_->Describe() + ", video mode, firmware " + firmware_.ToString() +
            ", HDMI output " + info.id;
  return info;
}

std::unique_ptr<Projector> OpenLightCrafterProjector(const ProjectorEntry& entry,
                                                     std::unique_ptr<Projector> hdmi_output) {
  try {
    return std::make_unique<LightCrafterProjector>(OpenLightCrafterUsb(""), std::move(hdmi_output));
  } catch (const Error& e) {
    SLSHADOW_THROW(entry.where, ": ", e.what());
  }
}

}  // namespace slshadow::capture

namespace slshadow::capture {

void LightCrafterSequenceOptions::Check(const std::string& where) const {
  SLSHADOW_THROW_IF(frame_period_us == 0, where, ".frame_period_us: must be > 0");
  SLSHADOW_THROW_IF(exposure_us != 0 && exposure_us != frame_period_us &&
                        uint64_t(exposure_us) + 230 > frame_period_us,
                    where, ".exposure_us: ", exposure_us, " must equal frame_period_us ",
                    frame_period_us, " or be at most frame_period_us - 230 (DLPC350)");
  SLSHADOW_THROW_IF(bit_depth < 0 || bit_depth > 8, where,
                    ".bit_depth: must be 1..8, or 0 for automatic (got ", bit_depth, ")");
}

LightCrafterSequenceProjector::LightCrafterSequenceProjector(
    std::unique_ptr<dlpc350::Transport> transport, LightCrafterSequenceOptions options)
    : transport_(std::move(transport)), options_(options), client_(*transport_) {
  options_.Check(transport_->Describe());
  firmware_ = client_.GetVersion();
  client_.SetSequence(dlpc350::SequenceControl::kStop);
}

ProjectorInfo LightCrafterSequenceProjector::Info() const {
  ProjectorInfo info;
  info.backend = "lightcrafter";
  info.id = transport_->Describe() + ", pattern-sequence mode, firmware " + firmware_.ToString();
  info.width = width_;
  info.height = height_;
  info.refresh_hz = 1e6 / options_.frame_period_us;
  return info;
}

void LightCrafterSequenceProjector::Load(const std::vector<cv::Mat>& images) {
  SLSHADOW_THROW_IF(images.empty(), transport_->Describe(), ": no images to load");
  bool binary = true;
  for (size_t i = 0; i < images.size(); ++i) {
    const cv::Mat& m = images[i];
    SLSHADOW_THROW_IF(m.type() != CV_8UC1 || m.size() != images[0].size(), transport_->Describe(),
                      ": image ", i, " is not 8-bit grey of the first image's size");
    binary = binary && cv::countNonZero((m != 0) & (m != 255)) == 0;
  }
  bit_depth_ = options_.bit_depth > 0 ? options_.bit_depth : binary ? 1 : 8;
  dlpc350::PatternSequence sequence = dlpc350::SequenceFor(
      static_cast<int>(images.size()), bit_depth_, dlpc350::EntryTrigger::kInternal,
      options_.exposure_us == 0 ? options_.frame_period_us : options_.exposure_us,
      options_.frame_period_us);
  sequence.repeat = false;
  client_.SetSequence(dlpc350::SequenceControl::kStop);
  client_.SetTrigOut1(options_.trig_out1);
  validation_ = client_.Program(sequence);
  width_ = images[0].cols;
  height_ = images[0].rows;
}

std::chrono::system_clock::time_point LightCrafterSequenceProjector::Start() {
  const auto before = std::chrono::system_clock::now();  // the device may start before it acks
  client_.SetSequence(dlpc350::SequenceControl::kStart);
  return before;
}

void LightCrafterSequenceProjector::Stop() { client_.SetSequence(dlpc350::SequenceControl::kStop); }

void LightCrafterSequenceProjector::CheckAlive() {
  SLSHADOW_THROW_IF(
      client_.GetDisplayMode() != dlpc350::DisplayMode::kPatternSequence, transport_->Describe(),
      ": the display mode reads back as video: the device left pattern-sequence mode");
}

std::unique_ptr<SequenceProjector> OpenLightCrafterSequenceProjector(const ProjectorEntry& entry) {
  try {
    LightCrafterSequenceOptions options;
    options.frame_period_us = static_cast<uint32_t>(entry.frame_period_us);
    options.exposure_us = static_cast<uint32_t>(entry.exposure_us);
    options.bit_depth = entry.bit_depth;
    options.trig_out1.invert = entry.trigger_inverted;
    return std::make_unique<LightCrafterSequenceProjector>(OpenLightCrafterUsb(entry.usb), options);
  } catch (const Error& e) {
    SLSHADOW_THROW(entry.where, ": ", e.what());
  }
}

}  // namespace slshadow::capture
