// Predicted coverage: before the part is on the table, which views of a rig will reconstruct which
// part of the CAD surface, and why the rest will be missed. No fringe image is rendered: every
// surface sample is tested against every device of the reconstruction mode in every view by the
// same rules the CAD comparison uses to explain the uncovered surface (cad_compare.h): the same
// area-uniform samples (compare::ReferenceFromMesh, fixed seed, so sample i here is sample i of a
// CompareWithCad with the same sample count), the same on-table rule, and per device: outside its
// image (behind it, beyond its field or outside the image after distortion), hidden (facing away
// or occluded by the part, Embree shadow rays from the sample towards the device centre), grazing
// (incidence beyond grazing_deg, or, in stereo, stereo's code-step gate max_code_step_px where the
// reconstruction applies it: a camera's 2 x 2 pixels around a rectified cell's source position
// spanning more than it in a coded projector coordinate, or the right camera's rectified row
// stepping by more than it in the projector column; at a steep view of a camera this gate, not the
// incidence, removes the surface; or a filter of the reconstruction on its reference
// grid rejecting the cell: the depth-discontinuity filter's range step to a neighbour cell, the
// statistical outlier filter's distance to the nearest cells, both on the surface's tangent plane
// and in the filters' own footprints and limits). In stereo the matcher's ambiguity too: the
// left cell's projector column crossed twice along the right camera's rectified row
// (MatchRectifiedMaps' kAmbiguousMatch) when another surface of the part on the line where the
// epipolar plane meets the projector's plane of that column is seen by the right camera and lit
// (Embree along that line; named occluded: the part itself is in the way of the match; on the
// occlusion part's overhang end seen at 45 deg, docs/benchmarks/log/
// 2026-12-07-prediction-agreement.md). A view reconstructs a sample when every device sees it
// unoccluded and not grazing and its match is unambiguous.
//
// The outlier filter decides the steep faces (~80 deg to the reference camera): its score there
// depends on the geometry alone (the prediction's score equals the reconstruction's within ~0.05
// footprints on the demo part), but a face whose score sits within the points' noise of the limit
// is kept in patches the prediction cannot call; it predicts them rejected (there the scan covers
// more than predicted): docs/benchmarks/log/2026-12-07-plan.md.
//
// The projector's light: the simulator's radiometric factor (sim/scene.h) gives the lit range a
// camera records, and the defocus layers the share of the finest fringe's modulation the
// projector's and the cameras' blur keep: below the decoder's shadow threshold the sample is too
// dark (or too blurred) to decode. A printed part (a checkerboard albedo) and a glossy one (a
// specular lobe about the projector's mirror direction) light up per sample; on a real capture
// WithCapturedRadiometry measures both from the white and black frames (checked on the kamino
// board: tests/multiview/kamino_coverage_test.cc,
// docs/benchmarks/log/2026-12-07-kamino-coverage.md).
//
// Frames and units: the part frame (views.h), mm, degrees. The prediction's report, coverage map
// and check against a scan (ToJson, Table, WriteCoverageMap, CheckPrediction) are in
// coverage_check.cc.
#pragma once

#include <array>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "core/mesh.h"
#include "core/rig.h"
#include "core/rigid3.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/reconstruct.h"
#include "sim/scene.h"
#include "workflows/multiview/cad_compare.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

// The reasons of a prediction, numbered as CoverageReason so that a sample's predicted reason and
// its reason in a scan's CAD comparison line up: kTooDark takes kNotReconstructed's place (seen by
// every device, but the predicted fringe modulation is below the decoder's threshold).
enum class PredictedReason : uint8_t {
  kReconstructed = 0,  // CoverageReason::kCovered
  kTooDark = 1,        // CoverageReason::kNotReconstructed
  kGrazing = 2,
  kOccluded = 3,
  kOutsideField = 4,
  kOnTable = 5
};
// "reconstructed", "too_dark", "grazing", "occluded", "outside_field", "on_table"
std::string ToString(PredictedReason reason);
constexpr int kNumPredictedReasons = 6;

