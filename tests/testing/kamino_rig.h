// The real projector-camera set ../shared/data/kamino-procam-graycode (one camera, one projector,
// OpenCV Gray code, a chessboard in 5 poses) with an upstream stereoCalibrate result as a rig
// (calibration_result_ccf1cd8.xml or calibration_result.xml: X_proj = R X_cam + t, units of the
// 75-unit squares: mm). Shared by the tests that read those captures.
#pragma once

#include <string>

#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "core/camera_model.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow::testing {

inline std::filesystem::path KaminoDir() { return SharedDataDir() / "kamino-procam-graycode"; }

inline Rig KaminoRig(const std::string& xml = "calibration_result_ccf1cd8.xml") {
  cv::FileStorage fs((KaminoDir() / xml).string(), cv::FileStorage::READ);
  cv::Mat ck, cd, pk, pd, r, t;
  fs["cam_int"] >> ck;
  fs["cam_dist"] >> cd;
  fs["proj_int"] >> pk;
  fs["proj_dist"] >> pd;
  fs["roration"] >> r;  // sic
  fs["translation"] >> t;
  auto model = [](int w, int h, const cv::Mat& k, const cv::Mat& d) {
    return CameraModel(w, h, k.at<double>(0, 0), k.at<double>(1, 1), k.at<double>(0, 2),
                       k.at<double>(1, 2), d.at<double>(0), d.at<double>(1), d.at<double>(2),
                       d.at<double>(3), d.at<double>(4));
  };
  Rig rig;
  rig.name = "kamino";
  rig.working_distance_mm = 1000;
  rig.cameras.push_back({"camera", model(1280, 1024, ck, cd), Rigid3d()});
  Eigen::Matrix3d rot;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) rot(i, j) = r.at<double>(i, j);
  }
  rig.projector =
      RigDevice{"projector", model(1024, 768, pk, pd),
                Rigid3d(Eigen::Quaterniond(rot),
                        Eigen::Vector3d(t.at<double>(0), t.at<double>(1), t.at<double>(2)))};
  rig.Check("kamino");
  return rig;
}

}  // namespace slshadow::testing
