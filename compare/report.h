// The comparison report folder (docs/formats.md "Comparison report"):
//   report.json         statistics, registration, options, inputs (schema in docs/formats.md)
//   compared.ply        the registered compared cloud with the "deviation" scalar field and colours
//   histogram.png       deviation histogram (PLplot)
//   deviation_map.png   the compared points rendered from a camera's view, coloured by deviation
//   summary.txt         CompareResult::Summary()
// The folder is staged next to its destination and renamed into place when complete, so a
// reader never sees a half-written report.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "compare/charts.h"
#include "compare/compare.h"
#include "core/camera_model.h"
#include "core/rigid3.h"

namespace slshadow::compare {

// The view the deviation map is rendered from: a camera and its pose relative to the
// reference frame the compared cloud is expressed in after registration.
struct ViewCamera {
  CameraModel camera;
  Rigid3d cam_from_reference;
};

// A 1024 px wide pinhole view that frames the points' bounding box: looking along the smallest
// principal axis of the points from the side where the mean stored normal points (or, without
// normals, the side the origin is on, where a scanner usually is), focal length chosen so that
// every point projects inside the image with a 4 % margin.
ViewCamera FitView(const PointCloud& cloud, int width_px = 1024);

// Renders `values` (one per point) by projecting each point into the view with a z-buffer;
// each point covers a square splat of `splat_px` pixels radius (0: automatic from the point
// spacing at the median depth, up to 4 px). Pixels no point reaches are NaN. `spacing_mm`: the
// points' median spacing when the caller knows it (CompareResult::median_spacing_mm), else 0
// (measured here on 5 000 samples). Of points landing at the same depth, the first one wins.
ValueImage RenderValues(const std::vector<Eigen::Vector3d>& points,
                        const std::vector<double>& values, const ViewCamera& view, int splat_px = 0,
                        double spacing_mm = 0);

struct ReportOptions {
  std::optional<ViewCamera> view;  // default: FitView(compared cloud)
  bool overwrite = true;           // replace an existing report folder
  bool binary_ply = true;
  // compared.ply's x, y, z as float when every |coordinate| < 8192 mm (rounding <= 2^-11 mm =
  // 0.49 um, below the 1 um fidelity the report keeps; docs/formats.md), else as double.
  bool float_positions = true;
  // Called with the staged folder once every file above is in it, before the folder is renamed
  // into place (e.g. report::HtmlWriter() adds report.html); if it throws, nothing is replaced.
  std::function<void(const std::filesystem::path&)> before_commit;
};

nlohmann::json ReportJson(const CompareResult& result);

// Writes the report folder `dir` (see above). Throws slshadow::Error when it cannot be written
// (or exists and !overwrite); an existing folder is only replaced by a complete new one.
void WriteReport(const std::filesystem::path& dir, const CompareResult& result,
                 const ReportOptions& options = {});

// The whole job in one call: Compare() then WriteReport(); returns the statistics.
CompareResult CompareAndReport(const PointCloud& cloud, const Reference& reference,
                               const CompareOptions& options, const std::filesystem::path& out_dir,
                               const ReportOptions& report_options = {},
                               const std::string& cloud_source = "cloud");

}  // namespace slshadow::compare
