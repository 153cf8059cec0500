// Calibration targets: what the board looks like (read from a target YAML file, docs/formats.md
// "Calibration target YAML") and finding it in an image, with a reason when it is not found.
//
// Board frame: z = 0 on the board surface, units mm. Chessboard and circle grids: origin at the
// first inner corner / circle centre, x along the first row, y along the first column. ChArUco:
// OpenCV's CharucoBoard frame (chessboardCorners scaled to mm).
// Point i of BoardPoints() is the i-th corner / circle in OpenCV's detection order:
//   chessboard, symmetric circles: (col * pitch, row * pitch, 0), row-major, i = row * cols + col
//   asymmetric circles:            ((2 col + row % 2) * pitch, row * pitch, 0)  (OpenCV's sample)
//   ChArUco:                       the inner chessboard corners, i = ChArUco corner id
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace slshadow {

class ConfigNode;

enum class TargetType { kChessboard, kCharuco, kCirclesSymmetric, kCirclesAsymmetric };
std::string ToString(TargetType type);  // "chessboard", "charuco", "circles", "circles_asymmetric"

// How a chessboard is found.
enum class ChessboardDetector {
  kSectorBased,  // cv::findChessboardCornersSB (accurate, no refinement needed)
  kClassic       // cv::findChessboardCorners + cv::cornerSubPix (as OpenCV's calibration sample)
};

struct TargetSpec {
  TargetType type = TargetType::kChessboard;
  // Chessboard / circles: inner corners (circles) per row and per column. ChArUco: squares.
  int cols = 0;
  int rows = 0;
  double square_size_mm = 0;  // corner pitch (chessboard, ChArUco) or circle pitch (circle grids)
  double marker_size_mm = 0;  // ChArUco only: side of the ArUco markers
  std::string dictionary;     // ChArUco only: OpenCV name, e.g. "DICT_6X6_250"
  ChessboardDetector detector = ChessboardDetector::kSectorBased;
  int subpix_half_window_px = 11;  // classic detector: cornerSubPix winSize (window 2n+1)
  // Classic detector: cornerSubPix stops when a corner moves less than this, px (OpenCV's
  // TermCriteria EPS; 30 iterations at most). OpenCV 2.x's calibration sample used 0.1.
  double subpix_epsilon_px = 0.001;
  int min_charuco_corners = 6;  // ChArUco: fewer interpolated corners count as not found
  // Grey level at or above which a pixel counts as saturated (8-bit scale), for the report.
  double saturation_level = 250;

  int NumPoints() const;  // number of board points (ChArUco: (cols-1) * (rows-1))
  // Throws slshadow::Error naming `what` when a field is out of range.
  void Check(const std::string& what) const;
};

// Reads a target YAML file (or any config node). Unknown keys and bad values throw naming the
// file and field.
TargetSpec TargetSpecFromConfig(const ConfigNode& node);
TargetSpec LoadTargetSpec(const std::filesystem::path& path);

// All board points in the board frame, mm, indexed as described at the top of this header.
std::vector<Eigen::Vector3d> BoardPoints(const TargetSpec& spec);

// Result of looking for the target in one image.
struct TargetDetection {
  bool found = false;
  std::string
      reason;     // empty when found; else why not, for the user (e.g. "9x6 chessboard not found")
  int width = 0;  // image size, pixels
  int height = 0;
  std::vector<Eigen::Vector2d> pixels_px;  // detected points (OpenCV pixel convention)
  std::vector<int> point_ids;              // index into BoardPoints() for each detected point
  // Share of pixels at or above spec.saturation_level: inside the convex hull of the detected
  // points when found (what biases corners), else over the whole image.
  double saturated_fraction = 0;
  double mean_grey = 0;  // on the 8-bit scale
};

// Finds the target in an 8- or 16-bit, 1- or 3-channel image. Never throws for "not found"
// (that is a result with a reason); throws slshadow::Error only for an empty image.
TargetDetection DetectTarget(const TargetSpec& spec, const cv::Mat& image);

// One image file: reads it (throws naming the file when it cannot be read) and detects.
TargetDetection DetectTargetInFile(const TargetSpec& spec, const std::filesystem::path& path);

}  // namespace slshadow
