#include "core/file_util.h"

#include <fstream>
#include <stdexcept>
#include <string>

#include <gtest/gtest.h>

#include "core/error.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;

std::string Read(const fs::path& p) {
  std::ifstream in(p);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// A staging folder moves into place whole on Commit; an error midway leaves nothing behind and
// an existing target untouched.
TEST(StagingDirectory, CommitsWholeOrLeavesNothing) {
  testing::TempDir dir;
  const fs::path target = dir.path() / "out";
  {
    StagingDirectory staged(target);
    ASSERT_TRUE(fs::is_directory(staged.path()));
    EXPECT_EQ(staged.path().parent_path(), target.parent_path());
    WriteTextFileAtomically(staged.path() / "a.txt", "first");
    EXPECT_FALSE(fs::exists(target));
    staged.Commit(/*overwrite=*/false);
  }
  EXPECT_EQ(Read(target / "a.txt"), "first");
  fs::path abandoned;
  try {
    StagingDirectory staged(target);
    abandoned = staged.path();
    WriteTextFileAtomically(staged.path() / "a.txt", "second");
    throw std::runtime_error("an error midway");
  } catch (const std::runtime_error&) {}
  EXPECT_FALSE(fs::exists(abandoned));
  EXPECT_EQ(Read(target / "a.txt"), "first");
  {
    StagingDirectory staged(target);
    WriteTextFileAtomically(staged.path() / "a.txt", "third");
    EXPECT_THROW(staged.Commit(/*overwrite=*/false), Error);  // the target exists
  }
  EXPECT_EQ(Read(target / "a.txt"), "first");
  {
    StagingDirectory staged(target);
    WriteTextFileAtomically(staged.path() / "a.txt", "fourth");
    staged.Commit(/*overwrite=*/true);
  }
  EXPECT_EQ(Read(target / "a.txt"), "fourth");
  size_t entries = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir.path())) ++entries;
  EXPECT_EQ(entries, 1u) << "no staging folder left beside the target";
}

}  // namespace
}  // namespace slshadow
