// The faults of a multi-view scan (workflows/multiview/scan.h) with the real turntable protocol:
// a GRBL 1.1 emulator on a pseudo-terminal (the backend's termios path) and two replay cameras
// playing a simulated ImageSet (no projector; the sequencer checks the replayed frames as live
// ones), so every fault the issue names runs in a second and without a network. Each fault while
// the table turns to the second view must end in one ScanError naming the view, the turntable and
// its port, leave the first view complete and the others missing, and `slshadow scan --resume`
// (with the device fixed) must complete the project: every view's images equal the replayed
// ones, bit for bit. Also: a table that moves during a capture rejects the view; hand-placed
// views wait for the operator (q aborts, resumable); a manual turntable with --yes.
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include <fcntl.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include "apps/commands.h"
#include "capture/factory.h"
#include "capture/manual_turntable.h"
#include "core/camera_model.h"
#include "core/error.h"
#include "core/image_set.h"
#include "core/rig.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"
#include "sim/scene.h"
#include "sim/simulate.h"
#include "tests/capture/grbl_emulator.h"
#include "tests/capture/scaled_demo_rig.h"
#include "tests/multiview/scan_test_util.h"
#include "workflows/multiview/scan.h"
#include "workflows/multiview/turntable_scene.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {
namespace {

namespace fs = std::filesystem;
using capture::testing::GrblEmulator;

using slshadow::testing::HookedProjector;
using slshadow::testing::RunSlshadow;

fs::path TestDir(const std::string& name) {
  return slshadow::testing::ScanTestDir("scan_faults_", name);
}

class ScanFaults : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = TestDir(::testing::UnitTest::GetInstance()->current_test_info()->name());
    // The demo part on its turntable, the demo rig at 1/8 of its resolution.
    const TurntableSetup setup =
        MakeTurntableSetup(slshadow::testing::ScaledDemoRig(8),
                           LoadScene(fs::path(SLSHADOW_SOURCE_DIR) / "config/demo/scene.yaml"));
    PatternSpec spec =
        LoadPatternSpec(fs::path(SLSHADOW_SOURCE_DIR) / "config/patterns/graycode_phase.yaml");
    spec.projector_width = setup.rig.projector->model.width;
    spec.projector_height = setup.rig.projector->model.height;
    spec.Check();
    rig_file_ = dir_ / "rig.yaml";
    patterns_file_ = dir_ / "patterns.json";
    views_file_ = dir_ / "views.yaml";
    SaveRig(setup.rig, rig_file_);
    std::ofstream(patterns_file_) << PatternSpecToJson(spec).dump(2);
    SaveViews(FullTurnViews(3), views_file_);
    rig_ = LoadRig(rig_file_);
    spec_ = LoadPatternSpec(patterns_file_);
    views_ = LoadViews(views_file_);
    // The recording the replay cameras play (a simulated scan at table angle 0).
    SimulateOptions sim;
    sim.write_ground_truth = false;
    sim.writer.encoding = ImageEncoding::kPgm;
    SimulateScan(setup.scene, rig_, GeneratePatterns(spec_), PatternSpecToJson(spec_),
                 dir_ / "recorded", sim);
    grbl_ = std::make_unique<GrblEmulator>();
    WriteDevices("devices.yaml", "grbl");
  }

  // A devices file: replay cameras, no projector, the turntable of `backend` (grbl: the
  // emulator's port).
  fs::path WriteDevices(const std::string& name, const std::string& backend) {
    const fs::path file = dir_ / name;
    std::ofstream out(file);
    out << "format: slshadow-devices\nversion: 1\ncameras:\n";
    for (const char* camera : {"left", "right"}) {
      out << "  - name: " << camera
          << "\n    backend: replay\n    imageset: " << (dir_ / "recorded").string()
          << "\n    settings: {trigger: software}\n";
    }
    out << "projector:\n  backend: none\nturntable:\n  backend: " << backend << "\n";
    if (backend == "grbl") {
      out << "  port: " << grbl_->port()
          << "\n  tolerance_deg: 0.001\n  poll_interval_ms: 10\n  reply_timeout_ms: 500\n"
             "  move_timeout_ms: 1500\n  unlock: true\n";
    }
    return file;
  }

  // Scans `project` with the library through the devices of `devices_file`; on_view after each
  // view, before_show(view, pattern) before each pattern is shown.
  ScanSummary Scan(const std::string& project, const std::function<void(size_t)>& on_view,
                   const std::function<void(int, int)>& before_show, const ViewsFile& views,
                   ScanOptions options = {}, capture::Turntable* turntable = nullptr) {
    const capture::DevicesConfig devices = capture::LoadDevices(dir_ / "devices.yaml");
    capture::OpenedDevices opened = capture::OpenDevices(devices, rig_);
    const std::unique_ptr<capture::Turntable> table =
        turntable ? nullptr : capture::OpenTurntable(devices.turntable);
    HookedProjector projector(*opened.projector, before_show);
    ScanDevices d;
    d.cameras = opened.cameras;
    d.projector = &projector;
    d.turntable = turntable ? turntable : table.get();
    d.turntable_backend = devices.turntable.backend;
    d.turntable_tolerance_deg = devices.turntable.tolerance_deg;
    d.devices_file = (dir_ / "devices.yaml").string();
    options.sequencer.writer.encoding = ImageEncoding::kPgm;
    options.sequencer.writer.durable = false;
    options.sequencer.progress = false;
    options.on_view = [&](const std::string&, size_t index, bool) { on_view(index); };
    return ScanProject(rig_, spec_, views, d, dir_ / project, options);
  }

  // The ScanError of a scan of `project` (fails the test when there is none).
  ScanError ScanFault(
      const std::string& project, const std::function<void(size_t)>& on_view,
      const std::function<void(int, int)>& before_show = [](int, int) {}) {
    try {
      Scan(project, on_view, before_show, views_);
    } catch (const ScanError& e) {
      std::printf("%s\n", e.what());
      return e;
    }
    ADD_FAILURE() << "the scan of " << project << " ended without a fault";
    return ScanError("", "", "");
  }

  std::vector<std::string> ScanArgs(const std::string& project) const {
    return {"scan",
            "--rig",
            rig_file_.string(),
            "--devices",
            (dir_ / "devices.yaml").string(),
            "--patterns",
            patterns_file_.string(),
            "--views",
            views_file_.string(),
            "--out",
            (dir_ / project).string(),
            "--encoding",
            "pgm",
            "--quiet",
            "--yes"};
  }

  // Images of the project's complete views that differ from the recording.
  int DifferingImages(const std::string& project) {
    const ImageSet recorded = ImageSet::Open(dir_ / "recorded");
    const ProjectManifest p = LoadProject(dir_ / project);
    int differing = 0;
    for (const ProjectView& v : p.views) {
      const ImageSet scanned = ImageSet::Open(dir_ / project / v.Folder());
      EXPECT_EQ(scanned.PatternCount(), recorded.PatternCount());
      for (const std::string& camera : recorded.CameraNames()) {
        for (int i = 0; i < recorded.PatternCount(); ++i) {
          const cv::Mat a = scanned.Load(camera, i), b = recorded.Load(camera, i);
          differing += !(a.size() == b.size() && cv::norm(a, b, cv::NORM_INF) == 0);
        }
      }
    }
    return differing;
  }

  // The project after a fault at view_01: view_00 complete, the others missing. Then, with the
  // turntable replaced by a fresh controller (a new port), `slshadow scan --resume` completes it
  // with the recording's images.
  void ExpectResumableAndResume(const std::string& project) {
    {
      const ProjectManifest p = LoadProject(dir_ / project);
      ASSERT_EQ(p.views.size(), 3u);
      EXPECT_EQ(p.views[0].state, ViewState::kComplete);
      EXPECT_EQ(p.views[1].state, ViewState::kMissing);
      EXPECT_EQ(p.views[2].state, ViewState::kMissing);
    }
    grbl_ = std::make_unique<GrblEmulator>();
    WriteDevices("devices.yaml", "grbl");
    std::string err;
    auto args = ScanArgs(project);
    args.push_back("--resume");
    ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
    const ProjectManifest p = LoadProject(dir_ / project);
    for (const ProjectView& v : p.views) {
      EXPECT_EQ(v.state, ViewState::kComplete) << v.spec.name;
      EXPECT_NEAR(v.provenance["read_back_deg"].get<double>(), *v.spec.table_deg, 1e-3);
    }
    EXPECT_EQ(DifferingImages(project), 0);
  }

  void ExpectTurntableFaultAtView1(const ScanError& e, const std::string& words) {
    const std::string what = e.what();
    EXPECT_EQ(e.view(), "view_01");
    EXPECT_EQ(e.device(), "turntable");
    EXPECT_NE(what.find("scan: view 'view_01' (2 of 3, table 120.000 deg): turntable: "),
              std::string::npos)
        << what;
    EXPECT_NE(what.find(port_at_fault_), std::string::npos) << what;
    EXPECT_NE(what.find(words), std::string::npos) << what;
    EXPECT_NE(what.find("1 of 3 views complete"), std::string::npos) << what;
    EXPECT_NE(what.find("run the same command with --resume (it continues at view 'view_01')"),
              std::string::npos)
        << what;
  }

  fs::path dir_, rig_file_, patterns_file_, views_file_;
  Rig rig_;
  PatternSpec spec_;
  ViewsFile views_;
  std::unique_ptr<GrblEmulator> grbl_;
  std::string port_at_fault_;
};

