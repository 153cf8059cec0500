#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "fuzz/readers.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;

std::string ReadBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// Each kept crasher goes through its reader; the outcome is read (no exception) or one
// slshadow::Error whose message names the scratch file the reader was given.
TEST(FuzzRegressions, EveryKeptCrasherIsReadOrRefusedWithOneClearError) {
  const fs::path root = testing::SourceDir() / "fuzz" / "regressions";
  size_t replayed = 0;
  for (const auto& format_dir : fs::directory_iterator(root)) {
    const std::string format = format_dir.path().filename().string();
    ASSERT_TRUE(fuzz::Readers().count(format))
        << "fuzz/regressions/" << format << ": no reader of that name";
    const auto& read = fuzz::Readers().at(format);
    for (const auto& entry : fs::directory_iterator(format_dir.path())) {
      const std::string bytes = ReadBytes(entry.path());
      SCOPED_TRACE(entry.path().string());
      try {
        read(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
      } catch (const Error& e) {
        const std::string message = e.what();
        EXPECT_NE(message.find(fuzz::ScratchDir().string()), std::string::npos) << message;
        EXPECT_EQ(message.find('\n'), std::string::npos) << "not one line: " << message;
      }
      ++replayed;
    }
  }
  // Each format with a harness has seeds; the regressions folder holds at least the findings
  // docs/fuzzing.md lists.
  EXPECT_GE(replayed, 1u);
}

// The readers also accept every handmade seed (fuzz/seeds/): the harnesses start from valid input.
TEST(FuzzRegressions, HandmadeSeedsAreValidInput) {
  const fs::path root = testing::SourceDir() / "fuzz" / "seeds";
  size_t read_ok = 0;
  for (const auto& format_dir : fs::directory_iterator(root)) {
    const auto& read = fuzz::Readers().at(format_dir.path().filename().string());
    for (const auto& entry : fs::directory_iterator(format_dir.path())) {
      const std::string bytes = ReadBytes(entry.path());
      EXPECT_NO_THROW(read(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size()))
          << entry.path();
      ++read_ok;
    }
  }
  EXPECT_GE(read_ok, 11u);
}

}  // namespace
}  // namespace slshadow