// One camera pixel's Gray bits as a capture shows them far above the decoder's thresholds
// (WithCapturedContrast): per coded axis (x, y) |pattern - inverse| / (white - black) per bit, bit
// 0 (the finest) first, and the bits whose flip alone gives the adjacent code (the decoder reads a
// pixel with one such bit below the contrast threshold as the edge between the two codes).
struct PixelBitContrast {
  std::array<std::vector<float>, 2> ratio;
  std::array<uint32_t, 2> adjacent_bits{0, 0};
};

struct CoveragePredictionOptions {
  ReconstructMode mode = ReconstructMode::kStereo;
  size_t samples = 200000;  // CAD surface samples (CadCompareOptions::samples)
  // Incidence to a device beyond which the surface is grazing. The simulator's surfaces are
  // Lambertian and the decoder has no incidence limit of its own: at a grazing projector incidence
  // the light that reaches the surface limits it (too_dark below), at a grazing camera incidence
  // stereo's code-step gate (reconstruct below: on the occlusion part a wall the right camera sees
  // at ~88 deg is lost to it, docs/benchmarks/log/2026-12-07-grazing.md). The default only rejects
  // the last degree, where a camera pixel's footprint runs along the surface.
  double grazing_deg = 89;
  double table_tolerance_mm = 0.5;  // CadCompareOptions::table_tolerance_mm
  // The radiometry of sim/scene.h: the lit range (white - black) a camera records is
  // exposure_fraction * 255 * albedo * cos_p * (d_ref / d_p)^2 in 8-bit grey levels; below the
  // decoder's shadow_threshold (patterns/codec.h DecodeOptions) the sample is too dark.
  double albedo = 0.5;  // the part's (FromScene: the darkest part mesh)
  // A printed part (a calibration board): when textured, the albedo of a sample is
  // albedo_texture.Evaluate(x, y) at its part-frame x, y (a planar part in the part frame's z = 0
  // carries the texture as sim/scene.h prints it on a plane) and `albedo` is not used.
  Albedo albedo_texture;
  // A glossy surface (a printed board's toner, a coat): a specular lobe adds
  // gloss x exp(-tan^2(theta_h) / gloss_alpha^2) to the albedo (Beckmann's distribution), theta_h
  // the angle between the normal and the half vector of the directions to the projector and to
  // the mode's first camera; 0: Lambertian. A checkerboard albedo_texture has one per class:
  // gloss_dark and gloss_alpha_dark on its dark squares, gloss and gloss_alpha on the light ones.
  double gloss = 0, gloss_dark = 0, gloss_alpha = 0.1, gloss_alpha_dark = 0.1;
  // A checkerboard albedo_texture at one known pose (WithCapturedRadiometry): per square (index
  // a + squares_x b, square a along x from the texture's corner square 0), grey levels added to
  // the lit range of its samples (the level each square really shows; empty: none).
  std::vector<float> square_offset_dn;
  double exposure_fraction = 0.8;    // Radiometry::exposure_fraction
  double reference_distance_mm = 0;  // d_ref; 0: the rig's working distance
  double shadow_threshold = 12;      // DecodeOptions::shadow_threshold (8-bit grey levels)
  // The defocus layers (sim/scene.h SceneLayers: thin lens, Gaussian PSF of sigma px; off unless
  // enabled): the finest fringe (period fringe_period_px in the projector) keeps
  // exp(-2 pi^2 sigma^2 / period^2) of its modulation through the projector's blur, and through a
  // camera's with the period in that camera's pixels (the projector px one camera px spans along
  // a coded axis on the surface); the lit range times what the worst camera keeps is the fringe's
  // peak-to-peak against shadow_threshold (too_dark: too dark or too blurred to decode).
  SceneLayers::Defocus camera_defocus, projector_defocus;
  // The decoder at its thresholds on a real capture (internal/decode_odds.h; 0 and empty: off, the
  // mean lit range against shadow_threshold decides, as on a simulated scan whose levels are far
  // from the thresholds). pixel_noise_dn: the lit range's pixel noise (sigma, grey levels; also
  // |pattern - inverse|'s); bit_contrasts: pixels' Gray-bit contrasts per unit of lit range (the
  // stripes' edges in the pixel and the camera's and projector's blur; WithCapturedContrast).
  // With either, a sample of mean lit range L decodes per pixel with the probability p(L) that the
  // pixel's lit range k (L plus the noise, an integer) passes shadow_threshold and its bits pass
  // the contrast test at k: each bit's |pattern - inverse| is its ratio x (k - bit_global_dn)
  // plus the noise, read against contrast_threshold (an integer), and an axis passes when every
  // bit does or only one whose flip gives the adjacent code fails (patterns/codec.h; the mean over
  // the measured pixels); the statistical outlier
  // filter keeps a pixel with a decoded neighbour in its window, p (1 - (1 - p)^neighbours); a
  // sample stands for the reference camera's pixels on its share of the surface (n, from its
  // distance and incidence), so it is reconstructed with the probability 1 - (1 - kept)^n that
  // one of them is, drawn with a fixed uniform per sample and view (internal::FixedUniform of the
  // sample's index and the view's pose): deterministic,
  // and the coverage radius of a check then counts the scattered points as the scan's does. The
  // level is L per sample (the light squares' or dark squares' level, gloss included), the noise
  // per pixel: the level is not drawn independently per pixel.
  // bit_global_dn: per axis (x, y) and bit (bit 0 first), the part of a pixel's lit range that
  // bit's fringes do not modulate (empty: none).
  double pixel_noise_dn = 0;
  std::array<std::vector<double>, 2> bit_global_dn;
  double contrast_threshold = 4;  // DecodeOptions::contrast_threshold
  std::vector<PixelBitContrast> bit_contrasts;
  double fringe_period_px = 16;  // WithPatterns: the phase codecs' finest period, Gray code 4
  bool code_y = true;            // the projector's rows are coded too (PatternSpec::code_y)
  // The reconstruction's gates and filters (ProjectMergeOptions::reconstruct's defaults): stereo's
  // code-step gate max_code_step_px (0, the automatic gate: its 4 px floor), on the surface's
  // tangent plane as stereo_matcher.h applies it: RectifyProjectorMap drops a rectified cell whose
  // 2 x 2 source pixels span more than the gate in a coded projector coordinate (the span is
  // |step to the next pixel along the row| + |step along the column|), MatchRectifiedMaps does not
  // search the right camera's rectified row across a larger step of the projector column; and on
  // the reference grid (the rectified left camera in
  // stereo, the first camera in projector mode) the depth-discontinuity filter
  // (max_depth_jump_footprints: the range step to a 4-neighbour cell) and the statistical outlier
  // filter (the RMS distance to the outlier_neighbors nearest cells on the tangent plane, against
  // max(mean + outlier_std_ratio x spread, outlier_min_distance_footprints) with the mean and
  // spread over the cells the view predicts: it rejects surfaces steeper than ~80 deg).
  ReconstructOptions reconstruct = [] {
    ReconstructOptions r;
    r.report_residuals = false;
    return r;
  }();
  // Also the points each view would reconstruct (CoveragePrediction::predicted_points, for
  // CheckPrediction): every cell of the reference grid over the part ray-cast onto the CAD, the
  // hit kept by the rules above, then the reconstruction's own depth-discontinuity and outlier
  // filters (reconstruct/filters.h) run on that grid of points (a cell whose ray misses the part
  // counts as a far background for the discontinuity filter: the scan's table or nothing), and
  // points within table_tolerance_mm of the table plane dropped (the merge's table crop). Where
  // the surface is steep to the reference camera the points are farther apart than the scan's
  // coverage radius, and an edge loses the cells the filters take from it: both show in the
  // check only this way. Slower (a ray per cell); off for the plan, which counts samples.
  bool predict_points = false;
  // Also the depth-discontinuity filter at the part's own occlusion edges, by the reconstruction
  // itself: per view both cameras' projector maps ray-cast over the part (Embree, a ray per pixel;
  // lit where the projector sees the point: a noise-free decode) and ReconstructStereo
  // (ReconstructWithProjector) run on them with `reconstruct`; a sample the rules above keep whose
  // nearest cell of the reference grid that reconstruction's FilterDepthDiscontinuities rejects is
  // grazing. The rules above test the jump on each sample's tangent plane, which shows none at an
  // occlusion edge, where the filter takes a cell and its dilation on each side of the edge: about
  // the coverage radius at a coarse rig (1/4 of the demo rig). Slower (two camera images of rays
  // and a reconstruction per view): off for the plan's candidates, for its check
  // (`slshadow plan --check P --rendered`): docs/benchmarks/log/2026-12-08-prediction-edges.md.
  bool rendered_reconstruction = false;
  void Check() const;  // throws slshadow::Error naming the bad field
};
// The radiometry of `scene` (exposure fraction, reference distance, the smallest uniform albedo of
// its meshes, the part) and its defocus layers in `options`.
CoveragePredictionOptions WithSceneRadiometry(CoveragePredictionOptions options,
                                              const Scene& scene);