TEST_F(ScanFaults, ErrorOnTheMove) {
  port_at_fault_ = grbl_->port();
  grbl_->ErrorOn("G90 G53 G0 X120", 20);
  ExpectTurntableFaultAtView1(ScanFault("p", [](size_t) {}), "error:20");
  ExpectResumableAndResume("p");
}

TEST_F(ScanFaults, AlarmMidMove) {
  port_at_fault_ = grbl_->port();
  const ScanError e = ScanFault("p", [&](size_t index) {
    if (index == 0) grbl_->AlarmDuringNextMove(1, 0.5);
  });
  ExpectTurntableFaultAtView1(e, "ALARM:1");
  ExpectResumableAndResume("p");
}

TEST_F(ScanFaults, MoveThatNeverReachesItsTarget) {
  port_at_fault_ = grbl_->port();
  const ScanError e = ScanFault("p", [&](size_t index) {
    if (index == 0) grbl_->StopMovesShort(0.5);
  });
  ExpectTurntableFaultAtView1(e, "move to 120.000 deg");
  ExpectResumableAndResume("p");
}

TEST_F(ScanFaults, LostReply) {
  port_at_fault_ = grbl_->port();
  grbl_->DropReplyTo("G90 G53 G0 X120");
  ExpectTurntableFaultAtView1(ScanFault("p", [](size_t) {}), "move to 120.000 deg");
  ExpectResumableAndResume("p");
}

