// The coverage prediction against a real capture (issue 33): on the five poses of
// ../shared/data/kamino-procam-graycode (one camera, one projector, OpenCV Gray code on a printed
// 9 x 7 chessboard), the board area the prediction says the camera-projector reconstruction will
// cover agrees with the area the real reconstruction (ReconstructFromImages, what `slshadow
// reconstruct` runs, at its default decode and reconstruct options) covers, within 2 % of the
// board on each pose.
//
// The part: the board's 10 x 8 squares of 75 mm (the target spec) as a rectangle in the board
// frame, at the pose the board detection gives (calib's DetectTarget on the white frame,
// cv::solvePnP with the rig's camera), printed with its checkerboard. The rig: slshadow's own
// calibration of the set (tests/reconstruct/data/kamino_slshadow_rig.yaml). The light: measured
// from the pose's own white and black frames (WithCapturedRadiometry: the lit range of the dark
// and of the light squares away from their edges, over the prediction's geometric factor, as a
// Lambertian level plus a gloss lobe about the projector's mirror direction, each square's offset
// from it and the pixel noise) and the Gray bits' contrast per unit of lit range from the raw
// pattern frames (WithCapturedContrast: the bright pixels' bits, the dim pixels' mean contrast per
// bit); nothing of the decoded result enters the prediction. On pose 0 the contrast is also
// taken from other poses' captures (the rig's, not the pose's own frames).
//
// The measure: the project's own coverage (CompareWithCad on the board: a board sample is covered
// when a reconstructed point within kThresholdMm of the board plane lies within the coverage
// radius of it), and the prediction measured the same way (CheckPrediction: a sample is
// predicted covered when a predicted-reconstructed sample lies within that radius).
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <map>
#include <string>
#include <vector>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "calib/target.h"
#include "compare/compare.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/projector_map.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct_image_set.h"
#include "sim/simulate.h"
#include "tests/testing/temp_dir.h"
#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/coverage_prediction.h"
#include "workflows/multiview/internal/decode_odds.h"