// The radiometry a real capture of the part records, from its all-white and all-black frames
// (what the decoder's shadow test reads): per albedo class (uniform: one; a checkerboard
// albedo_texture: its dark and its light squares), the median over the samples of that class at
// least edge_margin_mm from a square edge, inside the camera's and the projector's images and
// facing both, of (white - black) at the sample's camera pixel (nearest) divided by the
// prediction's own geometric factor cos_p * (d_ref / d_p)^2. That median is the class's
// exposure_fraction x 255 x albedo; the returned options carry it as exposure_fraction 1 and the
// class's albedo (capped at 1), with reference_distance_mm set to the d_ref used. Nothing of the
// decoded result is read: the prediction's rules then decide from this light alone.
// A glossy print shows as that ratio growing towards the mirror direction: the ratio is fitted per
// class as range_per_factor + gloss_range x exp(-tan^2(theta_h) / alpha^2) (the lobe above) by
// least squares on the medians of 20 equal-count bins of tan^2(theta_h), alpha the best of a
// log-spaced grid (0.02-1) per class; a class whose lobe comes out negative, or lifts it by less
// than one grey level at the smallest half angle measured (the frames' 8-bit step), keeps its
// median and no gloss. Where the view is far from the mirror direction the lobe is flat and the
// fit gives it no weight. Also the pixel noise of the lit range (pixel_noise_dn, below), and on a
// checkerboard each square's median offset of (white - black) from that fit (square_offset_dn).
struct CapturedRadiometry {
  double range_per_factor_dark = 0, range_per_factor_light = 0;  // grey levels (uniform: light)
  double gloss_range_dark = 0, gloss_range_light = 0;            // grey levels
  double gloss_alpha_dark = 0, gloss_alpha_light = 0;
  // The lobe at the smallest half angle measured (grey levels): what the capture shows of it;
  // gloss_range beyond that angle is an extrapolation (large and uncertain when the view is far
  // from the mirror direction, where it does not matter).
  double gloss_seen_dark = 0, gloss_seen_light = 0;
  double min_half_angle_deg = 0, max_half_angle_deg = 0;  // theta_h over the measured samples
  size_t samples_dark = 0, samples_light = 0;
  // The lit range's pixel noise per class (sigma, grey levels): 1.4826 x the median absolute step
  // of (white - black) to the next pixel along the row, / sqrt(2). The class of the lower level
  // (nearest the shadow threshold) gives pixel_noise_dn.
  double pixel_noise_dark = 0, pixel_noise_light = 0;
  // A checkerboard: the RMS over its squares of square_offset_dn (grey levels).
  double square_offset_rms = 0;
};
// `white`, `black`: the camera's 8-bit frames. Throws slshadow::Error when a class has no sample,
// the frames' size differs from the camera's or the rig has no projector.
CoveragePredictionOptions WithCapturedRadiometry(CoveragePredictionOptions options,
                                                 const TriangleMesh& part_in_part, const Rig& rig,
                                                 int camera, const Rigid3d& part_from_rig,
                                                 const cv::Mat& white, const cv::Mat& black,
                                                 double edge_margin_mm = 10,
                                                 CapturedRadiometry* measured = nullptr);

