// Bad input never costs a file (issue 18, DESIGN.md "Errors"): one table over every subcommand of
// the real `slshadow` binary, run as a child process. Each row feeds one kind of bad input (a
// missing file, an unreadable one, a wrong type, a NaN, a truncated binary, a wrong image size,
// an output folder that exists or is read-only, a full disk, SIGINT in the middle of a write) and
// checks that slshadow
//   - exits non-zero (or, for SIGINT, ends by the signal),
//   - prints exactly one line on stderr, naming the file, field and value (or the cause),
//   - changes nothing in the work folder: every file and folder there (inputs, earlier outputs,
//     the parent of the output) hashes the same before and after, so nothing that existed was
//     changed and nothing half-written (a temporary sibling, a partial file) was left behind.
// Unreadable files and read-only folders are real permissions: when the test runs as root the
// child drops to the user `nobody` for those rows. "Disk full" is RLIMIT_FSIZE with SIGXFSZ
// ignored, so writes beyond the limit fail with EFBIG as they would with ENOSPC.
#include <fcntl.h>
#include <grp.h>
#include <poll.h>
#include <pwd.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <map>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "core/image_set.h"
#include "core/rig.h"
#include "tests/testing/temp_dir.h"

namespace slshadow {
namespace {

namespace fs = std::filesystem;

struct ChildOptions {
  bool as_nobody = false;     // drop to uid/gid nobody (when root) so permissions apply
  long file_size_limit = -1;  // RLIMIT_FSIZE in bytes; SIGXFSZ ignored ("disk full")
  // Polled every 2 ms while the child runs; when it returns true the child gets SIGINT.
  std::function<bool()> interrupt_when;
};

struct ChildResult {
  int exit_code = -1;  // when it exited
  int signal = 0;      // when a signal ended it
  bool interrupted = false;
  std::string err;
};

ChildResult RunSlshadow(const std::vector<std::string>& args, const ChildOptions& options = {}) {
  int pipe_fds[2];
  EXPECT_EQ(::pipe2(pipe_fds, O_CLOEXEC), 0);
  const passwd* nobody = ::getpwnam("nobody");
  const pid_t pid = ::fork();
  if (pid == 0) {
    ::dup2(pipe_fds[1], STDERR_FILENO);
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, STDOUT_FILENO);
    if (options.file_size_limit >= 0) {
      const rlimit limit{static_cast<rlim_t>(options.file_size_limit),
                         static_cast<rlim_t>(options.file_size_limit)};
      ::setrlimit(RLIMIT_FSIZE, &limit);
      ::signal(SIGXFSZ, SIG_IGN);
    }
    if (options.as_nobody && ::getuid() == 0 && nobody != nullptr) {
      if (::setgroups(0, nullptr) != 0 || ::setgid(nobody->pw_gid) != 0 ||
          ::setuid(nobody->pw_uid) != 0)
        ::_exit(120);
    }
    std::vector<char*> argv;
    std::string binary = SLSHADOW_BINARY;
    argv.push_back(binary.data());
    std::vector<std::string> copy = args;
    for (auto& a : copy) argv.push_back(a.data());
    argv.push_back(nullptr);
    ::execv(binary.c_str(), argv.data());
    ::_exit(127);
  }
  ::close(pipe_fds[1]);
  ChildResult result;
  int status = 0;
  for (;;) {
    pollfd p{pipe_fds[0], POLLIN, 0};
    if (::poll(&p, 1, 2) > 0) {
      char buf[4096];
      const ssize_t n = ::read(pipe_fds[0], buf, sizeof(buf));
      if (n > 0) result.err.append(buf, static_cast<size_t>(n));
    }
    const pid_t done = ::waitpid(pid, &status, WNOHANG);
    if (done == pid) break;
    if (options.interrupt_when && !result.interrupted && options.interrupt_when()) {
      ::kill(pid, SIGINT);
      result.interrupted = true;
    }
  }
  char buf[4096];
  for (ssize_t n; (n = ::read(pipe_fds[0], buf, sizeof(buf))) > 0;)
    result.err.append(buf, static_cast<size_t>(n));
  ::close(pipe_fds[0]);
  if (WIFEXITED(status)) result.exit_code = WEXITSTATUS(status);
  if (WIFSIGNALED(status)) result.signal = WTERMSIG(status);
  return result;
}

// path relative to the root -> kind, permissions, size and FNV-1a hash of the content.
std::map<std::string, std::string> Snapshot(const fs::path& root) {
  std::map<std::string, std::string> out;
  for (auto it = fs::recursive_directory_iterator(root); it != fs::recursive_directory_iterator();
       ++it) {
    const fs::path& p = it->path();
    const auto status = fs::symlink_status(p);
    std::string entry = std::to_string(static_cast<int>(status.type())) + " " +
                        std::to_string(static_cast<unsigned>(status.permissions()));
    if (fs::is_regular_file(status)) {
      std::ifstream in(p, std::ios::binary);
      uint64_t h = 1469598103934665603ull;
      size_t size = 0;
      for (std::istreambuf_iterator<char> c(in), end; c != end; ++c, ++size) {
        h = (h ^ static_cast<unsigned char>(*c)) * 1099511628211ull;
      }
      entry += " " + std::to_string(size) + " " + std::to_string(h);
    }
    out[fs::relative(p, root).string()] = entry;
  }
  return out;
}

std::string Describe(const std::map<std::string, std::string>& before,
                     const std::map<std::string, std::string>& after) {
  std::string d;
  for (const auto& [k, v] : after) {
    auto it = before.find(k);
    if (it == before.end())
      d += "  added: " + k + "\n";
    else if (it->second != v)
      d += "  changed: " + k + "\n";
  }
  for (const auto& [k, v] : before) {
    if (!after.count(k)) d += "  removed: " + k + "\n";
  }
  return d;
}

void WriteText(const fs::path& p, const std::string& text) {
  std::ofstream out(p, std::ios::binary);
  out << text;
}

std::string ReadText(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// The demo rig at a quarter of its resolution (480 x 300 cameras, 320 x 200 projector): a scan of
// it simulates in about a second.
Rig QuarterDemoRig() {
  Rig rig = LoadRig(testing::SourceDir() / "config/demo/rig.yaml");
  std::vector<RigDevice*> devices;
  for (auto& c : rig.cameras) devices.push_back(&c);
  devices.push_back(&*rig.projector);
  for (RigDevice* d : devices) {
    d->model.width /= 4;
    d->model.height /= 4;
    for (int k : {CameraModel::kFx, CameraModel::kFy}) d->model.params[static_cast<size_t>(k)] /= 4;
    for (int k : {CameraModel::kCx, CameraModel::kCy}) {
      d->model.params[static_cast<size_t>(k)] =
          (d->model.params[static_cast<size_t>(k)] + 0.5) / 4 - 0.5;
    }
  }
  return rig;
}

struct Row {
  Row(std::string name_, std::vector<std::string> args_, std::string expect_,
      ChildOptions options_ = {}, bool interrupt_ = false)
      : name(std::move(name_)),
        args(std::move(args_)),
        expect(std::move(expect_)),
        options(std::move(options_)),
        interrupt(interrupt_) {}
  std::string name;
  std::vector<std::string> args;  // "@" is replaced by the work folder
  std::string expect;             // a substring of the single stderr line ("@" = work folder)
  ChildOptions options;
  bool interrupt = false;  // ends by SIGINT instead of a non-zero exit
};

class BadInput : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    tmp_ = new testing::TempDir;
    const fs::path w = Work();
    fs::create_directories(w);
    const fs::path src = testing::SourceDir();
    SaveRig(QuarterDemoRig(), w / "rig.yaml");
    std::string rig = ReadText(w / "rig.yaml");
    WriteText(w / "rig_nan.yaml", std::string(rig).replace(rig.find("fx: "), 4, "fx: .nan #"));
    WriteText(w / "rig_type.yaml",
              std::string(rig).replace(rig.find("width: "), 7, "width: wide #"));
    WriteText(w / "rig_unreadable.yaml", rig);
    fs::permissions(w / "rig_unreadable.yaml", fs::perms::owner_write);
    fs::create_directories(w / "rig_dir.yaml");
    std::string patterns = ReadText(src / "config/demo/patterns.yaml");
    for (const auto& [from, to] :
         {std::pair<std::string, std::string>{"projector_width: 1280", "projector_width: 320"},
          {"projector_height: 800", "projector_height: 200"}}) {
      ASSERT_NE(patterns.find(from), std::string::npos) << from;
      patterns.replace(patterns.find(from), from.size(), to);
    }
    WriteText(w / "patterns.yaml", patterns);
    const size_t period = patterns.find("period_px:");
    ASSERT_NE(period, std::string::npos);
    WriteText(w / "patterns_nan.yaml",
              std::string(patterns).replace(period, 10, "period_px: .nan #"));
    fs::copy_file(src / "config/demo/scene.yaml", w / "scene.yaml");
    // A small scan, then copies with one image of the wrong size and one truncated.
    const ChildResult sim = RunSlshadow(
        {"simulate", "--rig", (w / "rig.yaml").string(), "--scene", (w / "scene.yaml").string(),
         "--patterns", (w / "patterns.yaml").string(), "--out", (w / "scan").string(), "--encoding",
         "png", "--no-ground-truth", "--quiet"});
    ASSERT_EQ(sim.exit_code, 0) << sim.err;
    fs::copy(w / "scan", w / "scan_size", fs::copy_options::recursive);
    ASSERT_TRUE(cv::imwrite((w / "scan_size/left/0003.png").string(),
                            cv::Mat(100, 100, CV_8UC1, cv::Scalar(9))));
    fs::copy(w / "scan", w / "scan_truncated", fs::copy_options::recursive);
    const std::string png = ReadText(w / "scan/left/0003.png");
    WriteText(w / "scan_truncated/left/0003.png", png.substr(0, png.size() / 2));
    // Clouds and meshes: good, truncated binary, NaN.
    WriteText(w / "cloud.ply",
              "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float "
              "y\nproperty float z\n"
              "end_header\n0 0 0\n10 0 0\n0 10 0\n0 0 10\n");
    WriteText(w / "cloud_truncated.ply",
              "ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float "
              "x\nproperty float y\n"
              "property float z\nend_header\n" +
                  std::string(120, '\0'));
    WriteText(w / "cloud_nan.ply",
              "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float "
              "y\nproperty float z\n"
              "end_header\n0 0 0\n1 nan 2\n");
    std::string stl = "solid t\n";
    const char* tri[4][3] = {{"0 0 0", "0 10 0", "10 0 0"},
                             {"0 0 0", "10 0 0", "0 0 10"},
                             {"0 0 0", "0 0 10", "0 10 0"},
                             {"10 0 0", "0 10 0", "0 0 10"}};
    for (auto& t : tri) {
      stl += "facet normal 0 0 0\nouter loop\n";
      for (const char* v : t) stl += std::string("vertex ") + v + "\n";
      stl += "endloop\nendfacet\n";
    }
    WriteText(w / "mesh.stl", stl + "endsolid t\n");
    std::string binary_stl(84, '\0');
    binary_stl[80] = 100;  // claims 100 triangles, holds none
    WriteText(w / "mesh_truncated.stl", binary_stl);
    // OpenCV calibration files: a good one and one with a NaN focal length.
    WriteText(
        w / "opencv.yml",
        "%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
        "   rows: 3\n   cols: 3\n   dt: d\n   data: [ 500., 0., 320., 0., 500., 240., 0., 0., 1. "
        "]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        "   data: [ 0., 0., 0., 0., 0. ]\n");
    std::string cv_yml = ReadText(w / "opencv.yml");
    WriteText(w / "opencv_nan.yml",
              std::string(cv_yml).replace(cv_yml.find("500., 0., 320."), 4, ".Nan"));
    WriteText(w / "study.yaml", "not: a study\n");
    // Earlier outputs that must survive: a folder of the user's, an earlier report, a cloud file;
    // and a read-only folder.
    fs::create_directories(w / "mine");
    WriteText(w / "mine/notes.txt", "keep me");
    WriteText(w / "earlier.ply", ReadText(w / "cloud.ply"));
    fs::create_directories(w / "readonly");
    WriteText(w / "readonly/keep.txt", "keep me too");
    fs::permissions(w / "readonly", fs::perms::owner_read | fs::perms::owner_exec |
                                        fs::perms::group_read | fs::perms::group_exec |
                                        fs::perms::others_read | fs::perms::others_exec);
    // `nobody` must be able to reach and read the inputs.
    for (fs::path p = w; p.has_relative_path() && p != p.root_path(); p = p.parent_path()) {
      fs::permissions(p, fs::perms::others_exec, fs::perm_options::add);
    }
  }
  static void TearDownTestSuite() {
    std::error_code ec;
    fs::permissions(Work() / "readonly", fs::perms::owner_all, fs::perm_options::add, ec);
    delete tmp_;
    tmp_ = nullptr;
  }
  static fs::path Work() { return tmp_->path() / "work"; }
  static testing::TempDir* tmp_;
};
testing::TempDir* BadInput::tmp_ = nullptr;

std::string Expand(const std::string& s, const fs::path& work) {
  std::string out = s;
  for (size_t at; (at = out.find('@')) != std::string::npos;) out.replace(at, 1, work.string());
  return out;
}

TEST_F(BadInput, EverySubcommandFailsCleanlyAndChangesNothing) {
  const fs::path w = Work();
  // True once a temporary sibling (".partial-") of an output exists under the work folder: the
  // command is in the middle of writing.
  const auto writing = [w] {
    for (auto it = fs::recursive_directory_iterator(w); it != fs::recursive_directory_iterator();
         ++it) {
      if (it->path().filename().string().find(".partial-") != std::string::npos) return true;
    }
    return false;
  };
  ChildOptions nobody, disk_full, interrupt_mid_write;
  nobody.as_nobody = true;
  disk_full.file_size_limit = 64 * 1024;  // the quarter-size scan's images are about 40 kB
  ChildOptions disk_full_small = disk_full;
  disk_full_small.file_size_limit = 512;  // the 320 x 200 pattern PNGs are 650 to 900 bytes
  interrupt_mid_write.interrupt_when = writing;
  const std::vector<Row> rows = {
      // rig
      {"rig: missing file", {"rig", "show", "@/none.yaml"}, "@/none.yaml: file not found"},
      {"rig: a folder", {"rig", "show", "@/rig_dir.yaml"}, "@/rig_dir.yaml: is a directory"},
      {"rig: unreadable",
       {"rig", "show", "@/rig_unreadable.yaml"},
       "@/rig_unreadable.yaml: cannot open",
       nobody},
      {"rig: wrong type",
       {"rig", "show", "@/rig_type.yaml"},
       "@/rig_type.yaml: cameras[0].width: expected a whole number (got \"wide\")"},
      {"rig: NaN",
       {"rig", "show", "@/rig_nan.yaml"},
       "@/rig_nan.yaml: cameras[0].intrinsics.fx: must be a finite number (got NaN)"},
      // patterns
      {"patterns show: NaN",
       {"patterns", "show", "@/patterns_nan.yaml"},
       "@/patterns_nan.yaml: period_px: must be a finite number (got NaN)"},
      {"patterns generate: existing folder",
       {"patterns", "generate", "@/patterns.yaml", "--out", "@/mine"},
       "@/mine"},
      {"patterns generate: read-only folder",
       {"patterns", "generate", "@/patterns.yaml", "--out", "@/readonly/p"},
       "@/readonly/p",
       nobody},
      {"patterns generate: disk full",
       {"patterns", "generate", "@/patterns.yaml", "--out", "@/p"},
       "@/p",
       disk_full_small},
      // simulate
      {"simulate: missing rig",
       {"simulate", "--rig", "@/none.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/s"},
       "@/none.yaml: file not found"},
      {"simulate: NaN in rig",
       {"simulate", "--rig", "@/rig_nan.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/s"},
       "cameras[0].intrinsics.fx: must be a finite number (got NaN)"},
      {"simulate: existing folder",
       {"simulate", "--rig", "@/rig.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/mine"},
       "@/mine: already exists (pass --overwrite to replace it)"},
      {"simulate: read-only folder",
       {"simulate", "--rig", "@/rig.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/readonly/s"},
       "@/readonly/s",
       nobody},
      {"simulate: disk full",
       {"simulate", "--rig", "@/rig.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/s"},
       "@/s",
       disk_full},
      {"simulate: SIGINT mid-write",
       {"simulate", "--rig", "@/rig.yaml", "--scene", "@/scene.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/s", "--encoding", "png", "--quiet"},
       "interrupted (SIGINT)",
       interrupt_mid_write,
       true},
      // reconstruct
      {"reconstruct: missing folder", {"reconstruct", "@/none", "--out", "@/c.ply"}, "@/none"},
      {"reconstruct: wrong image size",
       {"reconstruct", "@/scan_size", "--out", "@/c.ply"},
       "@/scan_size/left/0003.png: wrong image size 100x100"},
      {"reconstruct: truncated image",
       {"reconstruct", "@/scan_truncated", "--out", "@/c.ply"},
       "@/scan_truncated/left/0003.png: truncated PNG"},
      {"reconstruct: NaN rig",
       {"reconstruct", "@/scan", "--rig", "@/rig_nan.yaml", "--out", "@/c.ply"},
       "@/rig_nan.yaml: cameras[0].intrinsics.fx"},
      {"reconstruct: read-only folder",
       {"reconstruct", "@/scan", "--out", "@/readonly/c.ply"},
       "@/readonly/c.ply",
       nobody},
      {"reconstruct: disk full",
       {"reconstruct", "@/scan", "--out", "@/earlier.ply"},
       "@/earlier.ply",
       disk_full},
      // compare
      {"compare: missing cloud",
       {"compare", "@/none.ply", "@/mesh.stl", "--out", "@/r"},
       "@/none.ply"},
      {"compare: truncated cloud",
       {"compare", "@/cloud_truncated.ply", "@/mesh.stl", "--out", "@/r"},
       "@/cloud_truncated.ply: PLY header: element 'vertex' claims 100 rows"},
      {"compare: NaN in cloud",
       {"compare", "@/cloud_nan.ply", "@/mesh.stl", "--out", "@/r"},
       "@/cloud_nan.ply: vertex 1 has a non-finite coordinate"},
      {"compare: truncated mesh",
       {"compare", "@/cloud.ply", "@/mesh_truncated.stl", "--out", "@/r"},
       "@/mesh_truncated.stl"},
      {"compare: existing folder not a report",
       {"compare", "@/cloud.ply", "@/mesh.stl", "--out", "@/mine"},
       "@/mine: exists and is not a compare report"},
      {"compare: read-only folder",
       {"compare", "@/cloud.ply", "@/mesh.stl", "--out", "@/readonly/r"},
       "@/readonly/r",
       nobody},
      // calibrate
      {"calibrate import: missing file",
       {"calibrate", "import", "@/none.yml", "--out", "@/imported.yaml"},
       "@/none.yml"},
      {"calibrate import: NaN",
       {"calibrate", "import", "@/opencv_nan.yml", "--out", "@/imported.yaml"},
       "@/opencv_nan.yml"},
      {"calibrate import: read-only folder",
       {"calibrate", "import", "@/opencv.yml", "--out", "@/readonly/r.yaml"},
       "@/readonly/r.yaml",
       nobody},
      {"calibrate export: wrong type",
       {"calibrate", "export", "@/rig_type.yaml", "--out", "@/e.yml"},
       "@/rig_type.yaml: cameras[0].width"},
      {"calibrate camera: missing images",
       {"calibrate", "camera", "--target", "@/none.yaml", "--images", "@/none", "--out",
        "@/c.yaml"},
       "@/none"},
      // shadow
      {"shadow: truncated part",
       {"shadow", "@/scan", "--part", "@/mesh_truncated.stl", "--out", "@/sh"},
       "@/mesh_truncated.stl"},
      {"shadow: existing folder",
       {"shadow", "@/scan", "--part", "@/mesh.stl", "--out", "@/mine"},
       "@/mine"},
      // demo
      {"demo: existing folder",
       {"demo", "--out", "@/mine"},
       "@/mine: exists and is not an earlier demo output"},
      {"demo: NaN rig",
       {"demo", "--out", "@/d", "--rig", "@/rig_nan.yaml"},
       "@/rig_nan.yaml: cameras[0].intrinsics.fx"},
      // sweep
      {"sweep plan: missing study",
       {"sweep", "plan", "@/none.yaml", "--out", "@/jobs"},
       "@/none.yaml: file not found"},
      {"sweep plan: wrong study",
       {"sweep", "plan", "@/study.yaml", "--out", "@/jobs"},
       "@/study.yaml"},
      {"sweep run: missing jobs", {"sweep", "run", "@/none"}, "@/none"},
      {"sweep merge: missing jobs", {"sweep", "merge", "@/none", "--out", "@/result"}, "@/none"},
      // devices, capture, latency, projector, bench
      {"capture: missing devices",
       {"capture", "--rig", "@/rig.yaml", "--devices", "@/none.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/cap"},
       "@/none.yaml"},
      {"capture: NaN rig",
       {"capture", "--rig", "@/rig_nan.yaml", "--devices", "@/none.yaml", "--patterns",
        "@/patterns.yaml", "--out", "@/cap"},
       "@/rig_nan.yaml"},
      {"latency: missing devices", {"latency", "--devices", "@/none.yaml"}, "@/none.yaml"},
      {"devices: bad address", {"devices", "--address", "not-an-address"}, "not-an-address"},
      {"projector: bad USB address", {"projector", "--usb", "x:y", "info"}, "x:y"},
      {"bench: unknown entry", {"bench", "--only", "render"}, "render"},
  };
  for (const Row& row : rows) {
    SCOPED_TRACE(row.name);
    std::vector<std::string> args;
    for (const auto& a : row.args) args.push_back(Expand(a, w));
    const auto before = Snapshot(w);
    const ChildResult r = RunSlshadow(args, row.options);
    const auto after = Snapshot(w);
    const std::string changes = Describe(before, after);
    EXPECT_TRUE(changes.empty()) << "the work folder changed:\n"
                                 << changes.substr(0, 2000) << r.err;
    if (row.interrupt) {
      EXPECT_TRUE(r.interrupted) << "finished before it was seen writing";
      EXPECT_EQ(r.signal, SIGINT) << r.err;
    } else {
      EXPECT_NE(r.exit_code, 0) << r.err;
      EXPECT_EQ(r.signal, 0) << r.err;
    }
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "not one line:\n" << r.err;
    EXPECT_NE(r.err.find(Expand(row.expect, w)), std::string::npos) << r.err;
  }
}

}  // namespace
}  // namespace slshadow
