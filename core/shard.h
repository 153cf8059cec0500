// Shards of independent jobs ("I/N": shard I of N, 0-based), one convention for every command that
// cuts work for a scheduler (one process, GNU parallel, Slurm job arrays): `slshadow sweep run
// --shard`, `slshadow merge --reconstruct-only --shard`.
#pragma once

#include <cstddef>
#include <string>

namespace slshadow {

struct Shard {
  int index = 0;  // 0 .. count - 1
  int count = 1;
  // Of `items` in order, this shard's: the contiguous block [begin, end), blocks of sizes
  // differing by at most one, in shard order.
  size_t Begin(size_t items) const;
  size_t End(size_t items) const;
};

// Parses "I/N" (integers, 0 <= I < N). Throws slshadow::Error naming `what` and the text otherwise.
Shard ParseShard(const std::string& text, const std::string& what);

}  // namespace slshadow
