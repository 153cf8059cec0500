#include "compare/charts.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>

#include "core/error.h"
#include "core/file_util.h"
#include "plot/plot.h"

namespace slshadow::compare {
namespace {

// Palette after white and black: colour 2 threshold lines, colour 3 bar outlines.
std::unique_ptr<plstream> OpenChart(const std::filesystem::path& file, int width, int height) {
  auto pls = plot::OpenPng(file, width, height, {{200, 0, 0}, {90, 90, 90}});
  plot::SetHeatColorMap(*pls);
  return pls;
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
  const auto lock = plot::LockPlplot();
  // Page: the image at its own aspect ratio plus room for the colour bar and labels.
  const int img_w = image.width, img_h = image.height;
  const double scale = std::min(1.0, std::min(static_cast<double>(chart.max_width_px) / img_w,
                                              static_cast<double>(chart.max_height_px) / img_h));
  // Fixed pixel margins: left for the y ticks and label, right for the colour bar and its
  // labels, bottom for the x ticks and label, top for the title.
  constexpr int kLeft = 145, kRight = 250, kTop = 70;
  const int kBottom = 100 + 38 * static_cast<int>(chart.notes.size());
  const int page_w = static_cast<int>(img_w * scale) + kLeft + kRight;
  const int page_h = static_cast<int>(img_h * scale) + kBottom + kTop;
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    auto pls = OpenChart(tmp, page_w, page_h);
    pls->adv(0);
    // Viewport in normalised page coordinates leaving space right for the colour bar.
    const double vx0 = static_cast<double>(kLeft) / page_w, vx1 = vx0 + img_w * scale / page_w;
    const double vy0 = static_cast<double>(kBottom) / page_h, vy1 = vy0 + img_h * scale / page_h;
    pls->vpor(vx0, vx1, vy0, vy1);
    pls->wind(-0.5, img_w - 0.5, img_h - 0.5, -0.5);
    // PLplot draws every data cell as a filled polygon: give it the cells at the size they are
    // drawn (each the mean of the finite values of its block of image pixels), not more.
    // data[x][y] with y going up in PLplot: flip rows. Empty cells are given a value below
    // the range; plimagefr skips values outside [valuemin, valuemax] (white background).
    const int cell_w = std::max(1, static_cast<int>(std::ceil(img_w * scale))),
              cell_h = std::max(1, static_cast<int>(std::ceil(img_h * scale)));
    std::vector<std::vector<PLFLT>> cols(static_cast<size_t>(cell_w),
                                         std::vector<PLFLT>(static_cast<size_t>(cell_h), 0.0));
    std::vector<std::vector<int>> counts(static_cast<size_t>(cell_w),
                                         std::vector<int>(static_cast<size_t>(cell_h), 0));
    for (int y = 0; y < img_h; ++y) {
      const auto cy = static_cast<size_t>(
          std::min(cell_h - 1, static_cast<int>(static_cast<int64_t>(y) * cell_h / img_h)));
      for (int x = 0; x < img_w; ++x) {
        const float v = image.values[static_cast<size_t>(y) * static_cast<size_t>(img_w) +
                                     static_cast<size_t>(x)];
        if (!std::isfinite(v)) continue;
        const auto cx = static_cast<size_t>(
            std::min(cell_w - 1, static_cast<int>(static_cast<int64_t>(x) * cell_w / img_w)));
        cols[cx][cy] += v;
        ++counts[cx][cy];
      }
    }
    std::vector<const PLFLT*> ptrs(static_cast<size_t>(cell_w));
    const double below = chart.lo - 10.0 * (chart.hi - chart.lo);
    for (size_t x = 0; x < cols.size(); ++x) {
      for (size_t y = 0; y < cols[x].size(); ++y) {
        cols[x][y] = counts[x][y] > 0
                         ? std::clamp<double>(cols[x][y] / counts[x][y], chart.lo, chart.hi)
                         : below;
      }
      ptrs[x] = cols[x].data();
    }
    pls->imagefr(ptrs.data(), cell_w, cell_h, -0.5, img_w - 0.5, img_h - 0.5, -0.5, chart.lo,
                 chart.hi, chart.lo, chart.hi, nullptr, nullptr);
    pls->col0(1);
    pls->box("bcnst", 0, 0, "bcnstv", 0, 0);
    pls->lab(chart.x_label.c_str(), chart.y_label.c_str(), chart.title.c_str());
    plot::HeatColorBar(*pls, chart.lo, chart.hi, chart.colorbar_label, 25.0 / page_w, 35.0 / page_w,
                       chart.marks);
    for (size_t i = 0; i < chart.notes.size(); ++i) {
      pls->mtex("b", 5.0 + 1.4 * static_cast<double>(i), 0.0, 0.0, chart.notes[i].c_str());
    }
  });
}

}  // namespace slshadow::compare
