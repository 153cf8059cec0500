// The prediction's report (its figures as JSON, the table `slshadow plan` prints), the coverage
// map and the check of a prediction against a scan's CAD comparison (coverage_prediction.h).
#include <tbb/parallel_for.h>

#include <string>
#include <vector>

#include "core/error.h"
#include "core/kdtree.h"
#include "core/point_cloud.h"
#include "core/string_printf.h"
#include "workflows/multiview/coverage_prediction.h"
#include "workflows/multiview/internal/prediction_reasons.h"

namespace slshadow::multiview {

using internal::kCovered;
using internal::kDark;
using internal::kGrazing;
using internal::kOccluded;
using internal::kOnTable;
using internal::kOutside;
using internal::Share;

nlohmann::json CoveragePrediction::ToJson() const {
  nlohmann::json j;
  j["samples"] = sample_points.size();
  j["cad_area_mm2"] = cad_area_mm2;
  j["coverage_off_table"] = coverage_off_table;
  nlohmann::json by = nlohmann::json::object();
  for (int r = 0; r < kNumPredictedReasons; ++r)
    by[ToString(static_cast<PredictedReason>(r))] = reason_samples[static_cast<size_t>(r)];
  j["samples_by_reason"] = by;
  j["views"] = nlohmann::json::array();
  for (const PredictedView& v : views) {
    nlohmann::json view = {{"name", v.name}, {"coverage_off_table", v.coverage}};
    for (int r = 0; r < kNumPredictedReasons; ++r) {
      view["samples_by_reason"][ToString(static_cast<PredictedReason>(r))] =
          v.reason_samples[static_cast<size_t>(r)];
    }
    j["views"].push_back(std::move(view));
  }
  j["seconds"] = seconds;
  return j;
}

std::string CoveragePrediction::Table() const {
  const size_t off = OffTable();
  const auto pct = [&](size_t n) { return 100.0 * Share(n, off); };
  std::string out =
      "predicted coverage (share of the CAD surface off the table, no images rendered)\n"
      "view        reconstructed  too dark   grazing  occluded   outside\n";
  const auto row = [&](const std::string& name, const std::array<size_t, kNumPredictedReasons>& n) {
    return StringPrintf("%-10s  %10.2f %%  %6.2f %%  %6.2f %%  %6.2f %%  %6.2f %%", name.c_str(),
                        pct(n[kCovered]), pct(n[kDark]), pct(n[kGrazing]), pct(n[kOccluded]),
                        pct(n[kOutside]));
  };
  for (const PredictedView& v : views) out += row(v.name, v.reason_samples) + "\n";
  out += row("all views", reason_samples) +
         StringPrintf("   (%zu samples, %.2f s)\n", sample_points.size(), seconds);
  return out;
}

void WriteCoverageMap(const std::filesystem::path& path, const CoveragePrediction& prediction) {
  PointCloud cloud;
  cloud.points = prediction.sample_points;
  cloud.normals = prediction.sample_normals;
  cloud.colors.resize(cloud.size());
  std::vector<float> reason(cloud.size()), views(cloud.size());
  for (size_t i = 0; i < cloud.size(); ++i) {
    reason[i] = prediction.sample_reason[i];
    views[i] = prediction.sample_views[i];
    cloud.colors[i] = internal::PredictedReasonColor(prediction.sample_reason[i]);
  }
  cloud.SetScalar("reason", std::move(reason));
  cloud.SetScalar("views", std::move(views));
  PlyWriteOptions options;
  options.double_positions = false;
  WritePly(path, cloud, options);
}

PredictionCheck CheckPrediction(const CoveragePrediction& prediction, const CadComparison& scan) {
  SLSHADOW_THROW_IF(scan.sample_reason.size() != prediction.sample_reason.size() ||
                        scan.sample_points.size() != prediction.sample_points.size(),
                    "prediction check: the scan's comparison has ", scan.sample_reason.size(),
                    " samples, the prediction ", prediction.sample_reason.size(),
                    " (use the same sample count)");
  const size_t ns = prediction.sample_reason.size();
  std::vector<Eigen::Vector3d> reconstructed;
  for (size_t i = 0; i < ns; ++i) {
    SLSHADOW_THROW_IF((scan.sample_points[i] - prediction.sample_points[i]).norm() > 1e-9,
                      "prediction check: sample ", i, " differs (another CAD mesh?)");
    if (prediction.sample_reason[i] == kCovered)
      reconstructed.push_back(prediction.sample_points[i]);
  }
  // Predicted covered as the scan measures it: a predicted point (or a reconstructed sample)
  // within the radius.
  std::vector<uint8_t> covered(ns, 0);
  if (!prediction.predicted_points.empty()) {
    const KdTree tree(prediction.predicted_points);
    tbb::parallel_for(size_t{0}, ns, [&](size_t i) {
      Neighbor n;
      covered[i] = tree.Nearest(prediction.sample_points[i], &n, scan.coverage_radius_mm);
    });
  } else if (!reconstructed.empty()) {
    const KdTree tree(reconstructed);
    tbb::parallel_for(size_t{0}, ns, [&](size_t i) {
      Neighbor n;
      covered[i] = prediction.sample_reason[i] == kCovered ||
                   tree.Nearest(prediction.sample_points[i], &n, scan.coverage_radius_mm);
    });
  }
  PredictionCheck check;
  check.coverage_radius_mm = scan.coverage_radius_mm;
  size_t predicted = 0, scanned = 0;
  for (size_t i = 0; i < ns; ++i) {
    const uint8_t p = prediction.sample_reason[i];
    const auto s = static_cast<CoverageReason>(scan.sample_reason[i]);
    if (p == kOnTable || s == CoverageReason::kOnTable) continue;
    ++check.compared;
    const bool pc = covered[i] != 0, sc = s == CoverageReason::kCovered;
    predicted += pc;
    scanned += sc;
    if (pc == sc) {
      ++check.agree;
    } else {
      check.predicted_not_scanned += pc;
      ++check.disagree_by_predicted[p];
    }
  }
  check.agreement = Share(check.agree, check.compared);
  check.predicted_coverage = Share(predicted, check.compared);
  check.scanned_coverage = Share(scanned, check.compared);
  return check;
}

std::string PredictionCheck::Summary() const {
  return StringPrintf(
      "prediction against the scan: %.3f %% of %zu samples agree (predicted coverage %.2f %%, "
      "scanned %.2f %%, coverage radius %.3f mm); disagreements: predicted covered but not "
      "scanned %zu, scanned but not predicted %zu; by the sample's own predicted reason: "
      "reconstructed %zu, too dark %zu, grazing %zu, occluded %zu, outside the field %zu\n",
      100 * agreement, compared, 100 * predicted_coverage, 100 * scanned_coverage,
      coverage_radius_mm, predicted_not_scanned, compared - agree - predicted_not_scanned,
      disagree_by_predicted[kCovered], disagree_by_predicted[kDark],
      disagree_by_predicted[kGrazing], disagree_by_predicted[kOccluded],
      disagree_by_predicted[kOutside]);
}

nlohmann::json PredictionCheck::ToJson() const {
  return {{"compared", compared},
          {"agree", agree},
          {"agreement", agreement},
          {"predicted_coverage", predicted_coverage},
          {"scanned_coverage", scanned_coverage},
          {"coverage_radius_mm", coverage_radius_mm},
          {"predicted_not_scanned", predicted_not_scanned},
          {"scanned_not_predicted", compared - agree - predicted_not_scanned},
          {"disagree",
           {{"predicted_covered_not_scanned", disagree_by_predicted[kCovered]},
            {"predicted_too_dark_scanned", disagree_by_predicted[kDark]},
            {"predicted_grazing_scanned", disagree_by_predicted[kGrazing]},
            {"predicted_occluded_scanned", disagree_by_predicted[kOccluded]},
            {"predicted_outside_scanned", disagree_by_predicted[kOutside]}}}};
}

}  // namespace slshadow::multiview
