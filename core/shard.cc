#include "core/shard.h"

#include <cstdint>
#include <exception>

#include "core/error.h"

namespace slshadow {

size_t Shard::Begin(size_t items) const {
  return static_cast<size_t>(static_cast<uint64_t>(items) * static_cast<uint64_t>(index) /
                             static_cast<uint64_t>(count));
}

size_t Shard::End(size_t items) const {
  return static_cast<size_t>(static_cast<uint64_t>(items) * static_cast<uint64_t>(index + 1) /
                             static_cast<uint64_t>(count));
}

Shard ParseShard(const std::string& text, const std::string& what) {
  const size_t slash = text.find('/');
  int i = -1, n = 0;
  size_t used_i = 0, used_n = 0;
  try {
    if (slash != std::string::npos) {
      i = std::stoi(text.substr(0, slash), &used_i);
      n = std::stoi(text.substr(slash + 1), &used_n);
    }
  } catch (const std::exception&) {
    i = -1;
  }
  SLSHADOW_THROW_IF(slash == std::string::npos || i < 0 || n < 1 || i >= n || used_i != slash ||
                        used_n != text.size() - slash - 1,
                    what, ": '", text, "' is not I/N with 0 <= I < N (e.g. 0/4)");
  return Shard{i, n};
}

}  // namespace slshadow
