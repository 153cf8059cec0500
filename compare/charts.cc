#include "compare/charts.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "plot/plot.h"

namespace slshadow::compare {
namespace {

// Palette after white and black: colour 2 threshold lines, colour 3 bar outlines.
std::unique_ptr<plstream> OpenChart(const std::filesystem::path& file, int width, int height) {
  auto pls = plot::OpenPng(file, width, height, {{200, 0, 0}, {90, 90, 90}});
  plot::SetHeatColorMap(*pls);
  return pls;
}

// An 8-bit RGB image (row-major, R G B) as a PNG, written atomically. OpenCV's default PNG
// settings: the "sub" filter, zlib level 1, run-length strategy (a few tens of milliseconds for a
// demo map, against ~0.2 s at cairo's default level; the file is ~15 % larger).
void WriteRgbPng(const std::filesystem::path& path, const uint8_t* rgb, int width, int height) {
  cv::Mat bgr(height, width, CV_8UC3);
  for (int y = 0; y < height; ++y) {
    const uint8_t* in = rgb + static_cast<size_t>(y) * static_cast<size_t>(width) * 3;
    auto* out = bgr.ptr<uint8_t>(y);
    for (int x = 0; x < width; ++x, in += 3, out += 3) {
      out[0] = in[2];
      out[1] = in[1];
      out[2] = in[0];
    }
  }
  const std::vector<uint8_t> bytes = EncodePng(bgr, path.string());
  WriteTextFileAtomically(path, std::string(bytes.begin(), bytes.end()));
}

}  // namespace

std::array<uint8_t, 3> DeviationColor(double t) { return plot::HeatColor(t); }

void WriteHistogramPng(const std::filesystem::path& path, const Histogram& h,
                       const HistogramChart& chart) {
  SLSHADOW_THROW_IF(h.counts.empty(), path.string(), ": histogram has no bins");
  const auto lock = plot::LockPlplot();
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    auto pls = OpenChart(tmp, chart.width_px, chart.height_px);
    const size_t peak = *std::max_element(h.counts.begin(), h.counts.end());
    const double ymax = std::max<double>(1.0, static_cast<double>(peak)) * 1.12;
    pls->schr(0, 1.1);
    pls->env(h.lo_mm, h.hi_mm, 0, ymax, 0, 0);
    pls->lab(chart.x_label.c_str(), "points per bin", chart.title.c_str());
    const double w = h.BinWidth();
    for (size_t i = 0; i < h.counts.size(); ++i) {
      if (h.counts[i] == 0) continue;
      const double x0 = h.lo_mm + w * static_cast<double>(i), x1 = x0 + w;
      const double xc = 0.5 * (x0 + x1);
      const double t = chart.is_signed ? (xc - h.lo_mm) / (h.hi_mm - h.lo_mm) : xc / h.hi_mm;
      PLFLT xs[4] = {x0, x0, x1, x1};
      PLFLT ys[4] = {0, static_cast<double>(h.counts[i]), static_cast<double>(h.counts[i]), 0};
      pls->col1(t);
      pls->fill(4, xs, ys);
      pls->col0(3);
      pls->line(4, xs, ys);
    }
    if (chart.threshold_mm > 0) {
      pls->col0(2);
      pls->lsty(2);
      for (double s : {-1.0, 1.0}) {
        if (!chart.is_signed && s < 0) continue;
        const double x = s * chart.threshold_mm;
        if (x < h.lo_mm || x > h.hi_mm) continue;
        PLFLT xs[2] = {x, x}, ys[2] = {0, ymax};
        pls->line(2, xs, ys);
      }
      pls->lsty(1);
    }
    pls->col0(1);
    pls->schr(0, 0.9);
    double y = 1.5;
    for (const auto& note : chart.notes) {
      pls->mtex("t", -y, 0.98, 1.0, note.c_str());
      y += 1.6;
    }
  });
}

