// Study 4: scan uncertainty by Monte Carlo, as a sweep (workflows/studies/sweep.h). The study key
// `monte_carlo` (docs/formats.md "Study YAML", docs/studies/uncertainty_quick/README.md) makes an
// implicit first axis `sample`: each job renders the scene with the true rig and its own sensor
// noise seed, and decodes and reconstructs it with a rig sampled from the calibration's
// uncertainty (the rig file's intrinsics covariance when it carries one, calib's
// `intrinsics_covariance`; else the study's per-parameter standard deviations; device poses from
// the study's rotation and translation standard deviations). Jobs are of two independent sets
// with their own seeds: the prediction set, whose spread per pixel is the standard uncertainty,
// and the replicate set, repeated simulated scans that check it (the share of replicate points
// within 2 predicted sigmas of the prediction's mean: 2-sigma coverage).
//
// Per job, the first mode's dense grid (projector mode: the first camera's pixels) is kept next to
// its result as NNNNNN.grid.npy (float32, rows x cols x 3, rig frame mm, NaN where no point).
#pragma once

#include "core/rig.h"

#include <nlohmann/json.hpp>

#include <array>
#include <cstdint>
#include <filesystem>
#include <string>
#include <vector>

namespace slshadow {
class ConfigNode;
struct DenseGrid;
}  // namespace slshadow

namespace slshadow::studies {

// Standard deviations of the rig's parameters where the rig carries no covariance.
struct RigSigma {
  std::array<double, 9> camera{};     // fx fy cx cy k1 k2 p1 p2 k3 (px, px, px, px, 1, ...)
  std::array<double, 9> projector{};  // the same for the projector
  double rotation_deg = 0;            // per axis, of every device but the first camera
  double translation_mm = 0;          // per axis, of every device but the first camera
};

// A rig drawn from the uncertainty: each device's intrinsics perturbed by N(0, covariance of the
// rig's calibration evidence, when it has one for that device by name) or N(0, diag(sigma^2)),
// each pose but the first camera's (the rig frame) by a rotation of N(0, rotation_deg^2) per
// axis and a translation of N(0, translation_mm^2) per axis. Deterministic in `seed`.
// `used_covariance` (optional) is set to the devices whose covariance came from the evidence.
Rig SampleRig(const Rig& rig, const RigSigma& sigma, uint64_t seed,
              std::vector<std::string>* used_covariance = nullptr);

struct MonteCarloStudy {
  int samples = 0, replicates = 0;
  uint64_t seed = 1;
  RigSigma sigma;
  std::vector<std::string> covariance_devices;  // devices sampled from the evidence's covariance
  // Per job (samples, then replicates): the job's `monte_carlo` entry: {sample, set, noise_seed,
  // reconstruct_rig}.
  std::vector<nlohmann::json> jobs;
  nlohmann::json ToJson() const;  // what the plan records
};

// Reads the study key `monte_carlo` for `rig`. Throws slshadow::Error naming file, field, value.
MonteCarloStudy MonteCarloStudyFromConfig(const ConfigNode& node, const Rig& rig);

// The grid file of job `id` in a jobs folder, and writing one (atomically).
std::filesystem::path MonteCarloGridFile(const std::filesystem::path& jobs_dir, int id);
void WriteMonteCarloGrid(const std::filesystem::path& file, const DenseGrid& grid);

// Per pixel valid in every job of both sets: u = the standard deviation (n - 1) of the prediction
// set's range (distance from the grid's viewpoint) and its mean point; coverage = the share of
// (pixel, replicate) whose range is within 2 u of the prediction's mean range. Writes at
// `out_dir`: uncertainty.ply (the mean points with the scalar field u_mm), uncertainty.png
// (the map of u over the grid), uncertainty.csv (per pixel: row, col, mean point, u_mm, the
// replicate's spread), uncertainty_summary.csv. `ids` are the job ids in plan order, `sets` each
// job's set. Returns the lines the command prints.
std::vector<std::string> WriteMonteCarloResults(const std::filesystem::path& jobs_dir,
                                                const std::filesystem::path& out_dir,
                                                const std::vector<int>& ids,
                                                const std::vector<std::string>& sets,
                                                const nlohmann::json& viewpoint,
                                                const std::string& study);

}  // namespace slshadow::studies
