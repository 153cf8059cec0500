// A multi-view scan with real devices (`slshadow scan`): for each view of a views file, the
// turntable turns the part to the view's commanded angle (or the operator places the part by hand
// and presses Enter), the sequencer (capture/sequencer.h) captures one validated ImageSet, and the
// project folder (workflows/multiview/views.h; docs/formats.md "Multi-view project") records each
// view's provenance: commanded and read-back table angles, the table and cameras that took it,
// and when. `slshadow merge` reads the result like a simulated project.
//
// Order per view: move (grbl: G53 G0 and wait until Idle within tolerance; manual: "set the table
// to X deg, press Enter"; hand-placed: "move the part, press Enter") -> read back the table ->
// capture into views/<name>/ (staged in views/<name>.partial/) -> read back the table again: a
// table that moved, raised an alarm or vanished during the capture rejects the view (its ImageSet
// is moved aside to views/<name>.rejected-N/, never merged) -> project.json with the view complete.
//
// Resumable: project.json is written first (every view missing) and rewritten after each view;
// a run with `resume` skips the complete views and continues a view's staged frames at its first
// missing one (after moving the table to the view's angle again). A device fault (a turntable
// error, alarm, timeout or lost port; a camera or projector failing its frames) ends the scan with
// one ScanError naming the view and the device; everything written stays, and a resume with the
// same inputs completes the project as an uninterrupted scan would have.
#pragma once

#include <cstddef>
#include <filesystem>
#include <functional>
#include <iosfwd>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "capture/sequence_projector.h"
#include "capture/sequencer.h"
#include "capture/turntable.h"
#include "core/error.h"
#include "core/rig.h"
#include "patterns/pattern_spec.h"
#include "reconstruct/strict_policy.h"
#include "workflows/multiview/views.h"

namespace slshadow::multiview {

// The devices a scan uses, opened by the caller (capture/factory.h OpenDevices, OpenTurntable);
// none are owned.
struct ScanDevices {
  std::vector<capture::CaptureCamera> cameras;
  // Exactly one of the two: a projector shown pattern by pattern, or one that runs the sequence
  // itself and triggers the cameras (a LightCrafter in pattern-sequence mode).
  capture::Projector* projector = nullptr;
  capture::SequenceProjector* sequence_projector = nullptr;
  // The turntable; needed when a view to scan is on the table (backend none turns only to 0).
  capture::Turntable* turntable = nullptr;
  std::string turntable_backend = "none";  // "grbl", "manual", "none" (provenance)
  // A table whose read-back angle after a view's capture differs from the one before by more than
  // this (degrees) moved during the capture: the view is rejected. > 0.
  double turntable_tolerance_deg = 0.01;
  std::string devices_file;  // provenance and messages
};

struct ScanOptions {
  // Per view: the sequencer's options; writer.resume and writer.overwrite are set by the scan
  // (resume continues a view's staged frames; a complete view is never overwritten), and extra
  // gets the view's provenance under "view".
  capture::SequencerOptions sequencer;
  // Continue an existing project (same rig, pattern spec, views and encoding; refused otherwise,
  // naming what differs). Without it, a folder that holds anything is refused.
  bool resume = false;
  // Home() the turntable before the first table view this run scans (grbl: the homing cycle when
  // the devices file enables it; manual: the operator sets the zero mark).
  bool home = true;
  // Hand-placed views: ask the operator and wait for Enter (false: `--yes`, the part is taken as
  // placed). A line "q", "quit" or "abort", or the input closing, interrupts the scan (resumable).
  bool confirm_hand_views = true;
  std::istream* input = nullptr;   // the operator's answers; null: std::cin
  std::ostream* prompt = nullptr;  // prompts and per-view lines; null: std::cerr
  // Added to the project's provenance (e.g. {"command": ..., "views_file": ...}).
  nlohmann::json provenance = nlohmann::json::object();
  // Strict mode (`--strict`, reconstruct/strict_policy.h): after each view's capture the view is
  // reconstructed as `slshadow reconstruct --strict` does (the rig's default mode) and a
  // calibration-check warning, a check that cannot run or too few points reject the view (moved
  // aside to views/<name>.rejected-N/) and stop the scan with a ScanError (device "rig"): a rig
  // bumped during a scan is caught at the view where it happened, not after the last view.
  StrictOptions strict;
  // Called after each view is captured or found complete.
  std::function<void(const std::string& name, size_t index, bool captured)> on_view;
  void Check() const;  // throws slshadow::Error naming the bad field
};

// One view this run captured.
struct ScanViewReport {
  std::string name;
  size_t index = 0;
  std::optional<double> commanded_deg;  // nullopt: placed by hand
  std::optional<double> read_back_deg;  // the table's reported angle after the move
  double move_seconds = 0;              // turning the table (or waiting for the operator)
  capture::CaptureSummary capture;
};

struct ScanSummary {
  std::filesystem::path project;
  std::vector<ScanViewReport> captured;  // views captured (or completed) by this run, in order
  std::vector<std::string> kept;         // views already complete, kept untouched
  bool interrupted = false;              // stopped by options.sequencer.stop or the operator
  bool complete = false;                 // every view of the project is complete
  double seconds = 0;
  std::string BriefReport() const;
};

// What a scan fault was: which view, which device, and how the project was left.
class ScanError : public Error {
 public:
  ScanError(const std::string& message, std::string view, std::string device)
      : Error(message), view_(std::move(view)), device_(std::move(device)) {}
  const std::string& view() const { return view_; }
  // "turntable", "capture" (a camera or the projector; the message names it) or "rig" (strict
  // mode: the view's reconstruction does not confirm the rig file).
  const std::string& device() const { return device_; }

 private:
  std::string view_, device_;
};

// The input checks ScanProject makes first, for a caller that opens the devices afterwards: valid
// views and rig, the pattern spec of the rig's projector size, table views only with the rig's
// turntable axis and a turntable backend that can turn to them ("none": only 0 deg). Throws
// slshadow::Error naming the view, the file and the field.
void CheckScanInputs(const Rig& rig, const PatternSpec& spec, const ViewsFile& views,
                     const std::string& turntable_backend, const std::string& devices_file);

// Scans every view of `views` that `project_dir` does not hold complete. Throws slshadow::Error on
// bad input before anything is written (a table view without a turntable axis in the rig or
// without a turntable that can turn to it, a pattern spec of another projector size, a
// project made with other inputs), and ScanError on a device fault during the scan, with the
// project left resumable. Returns interrupted = true on Ctrl-C (options.sequencer.stop) or an
// operator's abort (q at a hand-placed view's prompt or at a manual table's, kAborted).
ScanSummary ScanProject(const Rig& rig, const PatternSpec& spec, const ViewsFile& views,
                        const ScanDevices& devices, const std::filesystem::path& project_dir,
                        const ScanOptions& options);

}  // namespace slshadow::multiview