// The Gray bits' contrast per unit of lit range a real capture shows (bit_contrasts, up to 2000
// pixels evenly over the measured ones), from its raw frames (`images`: the camera's 8-bit frames
// in `spec` order; nothing decoded): on the
// samples (a checkerboard's at least edge_margin_mm from a square's edge) inside the camera's and
// the projector's images, facing both and lit at
// least 5 x the thresholds (there the ratio is the optics', the stripes' edges in the pixel and
// the blur, not the noise's), per pixel each bit's |pattern - inverse| over (white - black) (the
// figures: the decoder's weakest bit, per axis the weakest or the second weakest where flipping
// the weakest gives the adjacent code, the weaker axis). Throws slshadow::Error unless `spec`
// is a Gray code with inverse frames, or when the images do not fit the spec or the camera, or no
// sample is lit enough.
// On a part with surfaces lit below 5 x the thresholds (a board's dark squares), also per axis and
// bit the part of their lit range that bit's fringes do not modulate (bit_global_dn: veiling glare
// from the bright surface around, scatter in the print; the finer the bit, the more): the dim
// samples' mean lit range less their mean |pattern - inverse| over the bright samples' mean ratio
// of that bit, on the dim samples lit within 4 grey levels above the shadow threshold (where the
// contrast test decides) when there are 100, else on every dim sample (0 with fewer than 100).
struct CapturedContrast {
  size_t samples = 0, dim_samples = 0, threshold_samples = 0;
  double median = 0, p10 = 0;  // of the decoder's weakest bit contrast per unit of lit range
  double global_finest_dn = 0, global_coarsest_dn = 0;  // bit_global_dn of bit 0 and the top bit
};
CoveragePredictionOptions WithCapturedContrast(
    CoveragePredictionOptions options, const TriangleMesh& part_in_part, const Rig& rig, int camera,
    const Rigid3d& part_from_rig, const PatternSpec& spec, const std::vector<cv::Mat>& images,
    double edge_margin_mm = 10, CapturedContrast* measured = nullptr);

