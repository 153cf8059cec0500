// A fresh temporary folder per test, removed afterwards. Lives under $SLSHADOW_TEST_TMP (set by
// CTest to the build tree) or the system temporary folder.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>

#include <gtest/gtest.h>

namespace slshadow::testing {

class TempDir {
 public:
  TempDir() {
    const char* base = std::getenv("SLSHADOW_TEST_TMP");
    const std::filesystem::path root = base ? base : std::filesystem::temp_directory_path();
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = info ? std::string(info->test_suite_name()) + "." + info->name() : "test";
    for (char& c : name) {
      if (c == '/') c = '_';
    }
    std::random_device rd;
    path_ = root / (name + "-" + std::to_string(rd()));
    std::filesystem::create_directories(path_);
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  const std::filesystem::path& path() const { return path_; }
  std::filesystem::path operator/(const std::string& name) const { return path_ / name; }

 private:
  std::filesystem::path path_;
};

inline std::filesystem::path SourceDir() { return SLSHADOW_SOURCE_DIR; }
inline std::filesystem::path SharedDataDir() { return SLSHADOW_SHARED_DATA_DIR; }

}  // namespace slshadow::testing
