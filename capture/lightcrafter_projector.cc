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
  SLSHADOW_THROW_IF(client_.GetDisplayMode() != dlpc350::DisplayMode::kVideo, transport_->Describe(),
                    ": display mode reads back as pattern sequence after setting video mode");
}

ProjectorInfo LightCrafterProjector::Info() const {
  ProjectorInfo info = output_->Info();
  info.backend = "lightcrafter";
  info.id = transport_->Describe() + ", video mode, firmware " + firmware_.ToString() + ", HDMI output " + info.id;
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
