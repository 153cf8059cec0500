#include "calib/target.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include <opencv2/aruco/charuco.hpp>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "core/config.h"
#include "core/error.h"
#include "core/image_io.h"

namespace slshadow {
namespace {

const std::vector<std::pair<std::string, int>>& Dictionaries() {
  using namespace cv::aruco;
  static const std::vector<std::pair<std::string, int>> kDicts = {
      {"DICT_4X4_50", DICT_4X4_50},
      {"DICT_4X4_100", DICT_4X4_100},
      {"DICT_4X4_250", DICT_4X4_250},
      {"DICT_4X4_1000", DICT_4X4_1000},
      {"DICT_5X5_50", DICT_5X5_50},
      {"DICT_5X5_100", DICT_5X5_100},
      {"DICT_5X5_250", DICT_5X5_250},
      {"DICT_5X5_1000", DICT_5X5_1000},
      {"DICT_6X6_50", DICT_6X6_50},
      {"DICT_6X6_100", DICT_6X6_100},
      {"DICT_6X6_250", DICT_6X6_250},
      {"DICT_6X6_1000", DICT_6X6_1000},
      {"DICT_7X7_50", DICT_7X7_50},
      {"DICT_7X7_100", DICT_7X7_100},
      {"DICT_7X7_250", DICT_7X7_250},
      {"DICT_7X7_1000", DICT_7X7_1000},
      {"DICT_ARUCO_ORIGINAL", DICT_ARUCO_ORIGINAL},
      {"DICT_APRILTAG_16h5", DICT_APRILTAG_16h5},
      {"DICT_APRILTAG_25h9", DICT_APRILTAG_25h9},
      {"DICT_APRILTAG_36h10", DICT_APRILTAG_36h10},
      {"DICT_APRILTAG_36h11", DICT_APRILTAG_36h11},
  };
  return kDicts;
}

int DictionaryId(const std::string& name) {
  for (const auto& [n, id] : Dictionaries()) {
    if (n == name) return id;
  }
  return -1;
}

cv::Ptr<cv::aruco::CharucoBoard> MakeCharucoBoard(const TargetSpec& spec) {
  return cv::aruco::CharucoBoard::create(
      spec.cols, spec.rows, static_cast<float>(spec.square_size_mm),
      static_cast<float>(spec.marker_size_mm),
      cv::aruco::getPredefinedDictionary(DictionaryId(spec.dictionary)));
}

// 8-bit single-channel view of any supported image.
cv::Mat ToGray8(const cv::Mat& image) {
  cv::Mat gray;
  if (image.channels() == 3) {
    cv::cvtColor(image, gray, cv::COLOR_BGR2GRAY);
  } else if (image.channels() == 4) {
    cv::cvtColor(image, gray, cv::COLOR_BGRA2GRAY);
  } else {
    gray = image;
  }
  if (gray.depth() == CV_16U) {
    cv::Mat g8;
    gray.convertTo(g8, CV_8U, 1.0 / 257.0);
    return g8;
  }
  if (gray.depth() != CV_8U) {
    cv::Mat g8;
    cv::normalize(gray, g8, 0, 255, cv::NORM_MINMAX, CV_8U);
    return g8;
  }
  return gray;
}

std::string Hint(const TargetDetection& d) {
  if (d.saturated_fraction > 0.05) {
    return " (" + std::to_string(static_cast<int>(d.saturated_fraction * 100 + 0.5)) +
           "% of pixels saturated: lower the exposure)";
  }
  if (d.mean_grey < 20) return " (image very dark: raise the exposure or the light)";
  return " (is the whole board inside the image, in focus, with the configured size?)";
}

// Saturated share inside the convex hull of the detected points.
void SaturationInBoard(const cv::Mat& gray, const TargetSpec& spec, TargetDetection* d) {
  std::vector<cv::Point> pts, hull;
  for (const auto& p : d->pixels_px)
    pts.emplace_back(static_cast<int>(std::lround(p.x())), static_cast<int>(std::lround(p.y())));
  if (pts.size() < 3) return;
  cv::convexHull(pts, hull);
  cv::Mat mask(gray.size(), CV_8UC1, cv::Scalar(0));
  cv::fillConvexPoly(mask, hull, cv::Scalar(255));
  const int area = cv::countNonZero(mask);
  if (area == 0) return;
  d->saturated_fraction =
      static_cast<double>(cv::countNonZero((gray >= spec.saturation_level) & mask)) / area;
}

}  // namespace

std::string ToString(TargetType type) {
  switch (type) {
    case TargetType::kChessboard:
      return "chessboard";
    case TargetType::kCharuco:
      return "charuco";
    case TargetType::kCirclesSymmetric:
      return "circles";
    case TargetType::kCirclesAsymmetric:
      return "circles_asymmetric";
  }
  return "?";
}

int TargetSpec::NumPoints() const {
  if (type == TargetType::kCharuco) return (cols - 1) * (rows - 1);
  return cols * rows;
}

void TargetSpec::Check(const std::string& what) const {
  const int min_size = type == TargetType::kCharuco ? 3 : 2;
  SLSHADOW_THROW_IF(cols < min_size || rows < min_size, what, ": size: need at least ", min_size,
                    "x", min_size, (type == TargetType::kCharuco ? " squares" : " points"),
                    " (got ", cols, "x", rows, ")");
  SLSHADOW_THROW_IF(!(square_size_mm > 0), what, ": square_size_mm: must be positive (got ",
                    square_size_mm, ")");
  if (type == TargetType::kCharuco) {
    SLSHADOW_THROW_IF(!(marker_size_mm > 0 && marker_size_mm < square_size_mm), what,
                      ": marker_size_mm: must be positive and smaller than square_size_mm (got ",
                      marker_size_mm, ")");
    SLSHADOW_THROW_IF(DictionaryId(dictionary) < 0, what,
                      ": dictionary: unknown ArUco dictionary (got '", dictionary,
                      "'; e.g. DICT_6X6_250)");
    SLSHADOW_THROW_IF(min_charuco_corners < 4, what, ": min_corners: must be at least 4 (got ",
                      min_charuco_corners, ")");
  }
  SLSHADOW_THROW_IF(!(subpix_epsilon_px > 0 && subpix_epsilon_px <= 1), what,
                    ": subpix_epsilon_px: must be in (0, 1] (got ", subpix_epsilon_px, ")");
  SLSHADOW_THROW_IF(subpix_half_window_px < 1 || subpix_half_window_px > 50, what,
                    ": subpix_half_window_px: must be in 1..50 (got ", subpix_half_window_px, ")");
}

TargetSpec TargetSpecFromConfig(const ConfigNode& node) {
  node.RejectUnknownKeys({"format", "version", "type", "cols", "rows", "square_size_mm",
                          "marker_size_mm", "dictionary", "detector", "subpix_half_window_px",
                          "subpix_epsilon_px", "min_corners", "saturation_level"});
  TargetSpec spec;
  const auto type_node = node["type"];
  const std::string type = type_node.AsString();
  if (type == "chessboard") {
    spec.type = TargetType::kChessboard;
  } else if (type == "charuco") {
    spec.type = TargetType::kCharuco;
  } else if (type == "circles") {
    spec.type = TargetType::kCirclesSymmetric;
  } else if (type == "circles_asymmetric") {
    spec.type = TargetType::kCirclesAsymmetric;
  } else {
    type_node.Fail("unknown target type (use chessboard, charuco, circles or circles_asymmetric)");
  }
  spec.cols = static_cast<int>(node["cols"].AsInt());
  spec.rows = static_cast<int>(node["rows"].AsInt());
  spec.square_size_mm = node["square_size_mm"].AsDouble();
  if (spec.type == TargetType::kCharuco) {
    spec.marker_size_mm = node["marker_size_mm"].AsDouble();
    spec.dictionary = node["dictionary"].AsString();
    if (DictionaryId(spec.dictionary) < 0) {
      std::string known;
      for (const auto& d : Dictionaries()) known += (known.empty() ? "" : ", ") + d.first;
      node["dictionary"].Fail("unknown ArUco dictionary (known: " + known + ")");
    }
    spec.min_charuco_corners =
        static_cast<int>(node.GetInt("min_corners", spec.min_charuco_corners));
  }
  if (node.Has("detector")) {
    const auto det = node["detector"];
    const std::string name = det.AsString();
    if (name == "sb") {
      spec.detector = ChessboardDetector::kSectorBased;
    } else if (name == "classic") {
      spec.detector = ChessboardDetector::kClassic;
    } else {
      det.Fail("unknown chessboard detector (use sb or classic)");
    }
  }
  spec.subpix_half_window_px =
      static_cast<int>(node.GetInt("subpix_half_window_px", spec.subpix_half_window_px));
  spec.subpix_epsilon_px = node.GetDouble("subpix_epsilon_px", spec.subpix_epsilon_px);
  spec.saturation_level = node.GetDouble("saturation_level", spec.saturation_level);
  spec.Check(node.file());
  return spec;
}

TargetSpec LoadTargetSpec(const std::filesystem::path& path) {
  return TargetSpecFromConfig(ConfigNode::LoadFile(path));
}

std::vector<Eigen::Vector3d> BoardPoints(const TargetSpec& spec) {
  std::vector<Eigen::Vector3d> points;
  points.reserve(static_cast<size_t>(spec.NumPoints()));
  switch (spec.type) {
    case TargetType::kChessboard:
    case TargetType::kCirclesSymmetric:
      for (int r = 0; r < spec.rows; ++r) {
        for (int c = 0; c < spec.cols; ++c)
          points.emplace_back(c * spec.square_size_mm, r * spec.square_size_mm, 0);
      }
      break;
    case TargetType::kCirclesAsymmetric:
      for (int r = 0; r < spec.rows; ++r) {
        for (int c = 0; c < spec.cols; ++c) {
          points.emplace_back((2 * c + r % 2) * spec.square_size_mm, r * spec.square_size_mm, 0);
        }
      }
      break;
    case TargetType::kCharuco: {
      const auto board = MakeCharucoBoard(spec);
      for (const auto& p : board->chessboardCorners) points.emplace_back(p.x, p.y, p.z);
      break;
    }
  }
  return points;
}

TargetDetection DetectTarget(const TargetSpec& spec, const cv::Mat& image) {
  SLSHADOW_THROW_IF(image.empty(), "DetectTarget: empty image");
  TargetDetection d;
  d.width = image.cols;
  d.height = image.rows;
  const cv::Mat gray = ToGray8(image);
  d.mean_grey = cv::mean(gray)[0];
  d.saturated_fraction = static_cast<double>(cv::countNonZero(gray >= spec.saturation_level)) /
                         static_cast<double>(gray.total());

  std::vector<cv::Point2f> corners;
  const cv::Size size(spec.cols, spec.rows);
  const std::string size_text = std::to_string(spec.cols) + "x" + std::to_string(spec.rows);
  switch (spec.type) {
    case TargetType::kChessboard: {
      bool ok = false;
      if (spec.detector == ChessboardDetector::kSectorBased) {
        ok = cv::findChessboardCornersSB(
            gray, size, corners,
            cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_EXHAUSTIVE | cv::CALIB_CB_ACCURACY);
      } else {
        ok = cv::findChessboardCorners(gray, size, corners,
                                       cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE);
        if (ok) {
          const int w = spec.subpix_half_window_px;
          cv::cornerSubPix(gray, corners, cv::Size(w, w), cv::Size(-1, -1),
                           cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 30,
                                            spec.subpix_epsilon_px));
        }
      }
      if (!ok) {
        d.reason = size_text + " inner-corner chessboard not found" + Hint(d);
        return d;
      }
      break;
    }
    case TargetType::kCirclesSymmetric:
    case TargetType::kCirclesAsymmetric: {
      const int flags = spec.type == TargetType::kCirclesSymmetric ? cv::CALIB_CB_SYMMETRIC_GRID
                                                                   : cv::CALIB_CB_ASYMMETRIC_GRID;
      if (!cv::findCirclesGrid(gray, size, corners, flags)) {
        d.reason = size_text + " " + ToString(spec.type) + " grid not found" + Hint(d);
        return d;
      }
      break;
    }
    case TargetType::kCharuco: {
      const auto board = MakeCharucoBoard(spec);
      std::vector<std::vector<cv::Point2f>> marker_corners;
      std::vector<int> marker_ids;
      cv::aruco::detectMarkers(gray, board->dictionary, marker_corners, marker_ids,
                               cv::aruco::DetectorParameters::create());
      if (marker_ids.empty()) {
        d.reason = "no " + spec.dictionary + " ArUco marker found" + Hint(d);
        return d;
      }
      std::vector<cv::Point2f> charuco_corners;
      std::vector<int> charuco_ids;
      cv::aruco::interpolateCornersCharuco(marker_corners, marker_ids, gray, board, charuco_corners,
                                           charuco_ids);
      if (static_cast<int>(charuco_ids.size()) < spec.min_charuco_corners) {
        d.reason = std::to_string(marker_ids.size()) + " markers but only " +
                   std::to_string(charuco_ids.size()) + " ChArUco corners (need " +
                   std::to_string(spec.min_charuco_corners) + ")" + Hint(d);
        return d;
      }
      d.found = true;
      for (size_t i = 0; i < charuco_ids.size(); ++i) {
        d.pixels_px.emplace_back(charuco_corners[i].x, charuco_corners[i].y);
        d.point_ids.push_back(charuco_ids[i]);
      }
      SaturationInBoard(gray, spec, &d);
      return d;
    }
  }
  d.found = true;
  for (size_t i = 0; i < corners.size(); ++i) {
    d.pixels_px.emplace_back(corners[i].x, corners[i].y);
    d.point_ids.push_back(static_cast<int>(i));
  }
  SaturationInBoard(gray, spec, &d);
  return d;
}

TargetDetection DetectTargetInFile(const TargetSpec& spec, const std::filesystem::path& path) {
  SLSHADOW_THROW_IF(!std::filesystem::exists(path), path.string(), ": image file not found");
  return DetectTarget(spec, ReadImage(path, ImageReadMode::kUnchanged));
}

}  // namespace slshadow