TEST_F(ScanFaults, PortVanishes) {
  port_at_fault_ = grbl_->port();
  const ScanError e = ScanFault("p", [&](size_t index) {
    if (index == 0) grbl_->Vanish();  // the USB serial adapter unplugged after the first view
  });
  ExpectTurntableFaultAtView1(e, "move to 120.000 deg");
  ExpectResumableAndResume("p");
}

// The table turned by 0.5 deg while view_01's frames were taken: the view is moved aside (never
// merged) and the scan stops; the resume turns the table back and scans the view again.
TEST_F(ScanFaults, TableMovedDuringTheCaptureRejectsTheView) {
  port_at_fault_ = grbl_->port();
  const ScanError e = ScanFault(
      "p", [](size_t) {},
      [&](int view, int pattern) {
        if (view == 1 && pattern == 5) grbl_->SetMachinePosition(0, 120.5);
      });
  ExpectTurntableFaultAtView1(e, "moved (read back 120.0000 deg before, 120.5000 deg after");
  EXPECT_TRUE(fs::exists(dir_ / "p" / "views" / "view_01.rejected-1" / "manifest.json"));
  EXPECT_FALSE(fs::exists(dir_ / "p" / "views" / "view_01"));
  ExpectResumableAndResume("p");
  EXPECT_TRUE(fs::exists(dir_ / "p" / "views" / "view_01.rejected-1"));  // kept as evidence
}

