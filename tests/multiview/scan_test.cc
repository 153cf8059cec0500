// `slshadow scan` through the real protocols, compared with `slshadow simulate --views`:
//
//   views.yaml -> scan -> GRBL 1.1 over a pseudo-terminal (GrblEmulator: the backend's termios
//   path) turns the table; patterns --Show--> SDL window projector under Xvfb; two Aravis GigE
//   Vision fake cameras (127.0.0.2 / .3 in a private network namespace) render, with the
//   simulator, the demo part on its turntable at the angle the GRBL emulator's machine position
//   says, lit by the projector image read back from the X screen -> one ImageSet per view.
//
// The fake cameras never see the views file: only if the table really turned to each view's angle
// before its frames were taken, every frame shows its pattern, and each went to the right view,
// camera and pattern, do the project's images equal SimulateProject's pixel for pixel. Faults
// (a GRBL alarm while the table turns to view k, a camera unplugged in the middle of view k) end
// in one message naming the view and the device, and `slshadow scan --resume` completes the
// project with the same images.
#include <atomic>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <fcntl.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "apps/commands.h"
#include "capture/factory.h"
#include "capture/x11_screen.h"
#include "core/config.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "sim/renderer.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "tests/capture/fake_gv_camera.h"
#include "tests/capture/grbl_emulator.h"
#include "tests/capture/scaled_demo_rig.h"
#include "tests/capture/xvfb_server.h"
#include "tests/multiview/scan_test_util.h"
#include "workflows/multiview/scan.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/views.h"
#include "workflows/multiview/virtual_project.h"

namespace slshadow::multiview {
namespace {

namespace fs = std::filesystem;

using slshadow::testing::HookedProjector;
using slshadow::testing::RunSlshadow;

fs::path TestDir(const std::string& name) { return slshadow::testing::ScanTestDir("scan_", name); }

class ScanLoop : public ::testing::Test {
 protected:
  static constexpr int kMonitorWidth = 640;  // the X screen: a "monitor", then the projector

  void SetUp() override {
    const std::string reason = slshadow::testing::SkipReasonWithoutPrivateNetwork();
    if (!reason.empty()) GTEST_SKIP() << reason;
    dir_ = TestDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    // The demo part on its turntable, seen by the demo rig at a quarter of its resolution.
    const TurntableSetup setup =
        MakeTurntableSetup(slshadow::testing::ScaledDemoRig(4),
                           LoadScene(fs::path(SLSHADOW_SOURCE_DIR) / "config/demo/scene.yaml"));
    PatternSpec spec =
        LoadPatternSpec(fs::path(SLSHADOW_SOURCE_DIR) / "config/patterns/graycode_phase.yaml");
    spec.projector_width = setup.rig.projector->model.width;
    spec.projector_height = setup.rig.projector->model.height;
    spec.Check();
    // The inputs as files, read back: the library runs and the commands see the same values.
    rig_file_ = dir_ / "rig.yaml";
    patterns_file_ = dir_ / "patterns.json";
    views_file_ = dir_ / "views.yaml";
    devices_file_ = dir_ / "devices.yaml";
    SaveRig(setup.rig, rig_file_);
    std::ofstream(patterns_file_) << PatternSpecToJson(spec).dump(2);
    SaveViews(FullTurnViews(3), views_file_);
    rig_ = LoadRig(rig_file_);
    spec_ = LoadPatternSpec(patterns_file_);
    views_ = LoadViews(views_file_);
    scene_ = std::make_unique<Scene>(setup.scene);

    // The oracle: what `slshadow simulate --views` writes for the same scene, rig and views.
    VirtualProjectOptions vopt;
    vopt.encoding = ImageEncoding::kPgm;
    SimulateProject(*scene_, rig_, spec_, views_, dir_ / "simulated", vopt);

    const int pw = rig_.projector->model.width, ph = rig_.projector->model.height;
    projector_rect_ = cv::Rect(kMonitorWidth, 0, pw, ph);
    xvfb_ = std::make_unique<slshadow::testing::XvfbServer>(kMonitorWidth + pw, std::max(480, ph));
    grbl_ = std::make_unique<capture::testing::GrblEmulator>();

    // The part at each view's angle, as SimulateProject places it (the same poses, bit for bit).
    for (size_t i = 0; i < views_.views.size(); ++i) {
      const ViewSpec& v = views_.views[i];
      Angle& a = angles_[*v.table_deg];
      a.scene = std::make_unique<Scene>(VirtualViewScene(*scene_, rig_, v, i));
      a.simulator = std::make_unique<Simulator>(*a.scene, rig_, TraceMode::kPacket16,
                                                /*ground_truth=*/false);
      for (int c = 0; c < 2; ++c)
        a.renderers.push_back(
            std::make_unique<PatternRenderer>(*a.scene, rig_, c, a.simulator->geometry(c)));
    }
    for (size_t k = 0; k < 2; ++k) fakes_.push_back(MakeFakeCamera(k));
    WriteDevices();
  }

