// The comparison stages of `slshadow shadow` (workflows/twin/internal/twin_run.h): the real and
// the twin's images per camera, their maps, and the clouds per mode.
#include "workflows/twin/internal/twin_run.h"

#include "compare/neighbour_grid.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/twin/internal/twin_images.h"
#include "workflows/twin/internal/twin_stats.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <exception>
#include <memory>
#include <mutex>
#include <optional>
#include <thread>
#include <utility>

#include <Eigen/Dense>
#include <opencv2/core/utility.hpp>

#include "calib/calibration_io.h"
#include "compare/compare.h"
#include "compare/mesh_distance.h"
#include "core/config.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_io.h"
#include "core/image_set.h"
#include "core/kdtree.h"
#include "core/point_cloud.h"
#include "core/pose_io.h"
#include "sim/scene_surface.h"
#include "sim/simulate.h"

namespace slshadow::twin::internal {
namespace fs = std::filesystem;

std::vector<double> SignedC2M(const compare::MeshDistance& mesh,
                              const std::vector<Eigen::Vector3d>& points) {
  std::vector<double> d(points.size());
  cv::parallel_for_(cv::Range(0, static_cast<int>(points.size())), [&](const cv::Range& r) {
    for (int i = r.start; i < r.end; ++i)
      d[static_cast<size_t>(i)] = mesh.Closest(points[static_cast<size_t>(i)]).signed_distance_mm;
  });
  return d;
}

namespace {

// The projector-coordinate error (px) that the rig's calibration uncertainty explains for
// `camera`: the p95 projection uncertainties the rig file's calibration evidence keeps for the
// projector and the camera (docs/formats.md "Calibration evidence", the larger of the two noise
// models), the camera's in projector pixels, added in quadrature; NaN when the file has neither.
double RigUncertaintyPx(const Rig& rig, const std::string& camera) {
  if (!rig.projector) return std::nan("");
  const double proj = EvidenceProjectionUncertaintyP95Px(rig.calibration, rig.projector->name);
  const double cam = EvidenceProjectionUncertaintyP95Px(rig.calibration, camera);
  if (!std::isfinite(proj) && !std::isfinite(cam)) return std::nan("");
  const double cam_in_proj =
      std::isfinite(cam) ? cam * rig.projector->model.fx() / rig.Camera(camera).model.fx() : 0.0;
  return std::hypot(std::isfinite(proj) ? proj : 0.0, cam_in_proj);
}

// 5. Images (the per-camera comparisons: workflows/twin/twin_images.cc).
// Camera c's evidence for the diagnosis, and its white-difference and modulation-ratio maps.
void CameraEvidenceAndMaps(ShadowRun& run, size_t c, const GeometryBuffer& g, const cv::Mat& mask,
                           const std::vector<cv::Mat>& rimg, const std::vector<cv::Mat>& timg) {
  const PatternSpec& spec = run.spec;
  const ProjectorMap& rm = run.real_rec.maps[c];
  const ProjectorMap& gt = g.projector;
  const CameraData& data_c = run.data[c];
  CameraEvidence& ev = run.evidence[c];
  ev.camera = run.cameras[c];
  ev.width = g.width;
  ev.height = g.height;
  ev.mask = mask;
  ev.real_x = rm.proj_x;
  ev.real_y = rm.proj_y;
  ev.gt_x = gt.proj_x;
  ev.gt_y = gt.proj_y;
  if (!spec.code_x) ev.real_x = ev.gt_x = cv::Mat();
  if (!spec.code_y) ev.real_y = ev.gt_y = cv::Mat();
  ev.real = run.real_images[c];
  ev.white = data_c.white;
  ev.black = data_c.black;
  ev.projector_fx = run.twin_rig.projector->model.fx();
  ev.projector_fy = run.twin_rig.projector->model.fy();
  ev.projector_cx = run.twin_rig.projector->model.cx();
  ev.projector_cy = run.twin_rig.projector->model.cy();
  ev.rig_uncertainty_px = RigUncertaintyPx(run.rig, ev.camera);
  cv::Mat twin_white = data_c.twin_white, twin_black = data_c.twin_black;
  if (twin_white.empty() || twin_black.empty())
    WhiteBlackImages(spec, timg, &twin_white, &twin_black);
  const cv::Mat mr = data_c.real_modulation.empty()
                         ? NormalisedModulation(spec, rimg, ev.white, ev.black)
                         : data_c.real_modulation;
  const cv::Mat mt = data_c.twin_modulation.empty()
                         ? NormalisedModulation(spec, timg, twin_white, twin_black)
                         : data_c.twin_modulation;
  ev.modulation_ratio = mr / mt;
  cv::Mat wd(g.height, g.width, CV_32FC1, cv::Scalar(std::nanf("")));
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (mask.at<uint8_t>(y, x))
        wd.at<float>(y, x) = ev.white.at<float>(y, x) - twin_white.at<float>(y, x);
    }
  }
  run.maps.white_difference[c] = wd;
  cv::Mat mod = ev.modulation_ratio.clone();
  for (int y = 0; y < g.height; ++y) {
    for (int x = 0; x < g.width; ++x) {
      if (!mask.at<uint8_t>(y, x)) mod.at<float>(y, x) = std::nanf("");
    }
  }
  run.maps.modulation[c] = mod;
}

