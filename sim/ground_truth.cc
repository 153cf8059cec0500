// Simulator ground truth as files and back (docs/formats.md, "Simulator ground truth"; declared
// in sim/simulate.h): depth, points and normals as .npy, visibility / object ids / status as PNG,
// the visible surface as PLY, each written atomically.
#include <cstdint>
#include <cstring>
#include <fstream>
#include <string>
#include <utility>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/npy.h"
#include "core/point_cloud.h"
#include "sim/simulate.h"

namespace slshadow {
namespace {

void WriteImageAtomically(const std::filesystem::path& path, const cv::Mat& image) {
  WriteFileAtomically(path, [&](const std::filesystem::path& tmp) {
    // The encoder is picked from the extension; keep it on the temporary name.
    const std::filesystem::path with_ext = tmp.string() + path.extension().string();
    WriteImage(with_ext, image);
    std::filesystem::rename(with_ext, tmp);
  });
}

cv::Mat ReadImage(const std::filesystem::path& path, int expected_type) {
  const cv::Mat m = ReadImage(path, ImageReadMode::kUnchanged);
  SLSHADOW_THROW_IF(m.type() != expected_type, path.string(), ": unexpected image type ", m.type(),
                    " (expected ", expected_type, ")");
  return m;
}

}  // namespace

PointCloud VisibleSurface(const GeometryBuffer& g) {
  PointCloud cloud;
  std::vector<float> object_id, lit, proj_x, proj_y, pixel_x, pixel_y;
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (g.visibility.at<uint8_t>(y, x) == 0) continue;
      const cv::Vec3f p = g.point_in_rig.at<cv::Vec3f>(y, x);
      const cv::Vec3f n = g.normal_in_rig.at<cv::Vec3f>(y, x);
      cloud.points.emplace_back(p[0], p[1], p[2]);
      cloud.normals.emplace_back(n[0], n[1], n[2]);
      object_id.push_back(static_cast<float>(g.object_id.at<int32_t>(y, x)));
      lit.push_back(g.visibility.at<uint8_t>(y, x) == 2 ? 1.0f : 0.0f);
      proj_x.push_back(g.projector.proj_x.at<float>(y, x));
      proj_y.push_back(g.projector.proj_y.at<float>(y, x));
      pixel_x.push_back(static_cast<float>(x));
      pixel_y.push_back(static_cast<float>(y));
    }
  }
  cloud.SetScalar("object_id", std::move(object_id));
  cloud.SetScalar("lit", std::move(lit));
  cloud.SetScalar("proj_x", std::move(proj_x));
  cloud.SetScalar("proj_y", std::move(proj_y));
  cloud.SetScalar("pixel_x", std::move(pixel_x));
  cloud.SetScalar("pixel_y", std::move(pixel_y));
  return cloud;
}

void WriteGroundTruth(const GeometryBuffer& g, const std::filesystem::path& dir) {
  std::filesystem::create_directories(dir);
  cv::Mat ids(g.height, g.width, CV_16UC1);
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x)
      ids.at<uint16_t>(y, x) = static_cast<uint16_t>(g.object_id.at<int32_t>(y, x) + 1);
  }
  const std::vector<std::pair<std::string, cv::Mat>> files = {
      {"depth_mm.npy", g.depth_mm},           {"point_in_rig_mm.npy", g.point_in_rig},
      {"normal_in_rig.npy", g.normal_in_rig}, {"proj_x.npy", g.projector.proj_x},
      {"proj_y.npy", g.projector.proj_y},     {"status.png", g.projector.status},
      {"visibility.png", g.visibility},       {"object_id.png", ids}};
  tbb::parallel_for(size_t{0}, files.size() + 1, [&](size_t i) {
    if (i < files.size()) {
      if (files[i].first.ends_with(".npy")) {
        WriteNpy(dir / files[i].first, files[i].second);
      } else {
        WriteImageAtomically(dir / files[i].first, files[i].second);
      }
    } else {
      WritePly(dir / "surface.ply", VisibleSurface(g), PlyWriteOptions{true, false});
    }
  });
}

GroundTruth ReadGroundTruth(const std::filesystem::path& dir) {
  GroundTruth gt;
  gt.depth_mm = ReadNpy(dir / "depth_mm.npy", 1);
  gt.point_in_rig = ReadNpy(dir / "point_in_rig_mm.npy", 3);
  gt.normal_in_rig = ReadNpy(dir / "normal_in_rig.npy", 3);
  gt.visibility = ReadImage(dir / "visibility.png", CV_8UC1);
  const cv::Mat ids = ReadImage(dir / "object_id.png", CV_16UC1);
  ids.convertTo(gt.object_id, CV_32SC1, 1, -1);
  gt.projector.proj_x = ReadNpy(dir / "proj_x.npy", 1);
  gt.projector.proj_y = ReadNpy(dir / "proj_y.npy", 1);
  gt.projector.status = ReadImage(dir / "status.png", CV_8UC1);
  gt.projector.quality = cv::Mat(gt.projector.status.size(), CV_32FC1, cv::Scalar(0));
  gt.projector.has_x = gt.projector.has_y = true;
  return gt;
}

}  // namespace slshadow