// Views placed by hand: the operator is asked before each and answers Enter; "q" interrupts the
// scan with the views so far complete, and a resume asks only for the missing ones.
TEST_F(ScanFaults, HandPlacedViewsWaitForTheOperator) {
  ViewsFile hand;
  for (const char* name : {"top", "side", "bottom"}) hand.views.push_back({name, {}, {}});
  std::istringstream first("\n\nq\n");
  std::ostringstream prompts;
  ScanOptions options;
  options.input = &first;
  options.prompt = &prompts;
  ScanSummary s = Scan(
      "hand", [](size_t) {}, [](int, int) {}, hand, options);
  EXPECT_TRUE(s.interrupted);
  EXPECT_FALSE(s.complete);
  EXPECT_EQ(s.captured.size(), 2u);
  EXPECT_NE(prompts.str().find("scan: view 'bottom' (3 of 3, placed by hand): place the part for "
                               "this view by hand, then press Enter (q aborts)"),
            std::string::npos)
      << prompts.str();
  for (const std::string& line : grbl_->Lines())
    EXPECT_EQ(line.find("G53"), std::string::npos) << line;  // the table never turned
  std::istringstream second("\n");
  options.input = &second;
  options.resume = true;
  s = Scan(
      "hand", [](size_t) {}, [](int, int) {}, hand, options);
  EXPECT_TRUE(s.complete);
  ASSERT_EQ(s.kept.size(), 2u);
  ASSERT_EQ(s.captured.size(), 1u);
  EXPECT_EQ(s.captured[0].name, "bottom");
  const ProjectManifest p = LoadProject(dir_ / "hand");
  EXPECT_EQ(p.views[2].provenance["placed_by"], "operator (Enter)");
  EXPECT_TRUE(p.views[2].provenance["read_back_deg"].is_null());
  EXPECT_EQ(DifferingImages("hand"), 0);
}

// A manual turntable with --yes: the prompts are printed, the angles taken as set, and the
// read-back angle is the confirmed one.
TEST_F(ScanFaults, ManualTurntableWithYes) {
  WriteDevices("devices.yaml", "manual");
  std::string err;
  auto args = ScanArgs("manual");
  args.erase(std::find(args.begin(), args.end(), "--quiet"));
  ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
  EXPECT_NE(err.find("turn the table to 240.000 deg"), std::string::npos) << err;
  const ProjectManifest p = LoadProject(dir_ / "manual");
  for (const ProjectView& v : p.views) {
    EXPECT_EQ(v.provenance["turntable_backend"], "manual");
    EXPECT_EQ(v.provenance["read_back_deg"].get<double>(), *v.spec.table_deg);
  }
  EXPECT_EQ(DifferingImages("manual"), 0);
  // A resume of another kind of project is refused, naming the field.
  ASSERT_EQ(RunSlshadow(args, &err), 1);
  EXPECT_NE(err.find("already holds a project"), std::string::npos) << err;
  args.push_back("--resume");
  SaveViews(FullTurnViews(4), views_file_);
  EXPECT_EQ(RunSlshadow(args, &err), 1);
  EXPECT_NE(err.find("project.json: views (their number) differs from this run's"),
            std::string::npos)
      << err;
}

// The operator of a manual table answers q when asked to turn it to the second view: the scan
// stops as interrupted (not as a device fault) with the first view kept, and resumes.
TEST_F(ScanFaults, ManualTurntableAbortIsAnInterruption) {
  WriteDevices("devices.yaml", "manual");
  int answers[2];
  ASSERT_EQ(pipe(answers), 0);
  const std::string typed = "\nq\n";  // Enter at the zero mark; q at 120 deg (0 asks nothing)
  ASSERT_EQ(write(answers[1], typed.data(), typed.size()), static_cast<ssize_t>(typed.size()));
  close(answers[1]);
  const int prompts = open("/dev/null", O_WRONLY);
  capture::TurntableConfig config;
  config.backend = "manual";
  capture::ManualTurntable table(config, capture::ManualTurntableIo{answers[0], prompts});
  std::ostringstream lines;
  ScanOptions options;
  options.prompt = &lines;
  const ScanSummary s = Scan(
      "aborted", [](size_t) {}, [](int, int) {}, views_, options, &table);
  close(answers[0]);
  close(prompts);
  EXPECT_TRUE(s.interrupted);
  EXPECT_FALSE(s.complete);
  ASSERT_EQ(s.captured.size(), 1u);
  EXPECT_NE(lines.str().find("view 'view_01' (2 of 3, table 120.000 deg): turntable: "),
            std::string::npos)
      << lines.str();
  std::string err;
  auto args = ScanArgs("aborted");
  args.push_back("--resume");
  ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
  EXPECT_EQ(DifferingImages("aborted"), 0);
}

