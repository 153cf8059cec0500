#pragma once
// PNG (and SVG) charts through PLplot, shared by the report writers of calib/ and compare/.
//
// PLplot keeps process-wide state (stream table, current stream), so a chart must hold
// LockPlplot() for as long as its stream lives; reports may then be written from several threads.

#include <array>
#include <cstdint>
#include <filesystem>
#include <initializer_list>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <plstream.h>

namespace slshadow::plot {

// The heat colour map used by every deviation and residual chart, and by the colours stored in
// report PLYs: blue (t = 0), cyan, green, yellow, red (t = 1), linear in between. t is clamped to
// [0, 1]; NaN gives the middle (green).
std::array<uint8_t, 3> HeatColor(double t);

// Loads the same heat map into PLplot's colour map 1 (256 entries), for shade plots and colour
// bars.
void SetHeatColorMap(plstream& pls);

// A vertical colour bar of the heat map right of the current viewport: values lo..hi, `label`
// on its right; `offset` from the viewport and `width` in normalised page units.
// `marks` (e.g. a threshold) are drawn as black lines across the bar where they fall in range
// (then the bar is drawn by hand, its label 5 characters right of it: leave room).
void HeatColorBar(plstream& pls, double lo, double hi, const std::string& label, double offset,
                  double width, const std::vector<double>& marks = {});

// Serialises PLplot use across threads.
[[nodiscard]] std::unique_lock<std::mutex> LockPlplot();

// A stream writing a width x height px PNG (pngcairo) to `file`: colour 0 is the white
// background, colour 1 black (axes, text), and `palette` becomes colours 2, 3, ... in order.
// The stream is initialised and drawing in colour 1.
std::unique_ptr<plstream> OpenPng(const std::filesystem::path& file, int width, int height,
                                  std::initializer_list<std::array<int, 3>> palette);

// A stream drawing (memcairo) onto `rgb`, a caller-owned width x height x 3 byte buffer (row-major,
// row 0 at the top, R G B), over what the buffer already holds: nothing is cleared, so an image
// filled in beforehand stays under the axes and text drawn on it. The buffer holds the drawing
// once the stream is destroyed. Colours as OpenPng.
std::unique_ptr<plstream> OpenRgbMemory(uint8_t* rgb, int width, int height,
                                        std::initializer_list<std::array<int, 3>> palette);

// The same as an SVG (svgcairo) of width x height points: vector output of the same drawing.
std::unique_ptr<plstream> OpenSvg(const std::filesystem::path& file, int width, int height,
                                  std::initializer_list<std::array<int, 3>> palette);

}  // namespace slshadow::plot