// The finest fringe of `spec` in `options` (fringe_period_px, code_y).
CoveragePredictionOptions WithPatterns(CoveragePredictionOptions options, const PatternSpec& spec);

// One view to predict: its name and true part_from_rig (VirtualViewPose for a views file).
struct PredictedViewPose {
  std::string name;
  Rigid3d part_from_rig;
};

struct PredictedView {
  std::string name;
  Rigid3d part_from_rig;
  // Samples by this view's own reason (PredictedReason order).
  std::array<size_t, kNumPredictedReasons> reason_samples{};
  double coverage = 0;  // reconstructed by this view / samples off the table
};

struct CoveragePrediction {
  std::vector<Eigen::Vector3d> sample_points;  // part frame
  std::vector<Eigen::Vector3f> sample_normals;
  // Per view and sample: PredictedReason of that view alone (see PredictedView).
  std::vector<std::vector<uint8_t>> view_reason;
  // Per sample over all views (PredictedReason): reconstructed when some view reconstructs it,
  // else the best reason of any view (too_dark, grazing, occluded, outside_field in that order,
  // as cad_compare.h ranks them), or on_table.
  std::vector<uint8_t> sample_reason;
  std::vector<uint8_t> sample_views;  // number of views reconstructing the sample (<= 255)
  // With CoveragePredictionOptions::predict_points: the points the views would reconstruct, part
  // frame (CoveragePredictor::ViewPoints), all views together.
  std::vector<Eigen::Vector3d> predicted_points;
  std::vector<PredictedView> views;
  std::array<size_t, kNumPredictedReasons> reason_samples{};
  double cad_area_mm2 = 0;
  double coverage_off_table = 0;  // covered / samples off the table
  double seconds = 0;

  size_t OffTable() const;
  nlohmann::json ToJson() const;  // figures only
  std::string Table() const;      // per view and over all views, what `slshadow plan` prints
};

