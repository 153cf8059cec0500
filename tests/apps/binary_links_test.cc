// The slshadow binary's start-up cost is mostly the dynamic libraries it loads (issue 17): Debian's
// libopencv-imgcodecs alone pulls in ~100 (GDAL, poppler, HDF5, ...). Images are read and written
// through core/image_io.h instead; this test keeps it that way by reading the DT_NEEDED entries of
// the binary and, recursively, of every library it needs (the ELF files themselves, as ldd would
// resolve them in the system folders).
#include <elf.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <set>
#include <string>
#include <vector>

#include <gtest/gtest.h>

namespace {

namespace fs = std::filesystem;

// DT_NEEDED names of a 64-bit little-endian ELF file, from its SHT_DYNAMIC section and the string
// table that section links to. Fails the test on anything else.
std::vector<std::string> Needed(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  const std::string bytes((std::istreambuf_iterator<char>(in)), {});
  std::vector<std::string> needed;
  EXPECT_GE(bytes.size(), sizeof(Elf64_Ehdr)) << path;
  if (bytes.size() < sizeof(Elf64_Ehdr)) return needed;
  Elf64_Ehdr eh;
  std::memcpy(&eh, bytes.data(), sizeof(eh));
  EXPECT_EQ(std::memcmp(eh.e_ident, ELFMAG, SELFMAG), 0) << path << ": not ELF";
  EXPECT_EQ(eh.e_ident[EI_CLASS], ELFCLASS64) << path;
  auto section = [&](size_t i) {
    Elf64_Shdr sh{};
    const size_t at = eh.e_shoff + i * eh.e_shentsize;
    if (at + sizeof(sh) <= bytes.size()) std::memcpy(&sh, bytes.data() + at, sizeof(sh));
    return sh;
  };
  for (size_t i = 0; i < eh.e_shnum; ++i) {
    const Elf64_Shdr dyn = section(i);
    if (dyn.sh_type != SHT_DYNAMIC) continue;
    const Elf64_Shdr str = section(dyn.sh_link);
    for (size_t off = 0; off + sizeof(Elf64_Dyn) <= dyn.sh_size; off += sizeof(Elf64_Dyn)) {
      Elf64_Dyn d;
      std::memcpy(&d, bytes.data() + dyn.sh_offset + off, sizeof(d));
      if (d.d_tag == DT_NULL) break;
      if (d.d_tag == DT_NEEDED && str.sh_offset + d.d_un.d_val < bytes.size()) {
        needed.emplace_back(bytes.data() + str.sh_offset + d.d_un.d_val);
      }
    }
  }
  return needed;
}

fs::path Resolve(const std::string& name) {
  for (const char* dir : {"/lib/x86_64-linux-gnu", "/usr/lib/x86_64-linux-gnu", "/lib64", "/lib",
                          "/usr/lib", "/usr/local/lib"}) {
    if (fs::exists(fs::path(dir) / name)) return fs::path(dir) / name;
  }
  return {};
}

bool Banned(const std::string& name) {
  for (const char* banned : {"imgcodecs", "libgdal", "libpoppler", "libhdf5", "libgdcm"}) {
    if (name.find(banned) != std::string::npos) return true;
  }
  return false;
}

TEST(BinaryLinks, SlshadowNeedsNoImgcodecsDirectlyOrThroughAnyLibrary) {
  const std::vector<std::string> direct = Needed(SLSHADOW_BINARY);
  // The parser sees the libraries the binary does need (else the checks below prove nothing).
  ASSERT_FALSE(direct.empty());
  EXPECT_TRUE(std::any_of(direct.begin(), direct.end(),
                          [](const std::string& n) { return n.starts_with("libopencv_core.so"); }));
  EXPECT_TRUE(std::any_of(direct.begin(), direct.end(),
                          [](const std::string& n) { return n.starts_with("libpng16.so"); }));
  std::set<std::string> seen;
  // Depth-first over the NEEDED entries: (library, the library that needs it) not yet visited.
  std::vector<std::pair<std::string, std::string>> unvisited;
  for (const std::string& n : direct) unvisited.emplace_back(n, "slshadow");
  while (!unvisited.empty()) {
    const auto [name, parent] = unvisited.back();
    unvisited.pop_back();
    if (!seen.insert(name).second) continue;
    EXPECT_FALSE(Banned(name)) << name << " is needed by " << parent;
    const fs::path path = Resolve(name);
    if (path.empty()) continue;  // e.g. the loader itself under another folder
    for (const std::string& n : Needed(path)) unvisited.emplace_back(n, name);
  }
  // What ldd reports today is ~124 libraries; with imgcodecs it was 221.
  EXPECT_GT(seen.size(), 20u);
  EXPECT_LT(seen.size(), 180u) << "the binary loads " << seen.size() << " libraries";
}

}  // namespace
