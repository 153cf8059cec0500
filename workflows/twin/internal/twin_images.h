// The per-camera image comparisons of `slshadow shadow` (workflows/twin/twin.cc's stage 5): the
// real and the twin's pattern images frame by frame, and their decoded projector coordinates
// against the twin's truth and each other. Used by workflows/twin/twin.cc.
#pragma once

#include <cstdint>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/projector_map.h"
#include "patterns/pattern_spec.h"
#include "sim/geometry_pass.h"

namespace slshadow::twin::internal {

// The twin's lit part pixels of one camera (visible, lit, on an object) as a CV_8UC1 mask (255).
cv::Mat LitPartMask(const GeometryBuffer& g);

// Per pattern intensity differences, real - twin, over `mask`: the report's "patterns" entries
// (index, name, mean_dn, rms_dn, within_5pct), the pixel-frames within 5 % of full scale (`fs_dn`)
// in all frames, and the worst frame's share within.
struct FrameAgreement {
  std::vector<nlohmann::json> per;
  int64_t in_all = 0;
  double worst = 1;
};
FrameAgreement CompareFrames(const PatternSpec& spec, const std::vector<FrameInfo>& frames,
                             const std::vector<cv::Mat>& rimg, const std::vector<cv::Mat>& timg,
                             const cv::Mat& mask, const GeometryBuffer& g, double fs_dn);

// Decoded projector coordinates, real (`rm`) and twin (`tm`) against the twin's truth (`gt`) and
// each other over `mask` (`lit` pixels): the report's "projector_coordinates" (docs/formats.md,
// "Shadow report"), the residual map (CV_32FC1, the coded axis, x when there is one; NaN where
// not compared) and the validity image (CV_8UC3: both, real only, twin only).
nlohmann::json CompareProjectorCoordinates(const PatternSpec& spec, const ProjectorMap& rm,
                                           const ProjectorMap& tm, const ProjectorMap& gt,
                                           const cv::Mat& mask, int64_t lit,
                                           const GeometryBuffer& g, cv::Mat* residual_map,
                                           cv::Mat* validity_map);

}  // namespace slshadow::twin::internal
