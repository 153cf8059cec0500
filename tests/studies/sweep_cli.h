// The sweep as a user runs it from a shell: `slshadow sweep plan`, the shards of `sweep run`
// through GNU parallel, `sweep merge`. For tests that compare that path with the in-process one.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <string>

namespace slshadow::testing {

// Plans `study` into `jobs` with the slshadow binary at `binary`, runs shard I/N for each I in
// `shard_order` (e.g. "2 0 1", a permutation of 0..N-1) through GNU parallel (-j 2) and merges
// into `result`. Returns the first command that failed, or "" when all succeeded.
inline std::string SweepThroughGnuParallel(const std::string& binary,
                                           const std::filesystem::path& study,
                                           const std::filesystem::path& jobs,
                                           const std::filesystem::path& result,
                                           const std::string& shard_order, int shards) {
  const std::string commands[] = {
      binary + " sweep plan " + study.string() + " --out " + jobs.string() + " > /dev/null",
      "parallel --will-cite --halt now,fail=1 -j 2 " + binary + " sweep run " + jobs.string() +
          " --shard {}/" + std::to_string(shards) + " ::: " + shard_order + " > /dev/null",
      binary + " sweep merge " + jobs.string() + " --out " + result.string() + " > /dev/null"};
  for (const std::string& c : commands) {
    if (std::system(c.c_str()) != 0) return c;
  }
  return "";
}

}  // namespace slshadow::testing
