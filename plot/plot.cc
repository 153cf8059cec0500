#include "plot/plot.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace slshadow::plot {
namespace {

// Colour map control points: position, r, g, b.
constexpr double kStops[5][4] = {{0.00, 0, 0, 255},
                                 {0.25, 0, 255, 255},
                                 {0.50, 0, 255, 0},
                                 {0.75, 255, 255, 0},
                                 {1.00, 255, 0, 0}};

}  // namespace

std::array<uint8_t, 3> HeatColor(double t) {
  t = std::isnan(t) ? 0.5 : std::clamp(t, 0.0, 1.0);  // +-inf clamp to the ends, as documented
  int i = 0;
  while (i < 3 && t > kStops[i + 1][0]) ++i;
  const double f = (t - kStops[i][0]) / (kStops[i + 1][0] - kStops[i][0]);
  std::array<uint8_t, 3> c{};
  for (int k = 0; k < 3; ++k) {
    // std::lround without the library call: v is in [0, 255], its integer part t is exact and
    // so is v - t (Sterbenz), so this rounds half away from zero exactly as lround does.
    const double v = kStops[i][k + 1] + f * (kStops[i + 1][k + 1] - kStops[i][k + 1]);
    int t = static_cast<int>(v);
    if (v - t >= 0.5) ++t;
    c[static_cast<size_t>(k)] = static_cast<uint8_t>(t);
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

void HeatColorBar(plstream& pls, double lo, double hi, const std::string& label, double offset,
                  double width, const std::vector<double>& marks) {
  if (marks.empty()) {  // PLplot's own colour bar (its label placed to fit)
    constexpr int kValues = 64;
    std::vector<PLFLT> values(kValues);
    for (int i = 0; i < kValues; ++i)
      values[static_cast<size_t>(i)] = lo + (hi - lo) * i / (kValues - 1);
    const PLFLT* value_ptrs[1] = {values.data()};
    PLINT n_vals[1] = {kValues};
    const char* axis_opts[1] = {"bcvtm"};
    PLFLT ticks[1] = {0.0};
    PLINT sub_ticks[1] = {0};
    PLINT label_opts[1] = {PL_COLORBAR_LABEL_RIGHT};
    const char* labels[1] = {label.c_str()};
    PLFLT bar_w = 0, bar_h = 0;
    pls.colorbar(&bar_w, &bar_h, PL_COLORBAR_GRADIENT, PL_POSITION_RIGHT | PL_POSITION_OUTSIDE,
                 offset, 0.0, width, 0.9, 0, 1, 1, 0.0, 0.0, 0, 0.0, 1, label_opts, labels, 1,
                 axis_opts, ticks, sub_ticks, n_vals, value_ptrs);
    return;
  }
  // With marks, drawn by hand (an image column, a box with the values on its right): plcolorbar's
  // placement moves with its labels, and the marks must land on their values.
  PLFLT x0 = 0, x1 = 0, y0 = 0, y1 = 0, wx0 = 0, wx1 = 0, wy0 = 0, wy1 = 0;
  pls.gvpd(x0, x1, y0, y1);
  pls.gvpw(wx0, wx1, wy0, wy1);
  const double vh = y1 - y0;
  pls.vpor(x1 + offset, x1 + offset + width, y0 + 0.05 * vh, y1 - 0.05 * vh);
  pls.wind(0, 1, lo, hi);
  constexpr int kSteps = 256;
  std::vector<PLFLT> column(kSteps);
  for (int i = 0; i < kSteps; ++i)
    column[static_cast<size_t>(i)] = lo + (hi - lo) * (i + 0.5) / kSteps;
  const PLFLT* columns[2] = {column.data(),
                             column.data()};  // two columns: PLplot needs a cell edge
  pls.imagefr(columns, 2, kSteps, 0, 1, lo, hi, lo, hi, lo, hi, nullptr, nullptr);
  pls.col0(1);
  pls.box("bc", 0, 0, "bcmstv", 0, 0);
  pls.mtex("r", 5.2, 0.5, 0.5, label.c_str());
  pls.width(3);
  for (double m : marks) {
    if (!(m > lo && m < hi)) continue;
    const PLFLT xs[2] = {0, 1}, ys[2] = {m, m};
    pls.line(2, xs, ys);
  }
  pls.width(1);
  pls.vpor(x0, x1, y0, y1);
  pls.wind(wx0, wx1, wy0, wy1);
}

std::unique_lock<std::mutex> LockPlplot() {
  static std::mutex m;
  return std::unique_lock<std::mutex>(m);
}

namespace {

std::unique_ptr<plstream> Open(const char* device, const std::filesystem::path& file, int width,
                               int height, std::initializer_list<std::array<int, 3>> palette,
                               uint8_t* memory = nullptr) {
  auto pls = std::make_unique<plstream>();
  pls->sdev(device);
  if (memory != nullptr)
    pls->smem(width, height, memory);
  else
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

std::unique_ptr<plstream> OpenRgbMemory(uint8_t* rgb, int width, int height,
                                        std::initializer_list<std::array<int, 3>> palette) {
  return Open("memcairo", {}, width, height, palette, rgb);
}

std::unique_ptr<plstream> OpenSvg(const std::filesystem::path& file, int width, int height,
                                  std::initializer_list<std::array<int, 3>> palette) {
  return Open("svgcairo", file, width, height, palette);
}

}  // namespace slshadow::plot
