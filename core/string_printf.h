// printf into a std::string, any length: for text built line by line (summaries, device lists).
#pragma once

#include <cstdio>
#include <string>

namespace slshadow {

template <typename... Args>
std::string StringPrintf(const char* format, Args... args) {
  const int n = std::snprintf(nullptr, 0, format, args...);
  if (n <= 0) return std::string();
  std::string s(static_cast<size_t>(n), '\0');
  std::snprintf(s.data(), s.size() + 1, format, args...);
  return s;
}

}  // namespace slshadow