  // Fake camera k renders the part at the table angle the GRBL emulator is at (black while the
  // table is between views), lit by what the X screen shows in the projector's rectangle.
  std::unique_ptr<slshadow::testing::FakeGvCamera> MakeFakeCamera(size_t k) {
    auto fake =
        std::make_unique<slshadow::testing::FakeGvCamera>(slshadow::testing::FakeGvCameraOptions{
            .address = kAddresses[k], .serial = rig_.cameras[k].name});
    fake->SetFill([this, k](const slshadow::testing::FakeFrameRequest& r) {
      thread_local std::unique_ptr<capture::XScreenReader> screen;
      if (!screen) screen = std::make_unique<capture::XScreenReader>();
      const double angle_deg = grbl_->MachinePosition(0);  // degrees_per_unit 1
      const auto it = angles_.find(angle_deg);
      if (it == angles_.end()) return cv::Mat(r.height, r.width, CV_8UC1, cv::Scalar(0));
      return it->second.renderers[k]->Render(screen->ReadGrey(projector_rect_), 0);
    });
    return fake;
  }

  void WriteDevices() {
    std::ofstream out(devices_file_);
    out << "format: slshadow-devices\nversion: 1\ncameras:\n";
    for (size_t k = 0; k < 2; ++k) {
      out << "  - name: " << rig_.cameras[k].name
          << "\n    backend: aravis\n    address: " << kAddresses[k]
          << "\n    settings: {pixel_format: Mono8, trigger: software, roi: [0, 0, "
          << rig_.cameras[k].model.width << ", " << rig_.cameras[k].model.height
          << "], packet_size_bytes: 8192}\n    grab_timeout_ms: 1500\n";
    }
    out << "projector:\n  backend: window\n  display: \"" << projector_rect_.x << ","
        << projector_rect_.y << "," << projector_rect_.width << "," << projector_rect_.height
        << "\"\n  latency_us: 60000\n";
    out << "turntable:\n  backend: grbl\n  port: " << grbl_->port()
        << "\n  axis: X\n  degrees_per_unit: 1.0\n  tolerance_deg: 0.001\n  poll_interval_ms: 10\n"
           "  unlock: true\n";
  }

  std::vector<std::string> ScanArgs(const std::string& project) const {
    return {"scan",
            "--rig",
            rig_file_.string(),
            "--devices",
            devices_file_.string(),
            "--patterns",
            patterns_file_.string(),
            "--views",
            views_file_.string(),
            "--out",
            (dir_ / project).string(),
            "--encoding",
            "pgm",
            "--quiet",
            "--yes",
            "--max-retries",
            "2"};
  }

  // Scans `project` with the library, as `slshadow scan` does, through `wrap` (a projector
  // wrapper or the projector itself) and the turntable; on_view after each view.
  ScanSummary ScanWithLibrary(
      const std::string& project, const std::function<void(size_t)>& on_view,
      const std::function<void(int, int)>& before_show = [](int, int) {}) {
    const capture::DevicesConfig devices = capture::LoadDevices(devices_file_);
    capture::OpenedDevices opened = capture::OpenDevices(devices, rig_);
    const std::unique_ptr<capture::Turntable> table = capture::OpenTurntable(devices.turntable);
    HookedProjector projector(*opened.projector, before_show);
    ScanDevices d;
    d.cameras = opened.cameras;
    d.projector = &projector;
    d.turntable = table.get();
    d.turntable_backend = devices.turntable.backend;
    d.turntable_tolerance_deg = devices.turntable.tolerance_deg;
    d.devices_file = devices_file_.string();
    ScanOptions options;
    options.sequencer.settle = opened.settle;
    options.sequencer.max_retries = 2;
    options.sequencer.writer.encoding = ImageEncoding::kPgm;
    options.sequencer.progress = false;
    options.on_view = [&](const std::string&, size_t index, bool) { on_view(index); };
    return ScanProject(rig_, spec_, views_, d, dir_ / project, options);
  }

