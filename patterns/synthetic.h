// Synthetic camera images of projected patterns without the simulator: each camera pixel looks up
// the projector at a known coordinate (map_x, map_y), e.g. from a homography, a plane seen by a
// known rig, or an analytic disparity. Used as the ground-truth fixture of decoding tests and
// benchmarks; the full physical simulator lives in sim/.
//
// Model, per camera pixel p and projector image I (8-bit levels v):
//   v' = 255 (v / 255)^gamma                  projector response
//   s  = bilinear sample of v' at (map_x(p), map_y(p)) in projector pixels (OpenCV centres);
//        0 where the coordinate lies outside [-0.5, W - 0.5] x [-0.5, H - 0.5] or is NaN
//   c  = offset(p) + gain(p) s                camera level, 8-bit scale
//   c  = GaussianBlur(c, blur_sigma_px) (border replicated: pixels within 3 sigma of the image
//        edge are not physical), then + N(0, noise_sigma^2)
//   out = round(clamp(c, 0, 255)) for 8-bit, round(clamp(257 c, 0, 65535)) for 16-bit.
#pragma once

#include <cstdint>
#include <vector>

#include <opencv2/core.hpp>

#include "patterns/pattern_spec.h"

namespace slshadow {

struct CameraSimOptions {
  double offset = 8;         // ambient + dark level, 8-bit grey levels (offset_map overrides)
  double gain = 0.8;         // camera levels per projector level (gain_map overrides)
  double gamma = 1.0;        // projector response exponent, > 0
  double blur_sigma_px = 0;  // Gaussian blur of the camera image, camera pixels (0: none)
  double noise_sigma = 0;    // additive Gaussian noise, 8-bit grey levels
  int bit_depth = 8;         // 8 or 16
  uint64_t seed = 1;         // noise seed; images are deterministic for a seed
  cv::Mat gain_map;          // optional CV_32FC1 per camera pixel
  cv::Mat offset_map;        // optional CV_32FC1 per camera pixel
  void Check() const;        // throws slshadow::Error
};

// Renders one camera image per projector image. map_x / map_y: CV_32FC1 or CV_64FC1, the camera's
// size, projector coordinates seen by each camera pixel (NaN: nothing). Rows run in parallel.
std::vector<cv::Mat> SimulateCameraImages(const std::vector<cv::Mat>& projector_images,
                                          const cv::Mat& map_x, const cv::Mat& map_y,
                                          const CameraSimOptions& options = {});

// A standard test view for benchmarks and examples: a camera of width x height looking at the
// projector image under a 10 degree rotation and mild perspective, the projector's middle 80%
// filling the camera's width. Returns the camera images of GeneratePatterns(spec) and, if asked,
// the maps.
std::vector<cv::Mat> SimulateStandardView(const PatternSpec& spec, int width, int height,
                                          const CameraSimOptions& options = {},
                                          cv::Mat* map_x = nullptr, cv::Mat* map_y = nullptr);

// The maps of a homography: (map_x, map_y) = H * (u, v, 1) dehomogenised, for a camera of
// width x height (CV_64FC1).
void HomographyMaps(const cv::Matx33d& proj_from_cam, int width, int height, cv::Mat* map_x,
                    cv::Mat* map_y);

}  // namespace slshadow
