#include "tests/capture/xvfb_server.h"

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <vector>

extern char** environ;

namespace slshadow::testing {

namespace {

// Spawns `args` with the write end of a fresh pipe as fd 3 and stdout/stderr to `log` (or
// /dev/null), and returns what the child writes to fd 3 up to a newline (-displayfd), or throws.
std::string SpawnWithDisplayFd(const std::vector<std::string>& args, const std::string& log,
                               pid_t* pid) {
  int fds[2];
  if (pipe2(fds, O_CLOEXEC) != 0) throw std::runtime_error("X server: pipe failed");
  std::vector<std::string> copy = args;
  std::vector<char*> argv;
  for (auto& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  const int log_fd = open(log.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  *pid = fork();
  if (*pid == 0) {
    // Child: only async-signal-safe calls until exec. The server dies with the test process
    // (SIGTERM when the forking thread ends), so a crashed test leaves no server behind.
    prctl(PR_SET_PDEATHSIG, SIGTERM);
    dup2(fds[1], 3);  // dup2 clears close-on-exec
    if (log_fd >= 0) {
      dup2(log_fd, 1);
      dup2(log_fd, 2);
    }
    execvp(argv[0], argv.data());
    _exit(127);
  }
  if (log_fd >= 0) close(log_fd);
  close(fds[1]);
  if (*pid < 0) {
    close(fds[0]);
    throw std::runtime_error(args[0] + ": cannot fork");
  }
  std::string number;
  pollfd p{fds[0], POLLIN, 0};
  while (number.empty() || number.back() != '\n') {
    if (poll(&p, 1, 15000) <= 0) break;
    char buf[32];
    const ssize_t n = read(fds[0], buf, sizeof buf);
    if (n <= 0) break;
    number.append(buf, static_cast<size_t>(n));
  }
  close(fds[0]);
  if (number.empty() || number.back() != '\n') {
    kill(*pid, SIGKILL);
    waitpid(*pid, nullptr, 0);
    throw std::runtime_error(
        args[0] +
        ": did not start or report a display number within 15 s (is it installed? "
        "scripts/setup.sh installs it; log: " +
        log + ")");
  }
  number.pop_back();
  return ":" + number;
}

void Stop(pid_t pid) {
  if (pid <= 0) return;
  kill(pid, SIGTERM);
  waitpid(pid, nullptr, 0);
}

// Runs a command to completion (xrandr); throws when it fails.
void RunOrThrow(const std::vector<std::string>& args) {
  std::vector<std::string> copy = args;
  std::vector<char*> argv;
  for (auto& a : copy) argv.push_back(a.data());
  argv.push_back(nullptr);
  pid_t pid = -1;
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 1, "/dev/null", O_WRONLY, 0);
  const int rc = posix_spawnp(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) throw std::runtime_error(args[0] + ": cannot start");
  int status = 0;
  waitpid(pid, &status, 0);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    std::string line;
    for (const auto& a : args) line += a + " ";
    throw std::runtime_error("failed: " + line);
  }
}

}  // namespace

XorgDummyServer::XorgDummyServer(int monitor_width, int monitor_height, int projector_width,
                                 int projector_height, bool set_display_env) {
  char tmpl[] = "/tmp/slshadow-xorg-XXXXXX";
  if (!mkdtemp(tmpl)) throw std::runtime_error("Xorg: mkdtemp failed");
  dir_ = tmpl;
  const std::string conf = dir_ + "/dummy.conf";
  const int virtual_w = monitor_width + projector_width;
  const int virtual_h = monitor_height > projector_height ? monitor_height : projector_height;
  std::ofstream(conf)
      << "Section \"ServerFlags\"\n  Option \"AutoAddDevices\" \"false\"\n"
         "  Option \"AutoAddGPU\" \"false\"\nEndSection\n"
         "Section \"Device\"\n  Identifier \"dummy\"\n  Driver \"dummy\"\n  VideoRam "
         "256000\nEndSection\n"
         "Section \"Monitor\"\n  Identifier \"monitor\"\n  HorizSync 5.0-1000.0\n"
         "  VertRefresh 5.0-200.0\nEndSection\n"
         "Section \"Screen\"\n  Identifier \"screen\"\n  Device \"dummy\"\n  Monitor \"monitor\"\n"
         "  DefaultDepth 24\n  SubSection \"Display\"\n    Depth 24\n    Virtual "
      << virtual_w << " " << virtual_h << "\n  EndSubSection\nEndSection\n";
  display_ = SpawnWithDisplayFd({"Xorg", "-config", conf, "-noreset", "-nolisten", "tcp",
                                 "-logfile", dir_ + "/Xorg.log", "-displayfd", "3"},
                                dir_ + "/stderr.log", &pid_);
  try {
    const std::string monitor =
        std::to_string(monitor_width) + "x" + std::to_string(monitor_height);
    const std::string projector =
        std::to_string(projector_width) + "x" + std::to_string(projector_height);
    RunOrThrow({"xrandr", "-d", display_, "--output", "DUMMY0", "--mode", monitor, "--pos", "0x0"});
    RunOrThrow({"xrandr", "-d", display_, "--addmode", "DUMMY1", projector});
    RunOrThrow({"xrandr", "-d", display_, "--output", "DUMMY1", "--mode", projector, "--pos",
                std::to_string(monitor_width) + "x0"});
    // A full query makes the server probe its outputs again; without it, clients that ask for the
    // current resources only (SDL) still see one monitor.
    RunOrThrow({"xrandr", "-d", display_, "--query"});
  } catch (...) {
    Stop(pid_);
    throw;
  }
  if (set_display_env) setenv("DISPLAY", display_.c_str(), 1);
}

XorgDummyServer::~XorgDummyServer() {
  Stop(pid_);
  std::error_code ec;
  std::filesystem::remove_all(dir_, ec);
}

XvfbServer::XvfbServer(int width, int height, bool set_display_env)
    : width_(width), height_(height) {
  const std::string screen = std::to_string(width) + "x" + std::to_string(height) + "x24";
  display_ = SpawnWithDisplayFd(
      {"Xvfb", "-displayfd", "3", "-screen", "0", screen, "-nolisten", "tcp", "-nocursor"},
      "/dev/null", &pid_);
  if (set_display_env) setenv("DISPLAY", display_.c_str(), 1);
}

XvfbServer::~XvfbServer() {
  if (pid_ > 0) {
    kill(pid_, SIGTERM);
    waitpid(pid_, nullptr, 0);
  }
}

}  // namespace slshadow::testing