namespace slshadow::multiview {
namespace {

constexpr size_t kSamples = 200000;
// Points of this calibration lie 0.7-2.0 mm (median), 2.0-4.6 mm (p95) off the board plane
// (tests/reconstruct/reconstruct_image_set_test.cc): whole projector pixels at 3-3.7 m.
constexpr double kThresholdMm = 10;

// The board's pose in the rig frame from its corners in the white frame.
std::optional<Rigid3d> BoardFromRig(const TargetSpec& target, const Rig& rig,
                                    const cv::Mat& white) {
  const TargetDetection det = DetectTarget(target, white);
  if (!det.found) return std::nullopt;
  const std::vector<Eigen::Vector3d> board = BoardPoints(target);
  std::vector<cv::Point3d> object;
  std::vector<cv::Point2d> image;
  for (size_t k = 0; k < det.pixels_px.size(); ++k) {
    const Eigen::Vector3d& b = board[static_cast<size_t>(det.point_ids[k])];
    object.emplace_back(b.x(), b.y(), b.z());
    image.emplace_back(det.pixels_px[k].x(), det.pixels_px[k].y());
  }
  const CameraModel& m = rig.cameras[0].model;
  const cv::Mat K = (cv::Mat_<double>(3, 3) << m.fx(), 0, m.cx(), 0, m.fy(), m.cy(), 0, 0, 1);
  const cv::Mat dist = (cv::Mat_<double>(5, 1) << m.k1(), m.k2(), m.p1(), m.p2(), m.k3());
  cv::Mat rvec, tvec, R;
  if (!cv::solvePnP(object, image, K, dist, rvec, tvec)) return std::nullopt;
  cv::Rodrigues(rvec, R);
  Eigen::Matrix3d rot;
  Eigen::Vector3d t;
  for (int i = 0; i < 3; ++i) {
    t(i) = tvec.at<double>(i);
    for (int j = 0; j < 3; ++j) rot(i, j) = R.at<double>(i, j);
  }
  const Rigid3d cam_from_board(Eigen::Quaterniond(rot), t);
  return (rig.cameras[0].cam_from_rig.Inverse() * cam_from_board).Inverse();
}

// The shared kamino captures (../shared/data) and what this project keeps for them: the pattern
// spec, the board, slshadow's own calibration of the set.
struct KaminoSet {
  std::filesystem::path dir;
  PatternSpec spec;
  TargetSpec target;
  Rig rig;
  // The camera's frames of one pose, in the pattern order (graycode_00.png ...).
  std::vector<cv::Mat> Frames(int pose) const {
    std::vector<cv::Mat> frames;
    for (int k = 0; k < spec.NumImages(); ++k) {
      char name[32];
      std::snprintf(name, sizeof(name), "graycode_%02d.png", k);
      frames.push_back(ReadGrayImage(dir / ("capture_" + std::to_string(pose)) / name));
    }
    return frames;
  }
};
KaminoSet LoadKaminoSet() {
  return {testing::SharedDataDir() / "kamino-procam-graycode",
          LoadPatternSpec(testing::SourceDir() / "config/patterns/kamino_opencv_graycode.yaml"),
          LoadTargetSpec(testing::SourceDir() / "config/targets/kamino-procam-graycode.yaml"),
          LoadRig(testing::SourceDir() / "tests/reconstruct/data/kamino_slshadow_rig.yaml")};
}

// The board's squares (inner corner (c, r) at (75 c, 75 r, 0)) as two triangles facing the
// camera.
TriangleMesh BoardMesh(const TargetSpec& target, const Eigen::Vector3d& camera_in_board) {
  const double sq = target.square_size_mm;
  const double x0 = -sq, y0 = -sq, x1 = target.cols * sq, y1 = target.rows * sq;
  TriangleMesh mesh;
  mesh.vertices = {{x0, y0, 0}, {x1, y0, 0}, {x1, y1, 0}, {x0, y1, 0}};
  mesh.triangles = {{0, 1, 2}, {0, 2, 3}};
  if (mesh.FaceNormal(0).dot(camera_in_board) < 0) mesh.triangles = {{0, 2, 1}, {0, 3, 2}};
  return mesh;
}

TEST(KaminoCoverageTest, PredictedBoardAreaAgreesWithTheReconstructionOnEveryPose) {
  const KaminoSet set = LoadKaminoSet();
  ASSERT_TRUE(std::filesystem::exists(set.dir / "capture_0")) << "no shared data at " << set.dir;
  const PatternSpec& spec = set.spec;
  const TargetSpec& target = set.target;
  const Rig& rig = set.rig;
  const ImageSetReconstructOptions recon;  // slshadow reconstruct's defaults

  // The light measured per pose (per unit of the prediction's geometric factor, at d_ref): the
  // squares of the corner square's parity (light on this board) and the others (dark), each
  // Lambertian + its gloss lobe at the smallest half angle of the board.
  std::string table =
      "pose  distance  half angle      corner sq. + gloss  other sq. + gloss    predicted  "
      "reconstructed  difference (% of the board)\n";
  for (int pose = 0; pose < 5; ++pose) {
    SCOPED_TRACE("pose " + std::to_string(pose));
    std::map<std::string, std::vector<cv::Mat>> images;
    images["camera"] = set.Frames(pose);
    const cv::Mat& white = images["camera"][40];
    const cv::Mat& black = images["camera"][41];
    const auto board_from_rig = BoardFromRig(target, rig, white);
    ASSERT_TRUE(board_from_rig.has_value());
    const Eigen::Vector3d camera_in_board = *board_from_rig * rig.cameras[0].CenterInRig();
    const TriangleMesh board = BoardMesh(target, camera_in_board);

    // The prediction: no image rendered, the light from the white and black frames.
    CoveragePredictionOptions options;
    options.mode = ReconstructMode::kProjector;
    options.samples = kSamples;
    options.reconstruct = recon.reconstruct;
    options.shadow_threshold = recon.decode.shadow_threshold;
    options.albedo_texture.kind = Albedo::Kind::kCheckerboard;
    options.albedo_texture.square_mm = target.square_size_mm;
    options.albedo_texture.squares_x = target.cols + 1;
    options.albedo_texture.squares_y = target.rows + 1;
    options = WithPatterns(options, spec);
    const double distance_mm = camera_in_board.norm();
    // 3 camera pixel footprints at the board (CadCompareOptions' automatic radius is 3 x the
    // cloud's median spacing, but at least the threshold).
    const double radius_mm = 3 * distance_mm / rig.cameras[0].model.fx();
    CapturedRadiometry light;
    options =
        WithCapturedRadiometry(options, board, rig, 0, *board_from_rig, white, black, 10, &light);
    CapturedContrast contrast;
    options = WithCapturedContrast(options, board, rig, 0, *board_from_rig, spec, images["camera"],
                                   10, &contrast);
    std::printf(
        "pose %d: pixel noise dark %.2f light %.2f DN; bit contrast per lit range median "
        "%.3f p10 %.3f (%zu samples); global %.2f - %.2f DN; squares' offsets %.2f DN RMS\n",
        pose, light.pixel_noise_dark, light.pixel_noise_light, contrast.median, contrast.p10,
        contrast.samples, contrast.global_finest_dn, contrast.global_coarsest_dn,
        light.square_offset_rms);
    const CoveragePrediction prediction = PredictCoverage(
        board, rig, {{"pose " + std::to_string(pose), *board_from_rig}}, std::nullopt, options);
    std::printf("%s", prediction.Table().c_str());

    // The real reconstruction and its coverage of the board.
    const ImageSetReconstruction rec = ReconstructFromImages(rig, spec, images, recon);
    ASSERT_GT(rec.cloud.size(), 100000u);
    PointCloud in_board = rec.cloud;
    for (auto& p : in_board.points) p = *board_from_rig * p;
    for (auto& n : in_board.normals)
      n = (board_from_rig->rotation * n.cast<double>()).cast<float>();
    CadCompareOptions cad;
    cad.samples = kSamples;
    cad.threshold_mm = kThresholdMm;
    cad.coverage_radius_mm = radius_mm;
    const CadComparison scan =
        CompareWithCad(board, rig, ReconstructMode::kProjector,
                       {{"pose", *board_from_rig, &rec.cloud}}, in_board, std::nullopt, cad);
    const PredictionCheck check = CheckPrediction(prediction, scan);
    if (pose == 0) {
      // The bits' contrast is the rig's (the stripes' edges in a pixel, the blur) at a viewing
      // geometry, not something read off the answer: pose 0 predicted with the contrast measured
      // on another capture of the same rig at a similar incidence (poses 2-4, 21-42 deg from the
      // projector's mirror direction) agrees as well. Pose 1 (52-60 deg) is no stand-in: its
      // finest stripes span fewer camera pixels (contrast per lit range 0.35 against pose 0's
      // 0.60), and pose 0 predicted with it is 12 % short.
      for (const int other : {2, 3, 4}) {
        SCOPED_TRACE("contrast measured on pose " + std::to_string(other));
        const std::vector<cv::Mat> frames = set.Frames(other);
        const auto other_from_rig = BoardFromRig(target, rig, frames[40]);
        ASSERT_TRUE(other_from_rig.has_value());
        const TriangleMesh other_board =
            BoardMesh(target, *other_from_rig * rig.cameras[0].CenterInRig());
        const CoveragePredictionOptions measured =
            WithCapturedContrast(options, other_board, rig, 0, *other_from_rig, spec, frames, 10);
        CoveragePredictionOptions transferred = options;
        transferred.bit_contrasts = measured.bit_contrasts;
        transferred.bit_global_dn = measured.bit_global_dn;
        const PredictionCheck other_check = CheckPrediction(
            PredictCoverage(board, rig, {{"pose 0", *board_from_rig}}, std::nullopt, transferred),
            scan);
        const double other_diff = other_check.predicted_coverage - other_check.scanned_coverage;
        std::printf("pose 0 with the contrast of pose %d: %+.2f %% of the board\n", other,
                    100 * other_diff);
        // Measured: -1.50 / -1.26 / -1.43 % (pose 0's own: -1.27 %).
        EXPECT_LT(std::abs(other_diff), 0.02) << other_check.Summary();
      }
    }
    std::printf("%s", check.Summary().c_str());
    const double diff = check.predicted_coverage - check.scanned_coverage;
    char line[256];
    std::snprintf(
        line, sizeof(line),
        "%4d  %6.0f mm  %5.1f-%4.1f deg  %6.1f + %4.1f   %5.1f + %4.1f DN      %6.2f %%     "
        "%6.2f %%    %+6.2f %%\n",
        pose, distance_mm, light.min_half_angle_deg, light.max_half_angle_deg,
        light.range_per_factor_dark, light.gloss_seen_dark, light.range_per_factor_light,
        light.gloss_seen_light, 100 * check.predicted_coverage, 100 * check.scanned_coverage,
        100 * diff);
    table += line;
    // The goal: within 2 % of the board, on every pose. Pose 0's dark squares sit at the
    // decoder's shadow threshold (the glossy print 8.5-19 deg from the projector's mirror
    // direction): there the decoder's odds decide (the pixel noise on the shadow and contrast
    // tests, the bits' contrast with the part of the lit range they do not modulate, each square's
    // own level, the outlier filter's decoded neighbour, the coverage radius;
    // docs/benchmarks/log/2026-12-07-kamino-pose0.md). Measured: -1.3 % on pose 0 (-8.6 % on the
    // mean level alone), -1.9 to +0.8 % on poses 1-4.
    EXPECT_LT(std::abs(diff), 0.02) << check.Summary();
  }
  std::printf("%s", table.c_str());
}

// The oracle of the per-pixel odds (internal/decode_odds.h): on pose 0, whose dark squares lie at
// the shadow threshold, the decoder's own verdict (DecodePatterns at slshadow reconstruct's
// options) per pixel of the dark squares away from their edges, binned by the pixel's lit range
// read (white - black), against the odds at the level the prediction's light gives the pixel's
// sample (CoveragePredictor::ViewLevels: the light of WithCapturedRadiometry and
// WithCapturedContrast): per pixel P(read k | level) x the contrast test at the level, averaged
// per bin with P(read k | level) as the weight.
TEST(KaminoCoverageTest, PerPixelOddsMatchTheDecoderAtTheThreshold) {
  const KaminoSet set = LoadKaminoSet();
  ASSERT_TRUE(std::filesystem::exists(set.dir / "capture_0")) << "no shared data at " << set.dir;
  const PatternSpec& spec = set.spec;
  const TargetSpec& target = set.target;
  const Rig& rig = set.rig;
  const ImageSetReconstructOptions recon;
  const std::vector<cv::Mat> images = set.Frames(0);
  const cv::Mat& white = images[40];
  const cv::Mat& black = images[41];
  const auto board_from_rig = BoardFromRig(target, rig, white);
  ASSERT_TRUE(board_from_rig.has_value());
  const TriangleMesh board = BoardMesh(target, *board_from_rig * rig.cameras[0].CenterInRig());
  CoveragePredictionOptions options;
  options.mode = ReconstructMode::kProjector;
  options.samples = kSamples;
  options.shadow_threshold = recon.decode.shadow_threshold;
  options.contrast_threshold = recon.decode.contrast_threshold;
  options.albedo_texture.kind = Albedo::Kind::kCheckerboard;
  options.albedo_texture.square_mm = target.square_size_mm;
  options.albedo_texture.squares_x = target.cols + 1;
  options.albedo_texture.squares_y = target.rows + 1;
  options = WithCapturedRadiometry(options, board, rig, 0, *board_from_rig, white, black);
  CapturedContrast contrast;
  options =
      WithCapturedContrast(options, board, rig, 0, *board_from_rig, spec, images, 10, &contrast);
  const internal::DecodeOdds odds(options.shadow_threshold, options.pixel_noise_dn,
                                  options.bit_global_dn, options.contrast_threshold,
                                  options.bit_contrasts);
  const CoveragePredictor predictor(board, rig, std::nullopt, options);
  const std::vector<double> levels = predictor.ViewLevels(*board_from_rig);
  const ProjectorMap map = DecodePatterns(spec, images, recon.decode);
  const Albedo& t = options.albedo_texture;
  const double low = std::min(t.dark, t.light);
  const Rigid3d rig_from_board = board_from_rig->Inverse();
  const double sigma = options.pixel_noise_dn;
  const auto normal_cdf = [](double x) { return 0.5 * std::erfc(-x / std::sqrt(2.0)); };
  // Per lit range read (white - black): pixels, decoded, and the odds' expectation (the pixel's
  // level L from the prediction's light, P(read k | L) x the contrast test at L, summed).
  struct Bin {
    int pixels = 0, decoded = 0;
    double weight = 0, expected = 0;
  };
  std::map<int, Bin> bins;
  std::map<int, double> contrast_at;
  std::vector<uint8_t> seen(static_cast<size_t>(white.rows) * static_cast<size_t>(white.cols), 0);
  const std::vector<Eigen::Vector3d>& samples = predictor.Samples();
  for (size_t i = 0; i < samples.size(); ++i) {
    const Eigen::Vector3d& p = samples[i];
    const double sq = t.square_mm;
    const double ex = std::abs(p.x() / sq - std::round(p.x() / sq)) * sq;
    const double ey = std::abs(p.y() / sq - std::round(p.y() / sq)) * sq;
    if (std::min(ex, ey) < 10 || t.Evaluate(p.x(), p.y()) != low || !std::isfinite(levels[i]))
      continue;
    const auto px =
        rig.cameras[0].model.Project(rig.cameras[0].cam_from_rig * (rig_from_board * p));
    if (!px) continue;
    const int u = static_cast<int>(std::lround(px->x()));
    const int v = static_cast<int>(std::lround(px->y()));
    if (u < 0 || v < 0 || u >= white.cols || v >= white.rows) continue;
    const size_t idx =
        static_cast<size_t>(v) * static_cast<size_t>(white.cols) + static_cast<size_t>(u);
    if (seen[idx]) continue;
    seen[idx] = 1;
    const int range = white.at<uint8_t>(v, u) - black.at<uint8_t>(v, u);
    Bin& b = bins[range];
    ++b.pixels;
    b.decoded += map.status.at<uint8_t>(v, u) == static_cast<uint8_t>(PixelStatus::kValid);
    const double level = levels[i];
    const double w =
        normal_cdf((range + 0.5 - level) / sigma) - normal_cdf((range - 0.5 - level) / sigma);
    b.weight += w;
    if (range >= options.shadow_threshold) {
      // The contrast test at the level, memoised per 0.05 grey level (every measured pixel's bits).
      const auto key = static_cast<int>(std::lround(level * 20));
      auto it = contrast_at.find(key);
      if (it == contrast_at.end())
        it = contrast_at.emplace(key, odds.ContrastPass(key / 20.0)).first;
      b.expected += w * it->second;
    }
  }
  std::printf("pixel noise %.2f DN, bits' unmodulated part %.2f (finest) - %.2f DN (coarsest)\n",
              sigma, contrast.global_finest_dn, contrast.global_coarsest_dn);
  std::printf("lit range  pixels  decoded  odds\n");
  for (const auto& [range, b] : bins) {
    if (b.pixels < 200) continue;
    const double decoded = static_cast<double>(b.decoded) / b.pixels;
    const double expected = b.weight > 0 ? b.expected / b.weight : 0;
    std::printf("%6d DN  %6d  %6.1f %%  %6.1f %%\n", range, b.pixels, 100 * decoded,
                100 * expected);
    // Measured: 0 below the threshold, 55 / 73 / 87 / 96 % at 12 / 13 / 14 / 15 DN; the odds
    // 58 / 81 / 95 / 99 %.
    if (range < options.shadow_threshold) {
      EXPECT_EQ(b.decoded, 0) << range << " DN";
      EXPECT_EQ(expected, 0) << range << " DN";
    } else if (b.pixels >= 1000) {
      EXPECT_NEAR(expected, decoded, 0.1) << range << " DN";
    }
  }
  ASSERT_GT(bins[12].pixels, 1000);  // pose 0's dark squares do lie at the threshold
}

// Bad input to WithCapturedContrast: one message naming what is wrong, nothing returned.
TEST(KaminoCoverageTest, CapturedContrastNamesBadInput) {
  const KaminoSet set = LoadKaminoSet();
  ASSERT_TRUE(std::filesystem::exists(set.dir / "capture_0")) << "no shared data at " << set.dir;
  const PatternSpec& spec = set.spec;
  const TargetSpec& target = set.target;
  const Rig& rig = set.rig;
  const std::vector<cv::Mat> images = set.Frames(0);
  const auto board_from_rig = BoardFromRig(target, rig, images[40]);
  ASSERT_TRUE(board_from_rig.has_value());
  const TriangleMesh board = BoardMesh(target, *board_from_rig * rig.cameras[0].CenterInRig());
  const auto message = [&](const PatternSpec& s, const std::vector<cv::Mat>& ims) -> std::string {
    try {
      WithCapturedContrast({}, board, rig, 0, *board_from_rig, s, ims);
    } catch (const Error& e) {
      return e.what();
    }
    return "no error";
  };
  std::vector<cv::Mat> fewer(images.begin(), images.end() - 1);
  EXPECT_NE(message(spec, fewer).find("41 images for a pattern spec of 42"), std::string::npos)
      << message(spec, fewer);
  PatternSpec phase = spec;
  phase.kind = PatternKind::kPhaseShift;
  EXPECT_NE(
      message(phase, images).find("must be a Gray code with inverse frames (got phase_shift)"),
      std::string::npos)
      << message(phase, images);
  std::vector<cv::Mat> small = images;
  cv::resize(images[3], small[3], cv::Size(640, 512));
  EXPECT_NE(message(spec, small).find("8-bit grey images of camera 'camera' (1280 x 1024)"),
            std::string::npos)
      << message(spec, small);
  EXPECT_EQ(message(spec, images), "no error");
}

// The oracle of the light measured from a capture: the simulator's own radiometry (sim/scene.h,
// Lambertian: exposure_fraction x 255 x albedo x cos_p x (d_ref / d_p)^2). A virtual kamino board
// (dark 0.06, light 0.9, exposure 0.5) at pose 0's geometry, its white and black frames rendered:
// WithCapturedRadiometry gives back 0.5 x 255 x the albedo of each class (within the 8-bit
// quantisation) and no gloss, although pose 0 is the one near the mirror direction.
TEST(KaminoCoverageTest, TheMeasuredLightIsTheSimulatorsOnAVirtualBoard) {
  const KaminoSet set = LoadKaminoSet();
  ASSERT_TRUE(std::filesystem::exists(set.dir / "capture_0")) << "no shared data at " << set.dir;
  const auto& dir = set.dir;
  const TargetSpec& target = set.target;
  const Rig& rig = set.rig;
  const auto board_from_rig =
      BoardFromRig(target, rig, ReadGrayImage(dir / "capture_0/graycode_40.png"));
  ASSERT_TRUE(board_from_rig.has_value());
  const double sq = target.square_size_mm;
  Scene scene;
  scene.name = "virtual kamino board";
  scene.radiometry.exposure_fraction = 0.5;
  SceneObject o;
  o.name = "board";
  o.type = ObjectType::kPlane;
  o.size_mm = Eigen::Vector3d((target.cols + 1) * sq + 70, (target.rows + 1) * sq + 70, 0);
  o.albedo.kind = Albedo::Kind::kCheckerboard;
  o.albedo.square_mm = sq;
  o.albedo.squares_x = target.cols + 1;
  o.albedo.squares_y = target.rows + 1;
  o.albedo.dark = 0.06;
  o.albedo.light = 0.9;
  const Eigen::Vector3d centre((target.cols - 1) * sq / 2, (target.rows - 1) * sq / 2, 0);
  o.albedo_offset_mm = centre.head<2>();
  o.rig_from_object = board_from_rig->Inverse() * Rigid3d(Eigen::Quaterniond::Identity(), centre);
  scene.objects.push_back(o);
  const cv::Mat white(768, 1024, CV_8UC1, cv::Scalar(255)),
      black(768, 1024, CV_8UC1, cv::Scalar(0));
  const auto images = RenderScan(scene, rig, {white, black});
  const TriangleMesh board = BoardMesh(target, *board_from_rig * rig.cameras[0].CenterInRig());
  CoveragePredictionOptions options;
  options.mode = ReconstructMode::kProjector;
  options.albedo_texture = o.albedo;
  CapturedRadiometry light;
  WithCapturedRadiometry(options, board, rig, 0, *board_from_rig, images[0][0], images[0][1], 10,
                         &light);
  std::printf("measured: dark %.2f (+ %.2f gloss) light %.2f (+ %.2f gloss) DN; truth %.2f, %.2f\n",
              light.range_per_factor_dark, light.gloss_seen_dark, light.range_per_factor_light,
              light.gloss_seen_light, 0.5 * 255 * 0.06, 0.5 * 255 * 0.9);
  EXPECT_NEAR(light.range_per_factor_dark + light.gloss_seen_dark, 0.5 * 255 * 0.06, 0.6);
  EXPECT_NEAR(light.range_per_factor_light + light.gloss_seen_light, 0.5 * 255 * 0.9, 1.0);
  EXPECT_LT(light.gloss_seen_dark, 0.6);
  EXPECT_LT(light.gloss_seen_light, 1.0);
}

}  // namespace
}  // namespace slshadow::multiview
