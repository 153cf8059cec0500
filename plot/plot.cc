#include "plot/plot.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace slshadow::plot {
namespace {

// Colour map control points: position, r, g, b.
constexpr double kStops[5][4] = {
    {0.00, 0, 0, 255}, {0.25, 0, 255, 255}, {0.50, 0, 255, 0}, {0.75, 255, 255, 0}, {1.00, 255, 0, 0}};

}  // namespace

std::array<uint8_t, 3> HeatColor(double t) {
  t = std::isfinite(t) ? std::clamp(t, 0.0, 1.0) : 0.5;
  int i = 0;
  while (i < 3 && t > kStops[i + 1][0]) ++i;
  const double f = (t - kStops[i][0]) / (kStops[i + 1][0] - kStops[i][0]);
  std::array<uint8_t, 3> c{};
  for (int k = 0; k < 3; ++k) {
    c[static_cast<size_t>(k)] =
        static_cast<uint8_t>(std::lround(kStops[i][k + 1] + f * (kStops[i + 1][k + 1] - kStops[i][k + 1])));
  }
  return c;
}

void SetHeatColorMap(plstream& pls) {
  PLFLT pos[5], r[5], g[5], b[5];
  for (int i = 0; i < 5; ++i) {
    pos[i] = kStops[i][0];
    r[i] = kStops[i][1] / 255.0;
    g[i] = kStops[i][2] / 255.0;
    b[i] = kStops[i][3] / 255.0;
  }
  pls.scmap1n(256);
  pls.scmap1l(true, 5, pos, r, g, b);
}

void HeatColorBar(plstream& pls, double lo, double hi, const std::string& label, double offset, double width) {
  constexpr int kValues = 64;
  std::vector<PLFLT> values(kValues);
  for (int i = 0; i < kValues; ++i) values[static_cast<size_t>(i)] = lo + (hi - lo) * i / (kValues - 1);
  const PLFLT* value_ptrs[1] = {values.data()};
  PLINT n_vals[1] = {kValues};
  const char* axis_opts[1] = {"bcvtm"};
  PLFLT ticks[1] = {0.0};
  PLINT sub_ticks[1] = {0};
  PLINT label_opts[1] = {PL_COLORBAR_LABEL_RIGHT};
  const char* labels[1] = {label.c_str()};
  PLFLT bar_w = 0, bar_h = 0;
  pls.colorbar(&bar_w, &bar_h, PL_COLORBAR_GRADIENT, PL_POSITION_RIGHT | PL_POSITION_OUTSIDE, offset, 0.0, width, 0.9, 0, 1, 1,
               0.0, 0.0, 0, 0.0, 1, label_opts, labels, 1, axis_opts, ticks, sub_ticks, n_vals, value_ptrs);
}

std::unique_lock<std::mutex> LockPlplot() {
  static std::mutex m;
  return std::unique_lock<std::mutex>(m);
}

namespace {

std::unique_ptr<plstream> Open(const char* device, const std::filesystem::path& file, int width,
                               int height, std::initializer_list<std::array<int, 3>> palette) {
  auto pls = std::make_unique<plstream>();
  pls->sdev(device);
  pls->sfnam(file.c_str());
  pls->spage(0, 0, width, height, 0, 0);
  pls->scol0(0, 255, 255, 255);
  pls->scol0(1, 0, 0, 0);
  int index = 2;
  for (const auto& rgb : palette) pls->scol0(index++, rgb[0], rgb[1], rgb[2]);
  pls->init();
  pls->col0(1);
  return pls;
}

}  // namespace

std::unique_ptr<plstream> OpenPng(const std::filesystem::path& file, int width, int height,
                                  std::initializer_list<std::array<int, 3>> palette) {
  return Open("pngcairo", file, width, height, palette);
}

std::unique_ptr<plstream> OpenSvg(const std::filesystem::path& file, int width, int height,
                                  std::initializer_list<std::array<int, 3>> palette) {
  return Open("svgcairo", file, width, height, palette);
}

}  // namespace slshadow::plot