// --strict: each view is reconstructed after its capture. With the rig file the images were taken
// with every view passes (and says so in its provenance); with a rig file whose left camera's
// principal point is off by a pixel (a bumped rig) the first view is rejected, moved aside, and
// the scan stops naming the view, the rig and the calibration check.
TEST_F(ScanFaults, StrictRejectsTheViewWhereTheRigNoLongerFits) {
  std::string err;
  auto args = ScanArgs("strict");
  args.push_back("--strict");
  ASSERT_EQ(RunSlshadow(args, &err), 0) << err;
  for (const ProjectView& v : LoadProject(dir_ / "strict").views) {
    EXPECT_EQ(v.provenance["strict"]["mode"], "projector") << v.spec.name;
    EXPECT_TRUE(v.provenance["strict"]["violations"].empty()) << v.provenance.dump();
  }

  Rig bumped = rig_;
  bumped.cameras[0].model.params[CameraModel::kCx] += 1.0;
  bumped.cameras[0].model.params[CameraModel::kCy] += 1.0;
  SaveRig(bumped, dir_ / "bumped.yaml");
  args = ScanArgs("strict_bumped");
  args[2] = (dir_ / "bumped.yaml").string();
  args.push_back("--strict");
  EXPECT_EQ(RunSlshadow(args, &err), 1);
  EXPECT_NE(err.find("scan: view 'view_00' (1 of 3, table 0.000 deg): rig: --strict: "),
            std::string::npos)
      << err;
  EXPECT_NE(err.find("left-projector: the calibration check warns"), std::string::npos) << err;
  EXPECT_NE(err.find("needs a new calibration"), std::string::npos) << err;
  EXPECT_TRUE(fs::exists(dir_ / "strict_bumped" / "views" / "view_00.rejected-1"));
  EXPECT_EQ(LoadProject(dir_ / "strict_bumped").views[0].state, ViewState::kMissing);
}

// `slshadow turntable status|home|move`: what an engineer runs to check the table before a scan.
TEST_F(ScanFaults, TurntableCommand) {
  const std::string devices = (dir_ / "devices.yaml").string();
  ::testing::internal::CaptureStdout();
  std::string err;
  EXPECT_EQ(RunSlshadow({"turntable", "move", "--devices", devices, "--deg", "90"}, &err), 0);
  EXPECT_EQ(RunSlshadow({"turntable", "home", "--devices", devices}, &err), 0);  // homing: false
  EXPECT_EQ(RunSlshadow({"turntable", "status", "--devices", devices}, &err), 0);
  const std::string out = ::testing::internal::GetCapturedStdout();
  EXPECT_NE(out.find("grbl on " + grbl_->port() + " (axis X): idle at 90.0000 deg"),
            std::string::npos)
      << out;
  EXPECT_EQ(grbl_->MachinePosition(0), 90.0);
  EXPECT_NE(RunSlshadow({"turntable", "move", "--devices", devices}, &err), 0);
  EXPECT_NE(err.find("--deg is required"), std::string::npos) << err;
  grbl_->ErrorOn("G90 G53 G0 X45", 20);
  EXPECT_NE(RunSlshadow({"turntable", "move", "--devices", devices, "--deg", "45"}, &err), 0);
  EXPECT_NE(err.find("move to 45.000 deg: \"G90 G53 G0 X45.0000\" answered error:20"),
            std::string::npos)
      << err;
}

}  // namespace
}  // namespace slshadow::multiview