// 5. Images, camera c: its report entry, evidence and maps.
nlohmann::json CompareCamera(ShadowRun& run, size_t c, const std::vector<FrameInfo>& frames) {
  const GeometryBuffer& g = run.simulator->geometry(run.twin_rig.CameraIndex(run.cameras[c]));
  const std::vector<cv::Mat>& rimg = *run.real_images[c];
  const std::vector<cv::Mat>& timg = *run.twin_images[c];
  const cv::Mat mask = LitPartMask(g);
  const int64_t lit = cv::countNonZero(mask);
  const int nf = run.spec.NumImages();
  const FrameAgreement agreement = CompareFrames(run.spec, frames, rimg, timg, mask, g, run.fs_dn);
  nlohmann::json projector_coordinates =
      CompareProjectorCoordinates(run.spec, run.real_rec.maps[c], run.twin_rec.maps[c], g.projector,
                                  mask, lit, g, &run.maps.residual[c], &run.maps.validity[c]);
  nlohmann::json cj = {
      {"camera", run.cameras[c]},
      {"lit_part_pixels", lit},
      {"full_scale_dn", run.fs_dn},
      {"within_5pct_all_frames",
       lit ? static_cast<double>(agreement.in_all) / static_cast<double>(lit * nf) : 0.0},
      {"within_5pct_worst_frame", agreement.worst},
      {"patterns", agreement.per}};
  cj["projector_coordinates"] = std::move(projector_coordinates);
  CameraEvidenceAndMaps(run, c, g, mask, rimg, timg);
  return cj;
}

}  // namespace

// 5. Images: the cameras side by side (each mostly serial work); the report gets them in rig
// order.
void CompareImages(ShadowRun& run) {
  StageMeter meter("compare images");
  const Scene& fitted = run.fitted;
  run.response.resize(256);
  for (int v = 0; v < 256; ++v)
    run.response[static_cast<size_t>(v)] = static_cast<float>(
        fitted.layers.response_enabled ? std::pow(v / 255.0, fitted.layers.gamma) : v / 255.0);
  const size_t num_cameras = run.cameras.size();
  run.evidence.resize(num_cameras);
  nlohmann::json& report = run.result.report;
  report["images"]["cameras"] = nlohmann::json::array();
  const std::vector<FrameInfo> frames = run.spec.Frames();
  std::vector<nlohmann::json> camera_json(num_cameras);
  run.maps.residual.resize(num_cameras);
  run.maps.validity.resize(num_cameras);
  run.maps.white_difference.resize(num_cameras);
  run.maps.modulation.resize(num_cameras);
  cv::parallel_for_(cv::Range(0, static_cast<int>(num_cameras)),
                    [&](const cv::Range& camera_range) {
                      for (int camera_index = camera_range.start; camera_index < camera_range.end;
                           ++camera_index) {
                        const size_t c = static_cast<size_t>(camera_index);
                        camera_json[c] = CompareCamera(run, c, frames);
                      }
                    });
  for (auto& cj : camera_json) report["images"]["cameras"].push_back(std::move(cj));
  run.result.stages.push_back(meter.Stop());
}

// The report's maps depend on the images only: drawn on a thread of their own (PLplot and PNG
// encoding are single-threaded) while the clouds are compared and the diagnosis runs.
void StartMapsWriter(ShadowRun& run) {
  if (run.out_dir.empty()) return;
  std::error_code ec;
  run.staged.emplace(run.out_dir);
  const fs::path maps_dir = run.staged->path() / "maps";
  fs::create_directories(maps_dir, ec);
  SLSHADOW_THROW_IF(ec, maps_dir.string(), ": cannot create folder: ", ec.message());
  run.maps_writer.Start([&run, maps_dir] {
    WriteShadowMaps(maps_dir, run.cameras, run.spec, run.options.diagnose, run.fs_dn, run.maps,
                    &run.maps_json);
  });
}

