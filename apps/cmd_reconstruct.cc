// slshadow reconstruct IMAGESET --out CLOUD.ply [--rig RIG.yaml] [--mode auto|projector|stereo]
// [--method ...]
#include <CLI/CLI.hpp>
#include <cstdio>
#include <limits>

#include "apps/commands.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "reconstruct/reconstruct_image_set.h"
#include "reconstruct/strict_policy.h"
#include "reconstruct/write_reconstruction.h"

namespace slshadow::app {

int RunReconstruct(int argc, char** argv) {
  CLI::App app{
      "Reconstruct a point cloud from an ImageSet (docs/formats.md \"ImageSet\").\n\n"
      "Reads the rig and the pattern spec from IMAGESET/manifest.json, decodes every camera's "
      "fringe\n"
      "images (patterns/: projector column / row per camera pixel, with a validity reason and a\n"
      "quality), then triangulates:\n"
      "  projector  each camera against the projector (an inverse camera): ray-ray when columns "
      "and\n"
      "             rows are coded, exact ray-surface against the distorted projector when one "
      "axis is;\n"
      "             the clouds of all cameras are merged.\n"
      "  stereo     two cameras: rectified epipolar search for the equal projector column, "
      "sub-pixel\n"
      "             interpolation on the right camera's map, camera-camera triangulation.\n"
      "Gates (triangulation angle, depth range, reprojection and epipolar error) and filters "
      "(depth\n"
      "discontinuities, statistical outliers) reject cells with a reason; every count is printed.\n"
      "CLOUD.ply (binary, rig frame = first camera's frame, mm) has normals (toward the camera) "
      "and\n"
      "the scalar fields quality, u, v (source pixel), reprojection_error_px and camera (rig "
      "index);\n"
      "it is written atomically. A JSON summary (options, counts per reason, residual statistics\n"
      "median / p95 of the reprojection and epipolar errors, the calibration check, timings) goes "
      "next\n"
      "to it. The calibration check splits the epipolar error into a smooth field and the decode "
      "noise\n"
      "and warns (stderr) when the field is significant against the noise, naming its likely "
      "cause;\n"
      "with one coded axis it says on stderr what the capture cannot reveal and what would.\n"
      "With --strict a warning, a check that cannot run or too few points end the command with a\n"
      "non-zero exit before anything is written.",
      argv[0]};
  std::string imageset_dir, out_path, summary_path, rig_path, mode = "auto", method = "midpoint",
                                                              interpolation = "auto";
  ImageSetReconstructOptions options;
  StrictOptions strict;
  ReconstructOptions& r = options.reconstruct;
  bool ascii = false, no_discontinuity = false, no_outliers = false, no_normals = false,
       quiet = false;
  double max_reproj = r.max_reprojection_error_px, max_epi = r.max_epipolar_error_px;
  app.add_option("IMAGESET", imageset_dir, "ImageSet folder (holds manifest.json)")
      ->required()
      ->check(CLI::ExistingDirectory);
  app.add_option("--out", out_path, "output point cloud (.ply)")->required();
  app.add_option("--mode", mode,
                 "projector: camera-projector triangulation; stereo: two cameras; auto: projector "
                 "when the rig "
                 "has a projector, else stereo")
      ->check(CLI::IsMember({"auto", "projector", "stereo"}))
      ->capture_default_str();
  app.add_option("--rig", rig_path,
                 "rig file to use instead of the manifest's (e.g. from `slshadow calibrate "
                 "refine`); the ImageSet "
                 "is not modified, the summary records the rig used")
      ->check(CLI::ExistingFile);
  app.add_option(
         "--method", method,
         "two-view triangulation: midpoint (of the common perpendicular), dlt (linear, SVD), "
         "optimal (Lindstrom niter2: least image correction)")
      ->check(CLI::IsMember({"midpoint", "dlt", "optimal"}))
      ->capture_default_str();
  app.add_option(
         "--stereo-interpolation", interpolation,
         "stereo: resampling of the right map and sub-pixel crossing. linear (2 samples) is least "
         "noisy on decoded images; cubic (4 samples) removes the interpolation bias on smooth, "
         "noise-free maps (sub-nm on a plane) but amplifies decode noise ~1.2x; auto: cubic for "
         "exact (double) maps, linear for decoded ones")
      ->check(CLI::IsMember({"auto", "linear", "cubic"}))
      ->capture_default_str();
  app.add_option(
         "--cameras", options.cameras,
         "cameras to use (projector: any subset, default all with images; stereo: LEFT RIGHT, "
         "default the first two)")
      ->delimiter(',');
  app.add_option("--min-depth-mm", r.min_depth_mm,
                 "nearest accepted depth along the camera axis, mm")
      ->capture_default_str();
  app.add_option("--max-depth-mm", r.max_depth_mm, "farthest accepted depth, mm")
      ->capture_default_str();
  app.add_option(
         "--min-angle-deg", r.min_triangulation_angle_deg,
         "smallest accepted angle between the two rays, degrees (near-parallel rays give no depth)")
      ->capture_default_str();
  app.add_option("--max-reprojection-px", max_reproj,
                 "gate on the RMS reprojection error over both views, px (0: off)")
      ->capture_default_str();
  app.add_option(
         "--max-epipolar-px", max_epi,
         "gate on the epipolar error, projector px (projector mode with both axes coded: distance "
         "from the epipolar line; stereo: difference of the projector rows) (0: off)")
      ->capture_default_str();
  app.add_option("--min-quality", r.min_quality,
                 "reject pixels of lower decode quality (grey levels; 0: keep all)")
      ->capture_default_str();
  app.add_option("--max-code-step-px", r.max_code_step_px,
                 "stereo: no interpolation or matching across projector-coordinate steps larger "
                 "than this between neighbouring pixels, projector px; 0: automatic (for coarse "
                 "cameras and oblique surfaces), 3 x the "
                 "largest median step between decoded neighbours (per map and direction), at least "
                 "4 (the summary's code_step_gate_px)")
      ->capture_default_str();
  app.add_option("--max-code-step-ratio", r.max_code_step_ratio,
                 "stereo: nor across a smaller step larger than this many times the steps on "
                 "either side of it (a code jump: an occlusion edge, a wall's foot at grazing "
                 "incidence), and 0.5 projector px; 0: off")
      ->capture_default_str();
  app.add_flag("--no-discontinuity-filter", no_discontinuity, "keep points at depth jumps");
  app.add_option(
         "--max-depth-jump", r.max_depth_jump_footprints,
         "depth jump between neighbouring pixels that marks a discontinuity, in pixel footprints "
         "(range / focal length)")
      ->capture_default_str();
  app.add_option("--discontinuity-dilation-px", r.discontinuity_dilation_px,
                 "also reject this many pixels around a jump")
      ->capture_default_str();
  app.add_flag("--no-outlier-filter", no_outliers, "skip statistical outlier removal");
  app.add_option(
         "--outlier-std-ratio", r.outlier_std_ratio,
         "reject points whose mean neighbour distance exceeds mean + ratio x std over the cloud")
      ->capture_default_str();
  app.add_flag("--no-normals", no_normals, "do not estimate normals");
  app.add_option("--shadow-threshold", options.decode.shadow_threshold,
                 "decoding: minimum lit range (8-bit grey levels)")
      ->capture_default_str();
  app.add_option("--contrast-threshold", options.decode.contrast_threshold,
                 "decoding: minimum Gray-code bit contrast (8-bit grey levels)")
      ->capture_default_str();
  app.add_option("--calibration-warning-px", r.calibration_warning_px,
                 "calibration check: warn when the systematic part of the epipolar error (a smooth "
                 "field fitted to "
                 "it) exceeds this, projector px. 0: automatic, --calibration-noise-factor x the "
                 "decode noise of "
                 "this capture (at least 0.01 px); inf: report only. Residual maps are written "
                 "next to the cloud")
      ->capture_default_str();
  app.add_option("--calibration-noise-factor", r.calibration_noise_factor,
                 "calibration check: the automatic threshold in units of the decode noise")
      ->capture_default_str();
  app.add_option("--summary", summary_path,
                 "summary JSON path (default: CLOUD with .summary.json)");
  app.add_flag("--ascii", ascii, "write ASCII PLY instead of binary");
  app.add_flag("--quiet", quiet, "print only the one-line summaries");
  AddStrictOptions(&app, &strict);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }
  const ImageSet image_set = ImageSet::Open(imageset_dir);
  const Rig rig = rig_path.empty() ? image_set.rig() : LoadRig(rig_path);
  options.mode = mode == "auto" ? DefaultReconstructMode(rig) : ReconstructModeFromString(mode);
  r.method = TriangulationMethodFromString(method);
  r.stereo_interpolation = StereoInterpolationFromString(interpolation);
  const double inf = std::numeric_limits<double>::infinity();
  r.max_reprojection_error_px = max_reproj > 0 ? max_reproj : inf;
  r.max_epipolar_error_px = max_epi > 0 ? max_epi : inf;
  r.filter_depth_discontinuities = !no_discontinuity;
  r.filter_outliers = !no_outliers;
  r.estimate_normals = !no_normals;
  options.Check();