// The prediction's machinery, kept for many views of one part (slshadow plan): the samples, the
// on-table mask and the ray caster are made once; View() predicts one view. Thread-compatible.
class CoveragePredictor {
 public:
  // Throws slshadow::Error as PredictCoverage.
  CoveragePredictor(const TriangleMesh& cad_in_part, const Rig& rig,
                    const std::optional<TurntableAxis>& table_axis,
                    const CoveragePredictionOptions& options = {});
  ~CoveragePredictor();
  CoveragePredictor(const CoveragePredictor&) = delete;
  CoveragePredictor& operator=(const CoveragePredictor&) = delete;
  const std::vector<Eigen::Vector3d>& Samples() const;
  const std::vector<Eigen::Vector3f>& Normals() const;
  const std::vector<uint8_t>& OnTable() const;  // 1: on the table
  double CadAreaMm2() const;
  // Per sample, the view's PredictedReason (on_table where OnTable()).
  std::vector<uint8_t> View(const Rigid3d& part_from_rig) const;
  // Per sample, the mean lit range the view's light gives it (grey levels, the fringe's through
  // the defocus layers: what the shadow threshold is compared with); NaN where a device does not
  // see the sample.
  std::vector<double> ViewLevels(const Rigid3d& part_from_rig) const;
  // The points the view would reconstruct, part frame (CoveragePredictionOptions::predict_points).
  std::vector<Eigen::Vector3d> ViewPoints(const Rigid3d& part_from_rig) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Predicts `views` of `rig` on `cad_in_part` (see the header comment). `table_axis`: the turntable
// axis (its table face is excluded as on_table), nullopt: nothing excluded. Throws slshadow::Error
// on an empty mesh, no views, a rig without the mode's devices or invalid options.
CoveragePrediction PredictCoverage(const TriangleMesh& cad_in_part, const Rig& rig,
                                   const std::vector<PredictedViewPose>& views,
                                   const std::optional<TurntableAxis>& table_axis,
                                   const CoveragePredictionOptions& options = {});

// The views of a views file at their true poses (VirtualViewPose).
std::vector<PredictedViewPose> PosesOfViews(const ViewsFile& views, const Rig& rig);

// The coverage map as a binary PLY of the surface samples (atomically): x, y, z, nx, ny, nz,
// red, green, blue (the colours of project_merge's cad_coverage.ply: reconstructed green, too
// dark red, grazing orange, occluded blue, outside the field grey, on the table black), scalars
// `reason` (PredictedReason) and `views` (how many views reconstruct the sample).
void WriteCoverageMap(const std::filesystem::path& path, const CoveragePrediction& prediction);

// The prediction against a scan's CAD comparison of the same views (same sample count, so the
// same samples). The scan counts a sample covered when a reconstructed point lies within its
// coverage radius (cad_compare.h), so a hidden sample next to a seen one is covered: the
// prediction is measured the same way, a sample predicted covered when one of the predicted
// points (predict_points), else a sample some view reconstructs, lies within the scan's
// coverage_radius_mm. A sample agrees when it is off the
// table in both and predicted covered equals covered in the scan.
struct PredictionCheck {
  size_t compared = 0;  // samples off the table
  size_t agree = 0;
  double agreement = 0;  // agree / compared
  // Disagreements by the sample's own predicted reason (PredictedReason order). A sample not
  // reconstructed itself but within the radius of one that is counts as predicted covered, so a
  // disagreement under "occluded" may be either way: predicted_not_scanned says how many of all
  // are predicted covered and not covered in the scan (the rest: covered, not predicted).
  std::array<size_t, kNumPredictedReasons> disagree_by_predicted{};
  size_t predicted_not_scanned = 0;
  double predicted_coverage = 0, scanned_coverage = 0;  // of the compared samples
  double coverage_radius_mm = 0;                        // the scan's
  std::string Summary() const;
  nlohmann::json ToJson() const;
};
// Throws slshadow::Error when the sample counts or points differ.
PredictionCheck CheckPrediction(const CoveragePrediction& prediction, const CadComparison& scan);

}  // namespace slshadow::multiview