void WriteDeviationMapPng(const std::filesystem::path& path, const ValueImage& image,
                          const MapChart& chart) {
  SLSHADOW_THROW_IF(image.width <= 0 || image.height <= 0 ||
                        image.values.size() !=
                            static_cast<size_t>(image.width) * static_cast<size_t>(image.height),
                    path.string(), ": bad deviation image size ", image.width, "x", image.height);
  SLSHADOW_THROW_IF(!(chart.hi > chart.lo), path.string(), ": empty colour range");
  SLSHADOW_THROW_IF(chart.max_width_px < 16 || chart.max_height_px < 16, path.string(),
                    ": map drawn smaller than 16 px");
  // Page: the image at its own aspect ratio plus room for the colour bar and labels.
  const int img_w = image.width, img_h = image.height;
  const double scale = std::min(1.0, std::min(static_cast<double>(chart.max_width_px) / img_w,
                                              static_cast<double>(chart.max_height_px) / img_h));
  // The map is drawn at map_w x map_h page pixels, one pixel per cell.
  const int map_w = std::max(1, static_cast<int>(img_w * scale)),
            map_h = std::max(1, static_cast<int>(img_h * scale));
  // Fixed pixel margins: left for the y ticks and label, right for the colour bar and its
  // labels, bottom for the x ticks and label, top for the title.
  constexpr int kLeft = 145, kRight = 250, kTop = 70;
  const int kBottom = 100 + 38 * static_cast<int>(chart.notes.size());
  const int page_w = map_w + kLeft + kRight;
  const int page_h = map_h + kBottom + kTop;

  // The map's pixels are written straight into the page (white where no point landed): each page
  // pixel is the mean of the finite values of its block of image pixels (the pixel itself at
  // scale 1), clamped to [lo, hi] and coloured by the heat map. PLplot then draws the axes, the
  // labels and the colour bar over it; PLplot is only held for that, and the PNG is encoded
  // after the lock is released, so reports written concurrently draw their maps in parallel.
  std::vector<double> sum(static_cast<size_t>(map_w) * static_cast<size_t>(map_h), 0.0);
  std::vector<int> count(sum.size(), 0);
  for (int y = 0; y < img_h; ++y) {
    const auto cy = static_cast<size_t>(
        std::min(map_h - 1, static_cast<int>(static_cast<int64_t>(y) * map_h / img_h)));
    const float* row = image.values.data() + static_cast<size_t>(y) * static_cast<size_t>(img_w);
    for (int x = 0; x < img_w; ++x) {
      const float v = row[x];
      if (!std::isfinite(v)) continue;
      const auto cx = static_cast<size_t>(
          std::min(map_w - 1, static_cast<int>(static_cast<int64_t>(x) * map_w / img_w)));
      sum[cy * static_cast<size_t>(map_w) + cx] += v;
      ++count[cy * static_cast<size_t>(map_w) + cx];
    }
  }
  std::vector<uint8_t> rgb(static_cast<size_t>(page_w) * static_cast<size_t>(page_h) * 3, 255);
  const double range = chart.hi - chart.lo;
  for (int cy = 0; cy < map_h; ++cy) {
    uint8_t* out = rgb.data() + (static_cast<size_t>(kTop + cy) * static_cast<size_t>(page_w) +
                                 static_cast<size_t>(kLeft)) *
                                    3;
    for (int cx = 0; cx < map_w; ++cx, out += 3) {
      const size_t k =
          static_cast<size_t>(cy) * static_cast<size_t>(map_w) + static_cast<size_t>(cx);
      if (count[k] == 0) continue;
      const double mean = std::clamp(sum[k] / count[k], chart.lo, chart.hi);
      const std::array<uint8_t, 3> c = plot::HeatColor((mean - chart.lo) / range);
      out[0] = c[0];
      out[1] = c[1];
      out[2] = c[2];
    }
  }
  {
    const auto lock = plot::LockPlplot();
    auto pls = plot::OpenRgbMemory(rgb.data(), page_w, page_h, {{200, 0, 0}, {90, 90, 90}});
    plot::SetHeatColorMap(*pls);
    pls->adv(0);
    // Viewport in normalised page coordinates: exactly the map's pixels.
    const double vx0 = static_cast<double>(kLeft) / page_w,
                 vx1 = static_cast<double>(kLeft + map_w) / page_w;
    const double vy0 = static_cast<double>(kBottom) / page_h,
                 vy1 = static_cast<double>(kBottom + map_h) / page_h;
    pls->vpor(vx0, vx1, vy0, vy1);
    pls->wind(-0.5, img_w - 0.5, img_h - 0.5, -0.5);
    pls->col0(1);
    pls->box("bcnst", 0, 0, "bcnstv", 0, 0);
    pls->lab(chart.x_label.c_str(), chart.y_label.c_str(), chart.title.c_str());
    plot::HeatColorBar(*pls, chart.lo, chart.hi, chart.colorbar_label, 25.0 / page_w, 35.0 / page_w,
                       chart.marks);
    for (size_t i = 0; i < chart.notes.size(); ++i) {
      pls->mtex("b", 5.0 + 1.4 * static_cast<double>(i), 0.0, 0.0, chart.notes[i].c_str());
    }
  }  // the stream's end copies the drawing into rgb
  WriteRgbPng(path, rgb.data(), page_w, page_h);
}

}  // namespace slshadow::compare
