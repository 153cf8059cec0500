// The kamino proof (issue 13): calibrate the real projector-camera rig of
// ../shared/data/kamino-procam-graycode, then shadow each of its five captures with the board (a
// plane with its printed chessboard as albedo) at the pose the calibration estimated for that
// capture, and measure real vs virtual per pose.
#include <cstdio>
#include <cstdlib>
#include <fstream>

#include <gtest/gtest.h>

#include "core/image_set.h"
#include "sim/scene_surface.h"
#include "tests/testing/run_cli.h"
#include "tests/testing/temp_dir.h"
#include "workflows/pipeline/scan_pipeline.h"
#include "workflows/twin/twin.h"

namespace slshadow {
namespace {

constexpr double kSquareMm = 75;

// The board in its calibration frame: inner corner (c, r) at (75 c, 75 r, 0), 9 x 7 inner corners,
// 10 x 8 squares, plus a 35 mm paper margin (the printed sheet is larger on every side). The
// simulator's checkerboard has its corner square (at -75..0, -75..0) dark; when the real board's
// corner square is light the plane is turned 180 degrees about its y axis, which mirrors the
// texture onto the other (dark) corner.
twin::ShadowPart KaminoBoard(bool flipped) {
  twin::ShadowPart part;
  part.source = flipped ? "kamino board (texture mirrored)" : "kamino board";
  SceneObject o;
  o.name = "board";
  o.type = ObjectType::kPlane;
  const double margin = 35;
  o.size_mm = Eigen::Vector3d(10 * kSquareMm + 2 * margin, 8 * kSquareMm + 2 * margin, 0);
  o.albedo.kind = Albedo::Kind::kCheckerboard;
  o.albedo.square_mm = kSquareMm;
  o.albedo.squares_x = 10;
  o.albedo.squares_y = 8;
  o.albedo.dark = 0.05;
  o.albedo.light = 0.9;
  const Eigen::Vector3d centre(4 * kSquareMm, 3 * kSquareMm, 0);
  o.albedo_offset_mm = Eigen::Vector2d(centre.x(), centre.y());
  o.rig_from_object =
      flipped
          ? Rigid3d(Eigen::Quaterniond(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitY())), centre)
          : Rigid3d(Eigen::Quaterniond::Identity(), centre);
  part.scene.name = "kamino board";
  part.scene.radiometry.exposure_fraction = 0.5;
  part.scene.layers.supersampling = 3;  // anti-aliased square edges, as a real lens gives
  part.scene.objects.push_back(o);
  part.surface = SceneSurface(part.scene, part.source, twin::kPartPlaneCells);
  return part;
}

Rigid3d PoseFromJson(const nlohmann::json& j) {
  const auto& q = j["rotation_quat_wxyz"];
  const auto& t = j["translation_mm"];
  return Rigid3d(Eigen::Quaterniond(q[0].get<double>(), q[1].get<double>(), q[2].get<double>(),
                                    q[3].get<double>()),
                 Eigen::Vector3d(t[0].get<double>(), t[1].get<double>(), t[2].get<double>()));
}

TEST(ShadowKamino, RealVsVirtualPerPose) {
  testing::TempDir tmp;
  const auto kamino = testing::SharedDataDir() / "kamino-procam-graycode";
  const std::string spec_path =
      (testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml").string();
  const PatternSpec spec = LoadPatternSpec(spec_path);
  // The five captures as ImageSets, then `slshadow calibrate rig` on them.
  const Rig nominal = [&] {
    Rig r;
    r.name = "kamino";
    RigDevice cam;
    cam.name = "camera";
    cam.model = CameraModel(1280, 1024, 3452, 3450, 587, 521);
    r.cameras.push_back(cam);
    RigDevice proj;
    proj.name = "projector";
    proj.model = CameraModel(1024, 768, 1947, 1934, 449, 720);
    r.projector = proj;
    return r;
  }();
  std::vector<std::string> args = {
      "calibrate",
      "rig",
      "--target",
      (testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml").string(),
      "--shadow-threshold",
      "40",
      "--contrast-threshold",
      "5",
      "--min-views",
      "5",
      "--no-cross-validation",
      "--out",
      (tmp / "rig.yaml").string(),
      "--imagesets"};
  for (int p = 0; p < 5; ++p) {
    ImageSetWriterOptions wo;
    wo.encoding = ImageEncoding::kPgm;
    const auto dir = tmp / ("capture_" + std::to_string(p));
    ImageSetWriter writer(dir, nominal, PatternSpecToJson(spec), wo);
    for (int i = 0; i < spec.NumImages(); ++i) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", i);
      writer.Add("camera", i, ReadGrayImage(kamino / ("capture_" + std::to_string(p)) / name), 0,
                 ImageSource::kReplay);
    }
    writer.Commit();
    args.push_back(dir.string());
  }
  ASSERT_EQ(testing::RunCli(args), 0);
  const Rig rig = LoadRig(tmp / "rig.yaml");
  ASSERT_TRUE(rig.projector);
  const auto& poses = rig.calibration["rig_from_board"];
  ASSERT_EQ(poses.size(), 5u);

  std::string table =
      "pose  coords real-truth  real-twin dec.  twin-truth  within 5% FS (all / white)  kept "
      "layers                verdict\n";
  for (int p = 0; p < 5; ++p) {
    const Rigid3d rig_from_board = PoseFromJson(poses[static_cast<size_t>(p)]);
    // Which colour is the corner square? Compare the white frame at its centre and its neighbour's.
    const cv::Mat white =
        ReadGrayImage(kamino / ("capture_" + std::to_string(p)) / "graycode_40.png");
    const auto sample = [&](double x, double y) {
      const Eigen::Vector3d in_cam =
          rig.cameras[0].cam_from_rig * (rig_from_board * Eigen::Vector3d(x, y, 0));
      const auto px = rig.cameras[0].model.Project(in_cam);
      return px ? static_cast<double>(white.at<uint8_t>(static_cast<int>(std::lround(px->y())),
                                                        static_cast<int>(std::lround(px->x()))))
                : 0.0;
    };
    const bool flipped = sample(-37.5, -37.5) > sample(37.5, -37.5);
    twin::ShadowOptions options;
    options.rig_from_part = rig_from_board;
    options.refine_pose =
        false;  // a plane leaves registration blind in-plane: the calibration's pose
    options.decode.shadow_threshold = 40;
    options.decode.contrast_threshold = 5;
    options.overwrite = true;
    // SLSHADOW_KEEP_KAMINO_SHADOW=DIR keeps the report folders (maps, clouds) for a look.
    const char* keep = std::getenv("SLSHADOW_KEEP_KAMINO_SHADOW");
    const auto out =
        (keep ? std::filesystem::path(keep) : tmp.path()) / ("shadow_" + std::to_string(p));
    const twin::ShadowResult r = twin::RunShadow(tmp / ("capture_" + std::to_string(p)),
                                                 KaminoBoard(flipped), options, out, &rig);
    std::printf("%s\n", r.Summary().c_str());
    const auto& cam = r.report["images"]["cameras"][0];
    const auto& pc = cam["projector_coordinates"];
    double white_within = 0;
    for (const auto& f : cam["patterns"]) {
      if (f["name"] == "white") white_within = f["within_5pct"].get<double>();
    }
    std::string kept;
    for (const auto& l : r.physics.layers) {
      if (l.kept) kept += (kept.empty() ? "" : ",") + l.name;
    }
    char line[512];
    std::snprintf(
        line, sizeof(line), "%4d  %8.3f px  %11.3f px  %9.3f px  %9.1f%% / %5.1f%%  %-26s %s\n", p,
        pc["real_vs_truth_rms_px"].get<double>(), pc["real_vs_twin_decoded_rms_px"].get<double>(),
        pc["twin_vs_truth_rms_px"].get<double>(), 100 * cam["within_5pct_all_frames"].get<double>(),
        100 * white_within, kept.c_str(), r.diagnosis.verdict.c_str());
    table += line;
    // Goals (issue 13): decoded projector coordinates within 0.3 px RMS of the twin's truth (met
    // on every pose: 0.271-0.289 px measured); intensity within 5 % of full scale on >= 95 % of
    // the lit board pixels over all 42 frames (met since the black-level, illumination-field and
    // global-light layers: 96.6-98.3 % measured; 91.5-94.7 % without them).
    EXPECT_LT(pc["real_vs_truth_rms_px"].get<double>(), 0.3) << "pose " << p;
    EXPECT_GT(cam["within_5pct_all_frames"].get<double>(), 0.95) << "pose " << p;
    EXPECT_GT(cam["lit_part_pixels"].get<int64_t>(), 150000) << "pose " << p;
    // The camera's black level: the black frame reads 6 DN on dark and light squares alike
    // (6.28-6.49 DN fitted), so the offset is kept and ambient left off (0.002 of white, 10 sigma,
    // but the held-out residual drops by less than 5 %). The independent figure is the black
    // frame's own mean over the pixels the projector lights (white - black >= 40, the shadow
    // threshold above), read from the capture: the fit must land within 0.5 DN of it.
    const cv::Mat black =
        ReadGrayImage(kamino / ("capture_" + std::to_string(p)) / "graycode_41.png");
    cv::Mat lit;
    cv::compare(white, black + 40, lit, cv::CMP_GE);
    const double black_read = cv::mean(black, lit)[0];
    std::printf("pose %d: black frame over the lit pixels %.2f DN\n", p, black_read);
    ASSERT_NE(r.physics.Find("black_level_camera"), nullptr);
    EXPECT_TRUE(r.physics.Kept("black_level_camera")) << "pose " << p;
    EXPECT_NEAR(r.physics.Find("black_level_camera")->value, black_read, 0.5) << "pose " << p;
    EXPECT_FALSE(r.physics.Kept("ambient")) << "pose " << p;
    // Coarse stripes reach only 80-94 % of white - black: scattered light, kept.
    EXPECT_TRUE(r.physics.Kept("global_light")) << "pose " << p;
    // The fit sees the board's print: dark squares a few to 15 % of the light ones.
    ASSERT_NE(r.physics.Find("albedo_dark"), nullptr);
    const double dark_ratio = r.physics.Find("albedo_dark")->value / 0.9;  // 0.068-0.108 measured
    EXPECT_GT(dark_ratio, 0.04) << "pose " << p;
    EXPECT_LT(dark_ratio, 0.15) << "pose " << p;
  }
  std::printf("%s", table.c_str());
}

}  // namespace
}  // namespace slshadow