namespace {

// Clouds, mode m: the real and twin clouds (thinned to kComparedPoints) against the part and
// each other on the part; appended to the report and the run.
void CompareMode(ShadowRun& run, size_t m) {
  Reconstructions& real_rec = run.real_rec;
  Reconstructions& twin_rec = run.twin_rec;
  const compare::MeshDistance& part_distance = *run.part_distance_at_pose;
  ModeClouds mc;
  mc.mode = real_rec.modes[m].first;
  // At most kComparedPoints per cloud: every s-th point (the clouds not needed whole were made
  // that way by DecodeAndReconstruct: the same points).
  const auto thin = [](PointCloud cloud) {
    const size_t stride =
        std::max<size_t>(1, (cloud.size() + kComparedPoints - 1) / kComparedPoints);
    if (stride == 1) return cloud;
    std::vector<bool> keep(cloud.size(), false);
    for (size_t i = 0; i < cloud.size(); i += stride) keep[i] = true;
    return cloud.Select(keep);
  };
  const int64_t real_total = real_rec.modes[m].second.summary.points,
                twin_total = twin_rec.modes[m].second.summary.points;
  mc.real = thin(std::move(real_rec.modes[m].second.cloud));
  mc.twin = thin(std::move(twin_rec.modes[m].second.cloud));
  mc.real_c2m = SignedC2M(part_distance, mc.real.points);
  mc.twin_c2m = SignedC2M(part_distance, mc.twin.points);
  // Compare on the part only: points within 2 mm of it (the rest is background the twin lacks).
  const auto on_part = [](const PointCloud& cloud, const std::vector<double>& d,
                          std::vector<Eigen::Vector3d>* pts, std::vector<double>* vals) {
    for (size_t i = 0; i < cloud.size(); ++i) {
      if (std::abs(d[i]) < 2.0) pts->push_back(cloud.points[i]), vals->push_back(d[i]);
    }
  };
  ModeEvidence me;
  me.mode = mc.mode;
  if (run.pose_fit && run.pose_fit->points >= 100) {
    // The pose's uncertainty at a point, from the normal of its closest triangle.
    const internal::PoseUncertainty* u = &run.pose_fit->uncertainty;
    const Rigid3d part_from_rig = run.rig_from_part.Inverse();
    const compare::MeshDistance* mesh = &part_distance;
    me.pose_sigma_mm = [u, part_from_rig, mesh](const Eigen::Vector3d& p) {
      const compare::MeshHit hit = mesh->Closest(p);
      return u->PointSigmaMm(part_from_rig * p,
                             part_from_rig.rotation * mesh->FaceNormal(hit.triangle));
    };
  }
  on_part(mc.real, mc.real_c2m, &me.real_points, &me.real_c2m);
  on_part(mc.twin, mc.twin_c2m, &me.virtual_points, &me.virtual_c2m);
  std::vector<double> diff;
  if (!me.virtual_points.empty()) {
    const compare::NeighbourGrid tree(me.virtual_points);
    diff.resize(me.real_points.size(), std::nan(""));
    cv::parallel_for_(cv::Range(0, static_cast<int>(me.real_points.size())),
                      [&](const cv::Range& r) {
                        for (int i = r.start; i < r.end; ++i) {
                          Neighbor nb;
                          if (tree.Nearest(me.real_points[static_cast<size_t>(i)], &nb, 1.0))
                            diff[static_cast<size_t>(i)] =
                                me.real_c2m[static_cast<size_t>(i)] - me.virtual_c2m[nb.index];
                        }
                      });
  }
  const SampleStats sr = ComputeSampleStats(me.real_c2m), st = ComputeSampleStats(me.virtual_c2m),
                    sd = ComputeSampleStats(diff);
  // LoD95 of a real - twin difference from the twin's own scatter about the part (both scans
  // carry that noise): 1.96 sqrt(2) sigma.
  const double lod95 = 1.96 * std::sqrt(2.0) * st.stddev;
  int64_t significant = 0;
  for (double d : diff) {
    if (std::isfinite(d) && std::abs(d) > lod95) ++significant;
  }
  run.result.report["clouds"]["modes"].push_back(
      {{"mode", mc.mode},
       {"real_points", real_total},
       {"twin_points", twin_total},
       {"compared_real_points", mc.real.size()},
       {"compared_twin_points", mc.twin.size()},
       {"on_part_gate_mm", 2.0},
       {"real_vs_part", sr.ToJson("mm")},
       {"twin_vs_part", st.ToJson("mm")},
       {"real_vs_twin", sd.ToJson("mm")},
       {"lod95_mm", lod95},
       {"real_vs_twin_significant_fraction",
        sd.count ? static_cast<double>(significant) / static_cast<double>(sd.count) : 0.0},
       {"real_summary", real_rec.modes[m].second.summary.ToJson()},
       {"twin_summary", twin_rec.modes[m].second.summary.ToJson()}});
  run.mode_evidence.push_back(std::move(me));
  run.clouds.push_back(std::move(mc));
  run.mode_diffs.push_back(std::move(diff));
  run.mode_lod95.push_back(lod95);
}

}  // namespace

// 5. Clouds.
void CompareClouds(ShadowRun& run) {
  StageMeter meter("compare clouds");
  run.result.report["clouds"]["modes"] = nlohmann::json::array();
  for (size_t m = 0; m < run.real_rec.modes.size(); ++m) CompareMode(run, m);
  run.result.stages.push_back(meter.Stop());
}

}  // namespace slshadow::twin::internal