  const ImageSetReconstruction rec = ReconstructImageSet(image_set, options, rig);
  for (const auto& w : rec.Warnings()) std::fprintf(stderr, "slshadow: warning: %s\n", w.c_str());
  for (const auto& n : rec.Notices()) std::fprintf(stderr, "slshadow: note: %s\n", n.c_str());
  EnforceStrict(rec.summaries, strict, "reconstruct " + imageset_dir);
  ReconstructionOutputOptions output;
  output.cloud_path = out_path;
  output.summary_path = summary_path;
  output.binary_ply = !ascii;
  output.imageset = imageset_dir;
  output.rig_file = rig_path;
  const ReconstructionOutputs written = WriteReconstruction(rec, options, rig, output);
  if (quiet) {
    for (const auto& s : rec.summaries) {
      std::printf("%s\n", s.BriefReport().c_str());
      if (!s.calibration_check.warn) std::printf("%s\n", s.calibration_check.Message().c_str());
    }
  } else {
    std::printf("%s", rec.FullReport().c_str());
  }
  if (!rig_path.empty())
    std::printf("rig: %s (--rig; the manifest's rig was not used)\n", rig_path.c_str());
  std::printf("wrote %s (%zu points) and %s\n", out_path.c_str(), rec.cloud.size(),
              written.summary.string().c_str());
  return 0;
}

}  // namespace slshadow::app
