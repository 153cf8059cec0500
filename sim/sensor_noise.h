// The last step of the pattern pass (sim/renderer.h): the sensor-noise layer and the ADC of a
// camera (sim/scene.h SceneLayers, EMVA 1288 style) applied to a noise-free irradiance image.
// One definition, used by PatternRenderer and by the sweep's reuse of noise-free images
// (shadow/sweep_reuse.h), so both give the same image bit for bit.
//
// The noise generator (docs/formats.md, layer `noise`): per pixel, SplitMix64 of (the image's
// stream, a hash of seed, camera and pattern) + the pixel index y * width + x, and SplitMix64 of
// that, give two 24-bit uniforms; Box-Muller turns them into two independent standard normals
// (shot and read noise). Eight pixels at a time: the hashes in 64-bit lanes, log, sine and cosine
// as polynomials (Cephes' single-precision ones, within ~2 ulp of the C library's logf / sinf /
// cosf that computed them before, so the images stay those of earlier versions but for a rare
// pixel at a rounding boundary), the signal in double lanes. Deterministic for a seed whatever
// the thread count or the CPU (the same IEEE operations in every code path, no FMA).
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
void SensorNoiseNormals(uint64_t seed, int camera_index, int pattern_index, uint64_t first,
                        int count, float* n1, float* n2);

}  // namespace slshadow