  // Images of the project's views that differ from the simulated project's.
  int DifferingImages(const std::string& project) {
    int differing = 0;
    for (const ViewSpec& v : views_.views) {
      const ImageSet scanned = ImageSet::Open(dir_ / project / "views" / v.name);
      const ImageSet simulated = ImageSet::Open(dir_ / "simulated" / "views" / v.name);
      EXPECT_EQ(scanned.PatternCount(), simulated.PatternCount()) << v.name;
      for (const std::string& camera : simulated.CameraNames()) {
        for (int i = 0; i < simulated.PatternCount(); ++i) {
          const cv::Mat a = scanned.Load(camera, i), b = simulated.Load(camera, i);
          if (a.type() == b.type() && a.size() == b.size() && cv::norm(a, b, cv::NORM_INF) == 0)
            continue;
          ++differing;
          std::printf("  %s %s: %s pattern %d differs from the simulation\n", project.c_str(),
                      v.name.c_str(), camera.c_str(), i);
        }
      }
    }
    return differing;
  }

  void TearDown() override {
    fakes_.clear();
    grbl_.reset();
    xvfb_.reset();
  }

  struct Angle {
    std::unique_ptr<Scene> scene;
    std::unique_ptr<Simulator> simulator;
    std::vector<std::unique_ptr<PatternRenderer>> renderers;
  };
  const std::vector<std::string> kAddresses = {"127.0.0.2", "127.0.0.3"};
  fs::path dir_, rig_file_, patterns_file_, views_file_, devices_file_;
  Rig rig_;
  PatternSpec spec_;
  ViewsFile views_;
  std::unique_ptr<Scene> scene_;
  cv::Rect projector_rect_;
  std::map<double, Angle> angles_;
  std::unique_ptr<slshadow::testing::XvfbServer> xvfb_;
  std::unique_ptr<capture::testing::GrblEmulator> grbl_;
  std::vector<std::unique_ptr<slshadow::testing::FakeGvCamera>> fakes_;
};

// What a user runs: `slshadow turntable status`, then `slshadow scan`; every image of every view
// equals the simulation, and project.json holds each view's provenance in the format
// `slshadow merge` reads (LoadProject).
TEST_F(ScanLoop, ScanCommandEqualsSimulatedProject) {
  std::string err;
  ASSERT_EQ(RunSlshadow({"turntable", "status", "--devices", devices_file_.string()}, &err), 0);
  ASSERT_EQ(RunSlshadow(ScanArgs("scanned"), &err), 0);
  EXPECT_EQ(DifferingImages("scanned"), 0);

  const ProjectManifest project = LoadProject(dir_ / "scanned");
  EXPECT_EQ(project.provenance["generator"], "slshadow scan");
  EXPECT_EQ(project.provenance["encoding"], "pgm");
  ASSERT_EQ(project.views.size(), 3u);
  for (const ProjectView& v : project.views) {
    EXPECT_EQ(v.state, ViewState::kComplete) << v.spec.name;
    EXPECT_EQ(v.source, "device");
    ASSERT_TRUE(v.provenance.is_object()) << v.spec.name;
    EXPECT_EQ(v.provenance["table_deg"].get<double>(), *v.spec.table_deg);
    EXPECT_NEAR(v.provenance["read_back_deg"].get<double>(), *v.spec.table_deg, 1e-3);
    EXPECT_NEAR(v.provenance["read_back_after_deg"].get<double>(), *v.spec.table_deg, 1e-3);
    EXPECT_NE(v.provenance["turntable"].get<std::string>().find(grbl_->port()), std::string::npos);
    EXPECT_EQ(v.provenance["cameras"]["left"], "left");  // the fake cameras' serials
    // The view's ImageSet carries the move's provenance too.
    const ImageSet set = ImageSet::Open(dir_ / "scanned" / v.Folder());
    EXPECT_EQ(set.extra()["view"]["table_deg"].get<double>(), *v.spec.table_deg);
  }
  // The table was moved in machine coordinates to each angle in turn.
  int moves = 0;
  for (const std::string& line : grbl_->Lines()) moves += line.find("G53") != std::string::npos;
  EXPECT_EQ(moves, 3);
  EXPECT_EQ(grbl_->MachinePosition(0), 240.0);

  // `slshadow merge` reads the device project like a simulated one: every view merged. With the
  // poses from the axis (--poses axis): three views 120 deg apart at this resolution overlap too
  // little for the pairwise registration, which leaves a sliding pair out (what that looks like is
  // multiview_cmd_merge_test's); here the reading of the project is under test.
  ASSERT_EQ(RunSlshadow({"merge", (dir_ / "scanned").string(), "--out", (dir_ / "model").string(),
                         "--poses", "axis"},
                        &err),
            0);
  const nlohmann::json report = ConfigNode::LoadFile(dir_ / "model" / "report.json").json();
  ASSERT_EQ(report["views"].size(), 3u);
  for (const auto& v : report["views"]) EXPECT_TRUE(v["merged"].get<bool>()) << v["name"];

  // Scanning into the same folder again without --resume: refused, nothing touched.
  EXPECT_NE(RunSlshadow(ScanArgs("scanned"), &err), 0);
  EXPECT_NE(err.find("already holds a project (pass --resume"), std::string::npos) << err;
  // --resume of a complete project keeps every view and moves nothing.
  ASSERT_EQ(RunSlshadow(
                [&] {
                  auto a = ScanArgs("scanned");
                  a.push_back("--resume");
                  return a;
                }(),
                &err),
            0);
  moves = 0;
  for (const std::string& line : grbl_->Lines()) moves += line.find("G53") != std::string::npos;
  EXPECT_EQ(moves, 3);
}

// A GRBL alarm while the table turns to the second view: one error naming the view and the
// turntable, the first view kept, and `slshadow scan --resume` (which unlocks the controller on
// opening, unlock: true) completes the project with the simulation's images.
TEST_F(ScanLoop, TurntableAlarmAtViewKLeavesAProjectThatResumeCompletes) {
  std::string message, device, view;
  try {
    ScanWithLibrary("alarm", [&](size_t index) {
      if (index == 0) grbl_->AlarmDuringNextMove(1, 0.5);  // hard limit halfway to view_01
    });
    ADD_FAILURE() << "the alarm did not stop the scan";
  } catch (const ScanError& e) {
    message = e.what();
    device = e.device();
    view = e.view();
  }
  std::printf("%s\n", message.c_str());
  EXPECT_EQ(view, "view_01");
  EXPECT_EQ(device, "turntable");
  EXPECT_NE(message.find("view 'view_01' (2 of 3, table 120.000 deg): turntable: "),
            std::string::npos)
      << message;
  EXPECT_NE(message.find(grbl_->port()), std::string::npos) << message;
  EXPECT_NE(message.find("ALARM:1"), std::string::npos) << message;
  EXPECT_NE(message.find("1 of 3 views complete"), std::string::npos) << message;
  EXPECT_NE(message.find("--resume"), std::string::npos) << message;
  {
    const ProjectManifest p = LoadProject(dir_ / "alarm");
    EXPECT_EQ(p.views[0].state, ViewState::kComplete);
    EXPECT_EQ(p.views[1].state, ViewState::kMissing);
    EXPECT_EQ(p.views[2].state, ViewState::kMissing);
  }
  EXPECT_EQ(grbl_->State(), "Alarm");

  std::string err;
  auto args = ScanArgs("alarm");
  args.push_back("--resume");
  ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
  EXPECT_EQ(DifferingImages("alarm"), 0);
  const ProjectManifest p = LoadProject(dir_ / "alarm");
  for (const ProjectView& v : p.views) EXPECT_EQ(v.state, ViewState::kComplete) << v.spec.name;
  EXPECT_EQ(p.provenance["runs"].size(), 2u);
}

// The right camera unplugged in the middle of the second view: one error naming the view and the
// camera, the view's frames staged; with the camera back, `slshadow scan --resume` continues the
// view at its first missing frame and completes the project with the simulation's images.
TEST_F(ScanLoop, CameraLostAtViewKLeavesAProjectThatResumeCompletes) {
  std::string message, device, view;
  try {
    ScanWithLibrary(
        "unplugged", [](size_t) {},
        [&](int view_index, int pattern) {
          if (view_index == 1 && pattern == 10 && fakes_[1]) fakes_[1]->Destroy();
        });
    ADD_FAILURE() << "the lost camera did not stop the scan";
  } catch (const ScanError& e) {
    message = e.what();
    device = e.device();
    view = e.view();
  }
  std::printf("%s\n", message.c_str());
  EXPECT_EQ(view, "view_01");
  EXPECT_EQ(device, "capture");
  EXPECT_NE(message.find("view 'view_01' (2 of 3, table 120.000 deg): capture: "),
            std::string::npos)
      << message;
  EXPECT_NE(message.find("right"), std::string::npos) << message;
  EXPECT_NE(message.find("at its first missing frame"), std::string::npos) << message;
  const fs::path staged = dir_ / "unplugged" / "views" / "view_01.partial";
  ASSERT_TRUE(fs::exists(staged / "journal.jsonl"));
  {
    const ProjectManifest p = LoadProject(dir_ / "unplugged");
    EXPECT_EQ(p.views[0].state, ViewState::kComplete);
    EXPECT_EQ(p.views[1].state, ViewState::kMissing);
  }

  fakes_[1] = MakeFakeCamera(1);  // plugged in again
  std::string err;
  auto args = ScanArgs("unplugged");
  args.push_back("--resume");
  ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
  EXPECT_EQ(DifferingImages("unplugged"), 0);
  const ProjectManifest p = LoadProject(dir_ / "unplugged");
  for (const ProjectView& v : p.views) EXPECT_EQ(v.state, ViewState::kComplete) << v.spec.name;
  EXPECT_TRUE(p.views[1].provenance["resumed"].get<bool>());
  // Continued at its first missing frame: the frames staged before the camera was lost were kept.
  const int before = p.views[1].provenance["images_before"].get<int>();
  EXPECT_GT(before, 0);
  EXPECT_LT(before, p.views[1].provenance["images"].get<int>());
  EXPECT_FALSE(p.views[2].provenance["resumed"].get<bool>());
}

// Bad input is refused before anything is written: a table view with a rig that has no axis, and
// a table view with a devices file whose turntable is backend none.
TEST_F(ScanLoop, RefusesTableViewsWithoutAxisOrTurntable) {
  std::string err;
  Rig no_axis = rig_;
  no_axis.turntable.reset();
  SaveRig(no_axis, dir_ / "rig_no_axis.yaml");
  auto args = ScanArgs("no_axis");
  args[2] = (dir_ / "rig_no_axis.yaml").string();
  EXPECT_NE(RunSlshadow(args, &err), 0);
  EXPECT_NE(err.find("view 'view_00': table_deg 0, but rig"), std::string::npos) << err;
  EXPECT_NE(err.find("slshadow calibrate turntable"), std::string::npos) << err;
  EXPECT_FALSE(fs::exists(dir_ / "no_axis"));

  std::string text;
  {
    std::ifstream in(devices_file_);
    text.assign(std::istreambuf_iterator<char>(in), {});
  }
  text = text.substr(0, text.find("turntable:")) + "turntable:\n  backend: none\n";
  std::ofstream(dir_ / "devices_none.yaml") << text;
  args = ScanArgs("no_table");
  args[4] = (dir_ / "devices_none.yaml").string();
  EXPECT_NE(RunSlshadow(args, &err), 0);
  EXPECT_NE(err.find("turntable: backend none cannot turn the table to view 'view_01' (120"),
            std::string::npos)
      << err;
  EXPECT_FALSE(fs::exists(dir_ / "no_table"));
}

}  // namespace
}  // namespace slshadow::multiview

int main(int argc, char** argv) {
  slshadow::testing::RunInPrivateNetwork(argc, argv);
  ::testing::InitGoogleTest(&argc, argv);
  return RUN_ALL_TESTS();
}
