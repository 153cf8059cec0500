// PNG charts drawn with PLplot (cairo driver): the deviation histogram and the deviation map.
// Both use one colour map, CloudCompare's default look: blue (most negative or zero) - cyan -
// green - yellow - red (largest), so the PLY colours, the map and the histogram bars agree.
// Files are written atomically (temporary sibling, then rename).
#pragma once

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

#include "compare/statistics.h"

namespace slshadow::compare {

// t in [0, 1] (clamped) -> RGB.
std::array<uint8_t, 3> DeviationColor(double t);

struct HistogramChart {
  std::string title;
  std::string x_label = "deviation (mm)";
  bool is_signed = false;
  double threshold_mm = 0.0;       // drawn as dashed lines at +-threshold (0: none)
  std::vector<std::string> notes;  // short lines printed in the top-right corner
  int width_px = 1000, height_px = 650;
};
void WriteHistogramPng(const std::filesystem::path& path, const Histogram& histogram,
                       const HistogramChart& chart);

// A rendered value image: row-major, row 0 at the top; NaN where no point landed.
struct ValueImage {
  int width = 0, height = 0;
  std::vector<float> values;
};

struct MapChart {
  std::string title;
  std::string colorbar_label = "deviation (mm)";
  double lo = -1.0, hi = 1.0;  // colour range; values outside are drawn in the end colours
  std::vector<double> marks;   // values marked on the colour bar (e.g. +-threshold) where in range
  std::vector<std::string>
      notes;  // short lines under the colour bar's label (e.g. what the range is)
  std::string x_label = "image x (px)", y_label = "image y (px)";
  int max_width_px = 1100,
      max_height_px = 800;  // the image is drawn at most this large (block means)
};
void WriteDeviationMapPng(const std::filesystem::path& path, const ValueImage& image,
                          const MapChart& chart);

}  // namespace slshadow::compare
