// The last step of the pattern pass (sim/renderer.h): the sensor-noise layer and the ADC of a
// camera (sim/scene.h SceneLayers, EMVA 1288 style) applied to a noise-free irradiance image.
// One definition, used by PatternRenderer and by the sweep's reuse of noise-free images
// (shadow/sweep_reuse.h), so both give the same image bit for bit.
//
// The noise generator (docs/simulator.md, "Sensor noise"): per pixel, a 32-bit counter-based
// hash of (seed, camera, pattern, pixel index) gives two uniforms; Box-Muller turns them into two
// independent standard normals (shot and read noise), with its own polynomial log, sine and
// cosine (Cephes' single-precision coefficients, ~1e-7 relative error) computed eight pixels at a
// time. Deterministic for a seed whatever the thread count or the CPU (the same IEEE operations in
// every code path, no FMA).
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

// The per-pixel standard normals of the noise layer for (seed, camera, pattern) at pixel indices
// first .. first + count - 1 (index = y * width + x): n1 (shot noise) and n2 (read noise). For
// tests of the generator's statistics.
void SensorNoiseNormals(uint64_t seed, int camera_index, int pattern_index, uint32_t first,
                        int count, float* n1, float* n2);

}  // namespace slshadow
