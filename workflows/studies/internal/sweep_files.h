// What workflows/studies/sweep.cc (plan, run), workflows/studies/sweep_job.cc (a job) and
// workflows/studies/sweep_merge.cc (merge) share: the file formats of a sweep's jobs folder and the
// study key `curves`' metrics. Included only by those three.
#pragma once

#include <nlohmann/json.hpp>

#include <filesystem>
#include <string>
#include <vector>

namespace slshadow::studies::internal {

inline constexpr const char* kPlanFormat = "slshadow-sweep-plan";
inline constexpr const char* kResultFormat = "slshadow-sweep-result";
inline constexpr int kVersion = 1;

// The figures a study's `curves` may chart and limit. Error figures break upwards (above the
// limit), coverage figures downwards.
extern const std::vector<std::string> kCurveMetrics;
bool BreaksAbove(const std::string& metric);

// "000042": a job's file name without extension.
std::string JobName(int id);
// JOBS/results/<id>.json.
std::filesystem::path ResultFile(const std::filesystem::path& jobs_dir, int id);
// Throws slshadow::Error naming the file when it cannot be read or is not JSON.
nlohmann::json ReadJsonFile(const std::filesystem::path& path);
// JOBS/plan.json, checked to be a plan of this version.
nlohmann::json ReadPlan(const std::filesystem::path& jobs_dir);

}  // namespace slshadow::studies::internal
