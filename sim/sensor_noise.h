// The last step of the pattern pass (sim/renderer.h): the sensor-noise layer and the ADC of a
// camera (sim/scene.h SceneLayers, EMVA 1288 style) applied to a noise-free irradiance image.
// One definition, used by PatternRenderer and by the sweep's reuse of noise-free images
// (workflows/studies/sweep_reuse.h), so both give the same image bit for bit.
//
// The noise generator (docs/formats.md, layer `noise`): pixels in blocks of 16 by index
// i = y * width + x. Per block b, lane l (0..7): SplitMix64(the image's stream, a hash of seed,
// camera and pattern, + 8 b + l) gives two 24-bit uniforms, Box-Muller two independent standard
// normals: the cosine one for pixel 16 b + l, the sine one for pixel 16 b + 8 + l. Shot and read
// noise, independent Gaussians, enter as one: sqrt(mu_e + read^2) n. Log, sine and cosine as
// polynomials (Cephes' single-precision ones), the signal in float. Deterministic for a seed
// whatever the thread count or the CPU (the same IEEE operations in every code path, no FMA).
// The generator's history: docs/benchmarks/log/2026-12-07-header-notes.md.
#pragma once

#include <cstdint>

#include <opencv2/core.hpp>

#include "sim/scene.h"

namespace slshadow {

// Noise (when scene.layers.noise_enabled), rounding and clipping of `irradiance` (CV_32FC1, DN as
// float: PatternRenderer::RenderIrradiance's image) for camera `camera_index` and pattern
// `pattern_index` of a scan. `out` becomes CV_8UC1 when scene.radiometry.adc_bits <= 8, else
// CV_16UC1 (values up to 2^adc_bits - 1); it is reused when it already has that size and type.
// Noise off: each value rounded half up and clipped to [0, full scale] (NaN and negatives to 0).
void QuantizeIrradiance(const cv::Mat& irradiance, const Scene& scene, int camera_index,
                        int pattern_index, cv::Mat* out);

// The per-pixel standard normals n of the noise layer for (seed, camera, pattern) at pixel indices
// first .. first + count - 1 (index = y * width + x). For tests of the generator's statistics.
void SensorNoiseNormals(uint64_t seed, int camera_index, int pattern_index, uint64_t first,
                        int count, float* n);

}  // namespace slshadow
