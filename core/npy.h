// NumPy .npy files (format version 1.0) for float maps: little-endian float32 ('<f4'), C order,
// shape (rows, cols) for one channel or (rows, cols, 3) for three. The simulator's ground truth
// (sim/simulate.h) is stored this way, so NumPy reads it with np.load.
#pragma once

#include <filesystem>

#include <opencv2/core.hpp>

namespace slshadow {

// Writes a continuous CV_32FC1 or CV_32FC3 matrix atomically (temporary name, then rename).
void WriteNpy(const std::filesystem::path& path, const cv::Mat& m);

// Reads a file WriteNpy wrote (or NumPy saved with the same dtype, order and shape) as CV_32FC1
// or CV_32FC3. The shape is checked against the file size before anything is allocated. Throws
// slshadow::Error naming the file and the header field on a bad magic, dtype, order, shape,
// channel count other than `channels`, or a size that does not match the shape.
cv::Mat ReadNpy(const std::filesystem::path& path, int channels);

}  // namespace slshadow
