// What the two `slshadow scan` suites share (scan_test.cc through the real protocols,
// scan_faults_test.cc with replay cameras): a fresh folder per test, the command line run in this
// process (the fake devices live here), and a projector that runs a hook before each pattern.
#pragma once

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <string>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "apps/commands.h"
#include "capture/projector.h"

namespace slshadow::testing {

// An empty folder <SLSHADOW_TEST_TMP or the system's temporary folder>/<prefix><name>.
inline std::filesystem::path ScanTestDir(const std::string& prefix, const std::string& name) {
  const char* tmp = std::getenv("SLSHADOW_TEST_TMP");
  std::filesystem::path dir =
      std::filesystem::path(tmp ? tmp : std::filesystem::temp_directory_path().string()) /
      (prefix + name);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

// Runs `slshadow ARGS...` in this process (the fake cameras and the emulator live here); returns
// its exit status, with what it printed on stderr in *err.
inline int RunSlshadow(std::vector<std::string> args, std::string* err) {
  args.insert(args.begin(), "slshadow");
  std::vector<char*> argv;
  for (auto& a : args) argv.push_back(a.data());
  ::testing::internal::CaptureStderr();
  const int rc = app::Main(static_cast<int>(argv.size()), argv.data());
  *err = ::testing::internal::GetCapturedStderr();
  std::printf("slshadow %s: exit %d\n%s", args[1].c_str(), rc, err->c_str());
  return rc;
}

// A projector that forwards to another and runs `hook(view, index)` before each Show: `view`
// counts the sequencer's Load() calls (one per view's capture). For faults at a chosen frame of a
// chosen view, on the sequencer's own thread.
class HookedProjector : public capture::Projector {
 public:
  HookedProjector(capture::Projector& inner, std::function<void(int, int)> hook)
      : inner_(inner), hook_(std::move(hook)) {}
  capture::ProjectorInfo Info() const override { return inner_.Info(); }
  void Load(const std::vector<cv::Mat>& images) override {
    ++view_;
    inner_.Load(images);
  }
  std::chrono::steady_clock::time_point Show(int index) override {
    hook_(view_, index);
    return inner_.Show(index);
  }
  std::chrono::steady_clock::time_point ShowBlack() override { return inner_.ShowBlack(); }
  std::chrono::microseconds Latency() const override { return inner_.Latency(); }
  void SetLatency(std::chrono::microseconds latency) override { inner_.SetLatency(latency); }
  int size() const override { return inner_.size(); }

 private:
  capture::Projector& inner_;
  std::function<void(int, int)> hook_;
  int view_ = -1;
};

}  // namespace slshadow::testing
