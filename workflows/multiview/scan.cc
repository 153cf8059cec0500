#include "workflows/multiview/scan.h"

#include <chrono>
#include <cmath>
#include <iostream>

#include "capture/factory.h"
#include "capture/pattern_sequence_capture.h"
#include "core/config.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "core/string_printf.h"
#include "reconstruct/reconstruct_image_set.h"

namespace slshadow::multiview {
namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

constexpr const char* kGenerator = "slshadow scan";

double SecondsSince(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

nlohmann::json Deg(std::optional<double> deg) {
  return deg ? nlohmann::json(*deg) : nlohmann::json(nullptr);
}

// "view 'view_07' (8 of 12, table 210.000 deg)".
std::string ViewLabel(const ProjectView& view, size_t index, size_t count) {
  return StringPrintf("view '%s' (%zu of %zu, %s)", view.spec.name.c_str(), index + 1, count,
                      view.spec.OnTable()
                          ? StringPrintf("table %.3f deg", *view.spec.table_deg).c_str()
                          : "placed by hand");
}

// Why an existing project cannot be continued by this scan, or empty.
std::string ResumeMismatch(const ProjectManifest& project, const Rig& rig,
                           const nlohmann::json& patterns, const ViewsFile& views,
                           const std::string& encoding) {
  const std::string generator = project.provenance.value("generator", "");
  if (generator != kGenerator)
    return "provenance.generator ('" + generator + "': not a device scan)";
  const std::string inputs = ProjectInputsMismatch(project, rig, patterns, views);
  if (!inputs.empty()) return inputs;
  if (project.provenance.value("encoding", "") != encoding) return "provenance.encoding";
  return "";
}

// The first views/<name>.rejected-N that does not exist.
fs::path RejectView(const fs::path& project_dir, const ProjectView& view) {
  std::error_code ec;
  for (int n = 1;; ++n) {
    const fs::path to = project_dir / "views" / (view.spec.name + ".rejected-" + std::to_string(n));
    if (fs::exists(to, ec)) continue;
    fs::rename(project_dir / view.Folder(), to, ec);
    SLSHADOW_THROW_IF(ec, (project_dir / view.Folder()).string(), ": cannot move aside to ",
                      to.string(), ": ", ec.message());
    return to;
  }
}

bool Faulty(capture::TurntableState state) {
  return state == capture::TurntableState::kAlarm || state == capture::TurntableState::kFault;
}

}  // namespace

void ScanOptions::Check() const {
  sequencer.Check();
  strict.Check();
  SLSHADOW_THROW_IF(!provenance.is_object(), "scan: provenance must be a JSON object");
}

std::string ScanSummary::BriefReport() const {
  int images = 0, retries = 0;
  for (const ScanViewReport& v : captured) {
    images += v.capture.images_stored;
    retries += v.capture.retries;
  }
  return StringPrintf("views captured %zu, kept %zu; %d images stored, %d retries; %s; %.1f s",
                      captured.size(), kept.size(), images, retries,
                      complete      ? "project complete"
                      : interrupted ? "interrupted (resumable)"
                                    : "incomplete",
                      seconds);
}

void CheckScanInputs(const Rig& rig, const PatternSpec& spec, const ViewsFile& views,
                     const std::string& turntable_backend, const std::string& devices_file) {
  views.Check("views");
  rig.Check("rig '" + rig.name + "'");
  CheckProjectorSize(rig, spec, "pattern spec", "rig '" + rig.name + "'");
  for (const ViewSpec& v : views.views) {
    if (!v.OnTable()) continue;
    SLSHADOW_THROW_IF(!rig.turntable, "view '", v.name, "': table_deg ", *v.table_deg,
                      ", but rig '", rig.name,
                      "' has no turntable axis (rig.turntable): measure it with `slshadow "
                      "calibrate turntable` first, or place the views by hand (no table_deg)");
    SLSHADOW_THROW_IF(turntable_backend == "none" && *v.table_deg != 0, devices_file,
                      ": turntable: backend none cannot turn the table to view '", v.name, "' (",
                      *v.table_deg,
                      " deg); add a turntable: entry with backend grbl or manual (docs/formats.md "
                      "\"Devices YAML\")");
  }
}

ScanSummary ScanProject(const Rig& rig, const PatternSpec& spec, const ViewsFile& views,
                        const ScanDevices& devices, const fs::path& project_dir,
                        const ScanOptions& options) {
  const auto t_start = Clock::now();
  options.Check();
  const std::string devices_file = devices.devices_file.empty() ? "devices" : devices.devices_file;
  CheckScanInputs(rig, spec, views, devices.turntable_backend, devices_file);
  SLSHADOW_THROW_IF(devices.cameras.empty(), devices_file,
                    ": no camera of the rig has a device entry; a scan needs at least one");
  SLSHADOW_THROW_IF((devices.projector == nullptr) == (devices.sequence_projector == nullptr),
                    "scan: exactly one projector is needed (shown pattern by pattern, or running "
                    "the sequence itself)");
  SLSHADOW_THROW_IF(!(devices.turntable_tolerance_deg > 0), devices_file,
                    ": turntable.tolerance_deg: must be > 0 (got ", devices.turntable_tolerance_deg,
                    ")");
  for (const ViewSpec& v : views.views) {
    SLSHADOW_THROW_IF(v.OnTable() && !devices.turntable, devices_file, ": view '", v.name,
                      "' is on the table (", *v.table_deg, " deg), but no turntable is open");
  }

  const nlohmann::json patterns = PatternSpecToJson(spec);
  const std::string encoding = ToString(options.sequencer.writer.encoding);
  const std::string turntable_name =
      devices.turntable ? devices.turntable->Describe() : std::string("none");
  nlohmann::json run = options.provenance;
  run["started"] = UtcTimestamp();
  run["devices"] = devices.devices_file;
  run["turntable"] = turntable_name;
  std::error_code ec;
  nlohmann::json provenance = options.provenance;
  provenance["generator"] = kGenerator;
  provenance["devices"] = devices.devices_file;
  provenance["encoding"] = encoding;
  provenance["turntable"] = turntable_name;
  provenance["turntable_backend"] = devices.turntable_backend;
  provenance["runs"] = nlohmann::json::array({run});
  // A complete view whose folder was lost since is scanned again below.
  StartedProject started =
      StartOrResumeProject(project_dir, rig, patterns, views, provenance, options.resume,
                           "scan its missing views", [&](const ProjectManifest& stored) {
                             return ResumeMismatch(stored, rig, patterns, views, encoding);
                           });
  ProjectManifest& project = started.manifest;
  if (started.resumed) {
    project.provenance["runs"].push_back(run);
    SaveProject(project, project_dir);
  }

  std::istream& input = options.input ? *options.input : std::cin;
  std::ostream& out = options.prompt ? *options.prompt : std::cerr;
  ScanSummary summary;
  summary.project = project_dir;
  const size_t count = project.views.size();
  const auto complete_views = [&] {
    size_t n = 0;
    for (const ProjectView& v : project.views) n += v.state == ViewState::kComplete;
    return n;
  };
  // A fault during view `index`: the project stays as it is (this view missing, its frames
  // staged), and the message says so.
  const auto fault = [&](size_t index, const std::string& device, const std::string& what) {
    const ProjectView& view = project.views[index];
    const bool staged =
        fs::exists(ResumableImageSetWriter::StagingDirFor(project_dir / view.Folder()), ec);
    return ScanError(
        StringPrintf("scan: %s: %s: %s; %zu of %zu views complete in %s, which is resumable: fix "
                     "the %s and run the same command with --resume (it continues at view '%s'%s)",
                     ViewLabel(view, index, count).c_str(), device.c_str(), what.c_str(),
                     complete_views(), count, project_dir.string().c_str(),
                     device == "capture" ? "camera or projector"
                     : device == "rig"   ? "cause (a rig file that no longer fits needs a new "
                                           "calibration, and then a new project)"
                                         : device.c_str(),
                     view.spec.name.c_str(), staged ? ", at its first missing frame" : ""),
        view.spec.name, device);
  };
  const auto mark_complete = [&](ProjectView& view, const fs::path& dir) {
    view.state = ViewState::kComplete;
    view.source = "device";
    const ImageSet set = ImageSet::Open(dir);
    view.completed = set.created();
    // Interrupted between the ImageSet's commit and the project's update: the move's provenance
    // is in the ImageSet (extra.view).
    if (view.provenance.is_null() && set.extra().contains("view"))
      view.provenance = set.extra()["view"];
    SaveProject(project, project_dir);
  };

  bool homed = !options.home;
  for (size_t i = 0; i < count; ++i) {
    ProjectView& view = project.views[i];
    const fs::path dir = project_dir / view.Folder();
    if (fs::exists(dir / "manifest.json", ec)) {
      if (view.state != ViewState::kComplete) mark_complete(view, dir);
      summary.kept.push_back(view.spec.name);
      if (options.on_view) options.on_view(view.spec.name, i, false);
      continue;
    }
    if (view.state == ViewState::kComplete) {  // its folder was removed: scan it again
      view.state = ViewState::kMissing;
      view.provenance = nullptr;
      SaveProject(project, project_dir);
    }
    if (options.sequencer.stop && options.sequencer.stop->load()) {
      summary.interrupted = true;
      break;
    }
    const std::string label = ViewLabel(view, i, count);
    ScanViewReport report;
    report.name = view.spec.name;
    report.index = i;
    report.commanded_deg = view.spec.table_deg;
    nlohmann::json provenance = {{"name", view.spec.name},
                                 {"table_deg", Deg(view.spec.table_deg)},
                                 {"devices", devices.devices_file},
                                 {"move_started", UtcTimestamp()}};

    // 1. The part to the view: the table turns, or the operator places it.
    const auto move_t0 = Clock::now();
    if (view.spec.OnTable()) {
      capture::Turntable& table = *devices.turntable;
      provenance["turntable"] = table.Describe();
      provenance["turntable_backend"] = devices.turntable_backend;
      try {
        if (!homed) {
          out << "scan: referencing the turntable (" << table.Describe() << ")" << std::endl;
          table.Home();
          homed = true;
        }
        out << "scan: " << label << ": turning the table" << std::endl;
        table.MoveTo(*view.spec.table_deg);
      } catch (const capture::TurntableError& e) {
        // The operator of a manual table said q (or its input closed): a stop, not a fault.
        if (e.fault() == capture::TurntableFault::kAborted) {
          out << "scan: " << label << ": " << e.what() << std::endl;
          summary.interrupted = true;
          break;
        }
        throw fault(i, "turntable", e.what());
      }
      const capture::TurntableStatus status = table.Status();
      if (Faulty(status.state)) {
        throw fault(i, "turntable",
                    table.Describe() + ": after the move to " +
                        StringPrintf("%.3f deg", *view.spec.table_deg) + ": state " +
                        ToString(status.state) + " (" + status.detail + ")");
      }
      report.read_back_deg = status.position_deg;
    } else {
      out << "scan: " << label << ": place the part for this view by hand"
          << (view.spec.placed_on_table ? " on the table (the table stands still)" : "")
          << (options.confirm_hand_views ? ", then press Enter (q aborts)" : "") << std::endl;
      if (options.confirm_hand_views) {
        std::string line;
        if (!std::getline(input, line) || line == "q" || line == "quit" || line == "abort") {
          summary.interrupted = true;
          break;
        }
      }
      provenance["placed_by"] = options.confirm_hand_views ? "operator (Enter)" : "--yes";
    }
    report.move_seconds = SecondsSince(move_t0);
    provenance["read_back_deg"] = Deg(report.read_back_deg);
    provenance["arrived"] = UtcTimestamp();
    provenance["move_s"] = report.move_seconds;

    // 2. One ImageSet, staged in views/<name>.partial and continued from it.
    capture::SequencerOptions sequencer = options.sequencer;
    sequencer.writer.resume = true;  // continue the staged frames of an earlier run, if any
    sequencer.writer.overwrite = false;
    if (!sequencer.extra.is_object()) sequencer.extra = nlohmann::json::object();
    sequencer.extra["view"] = provenance;
    nlohmann::json cameras = nlohmann::json::object();
    for (const capture::CaptureCamera& c : devices.cameras)
      cameras[c.name] = c.camera ? c.camera->Info().serial : "";
    provenance["cameras"] = cameras;
    provenance["capture_started"] = UtcTimestamp();
    const auto capture_t0 = Clock::now();
    try {
      report.capture = capture::CaptureImageSet(rig, spec, devices.cameras, devices.projector,
                                                devices.sequence_projector, dir, sequencer);
    } catch (const Error& e) {
      throw fault(i, "capture", e.what());
    }
    if (report.capture.interrupted) {
      summary.interrupted = true;
      break;
    }
    provenance["capture_completed"] = UtcTimestamp();
    provenance["capture_s"] = SecondsSince(capture_t0);
    provenance["resumed"] = report.capture.resumed;
    provenance["images"] = report.capture.images_total;
    provenance["images_before"] = report.capture.images_before;
    provenance["retries"] = report.capture.retries;

    // 3. The table must not have moved while the frames were taken.
    if (view.spec.OnTable()) {
      capture::Turntable& table = *devices.turntable;
      const capture::TurntableStatus after = table.Status();
      provenance["read_back_after_deg"] = after.position_deg;
      const double drift = std::abs(after.position_deg - *report.read_back_deg);
      if (Faulty(after.state) || drift > devices.turntable_tolerance_deg) {
        const fs::path aside = RejectView(project_dir, view);
        throw fault(
            i, "turntable",
            StringPrintf(
                "%s: during the capture the table %s (read back %.4f deg before, "
                "%.4f deg after; tolerance %.4f deg), so the view's images are "
                "not of one pose: moved aside to %s, not merged",
                table.Describe().c_str(),
                Faulty(after.state)
                    ? ("went to state " + ToString(after.state) + " (" + after.detail + ")").c_str()
                    : "moved",
                *report.read_back_deg, after.position_deg, devices.turntable_tolerance_deg,
                aside.string().c_str()));
      }
    }
    // 4. Strict mode: the view's own reconstruction must confirm the rig file.
    if (options.strict.enabled) {
      ImageSetReconstructOptions reconstruct;
      reconstruct.mode = DefaultReconstructMode(rig);
      std::vector<std::string> violations;
      try {
        violations = StrictViolations(
            ReconstructImageSet(ImageSet::Open(dir), reconstruct).summaries, options.strict);
      } catch (const Error& e) {
        violations = {std::string("the view cannot be reconstructed: ") + e.what()};
      }
      provenance["strict"] = {{"mode", ToString(reconstruct.mode)}, {"violations", violations}};
      if (!violations.empty()) {
        std::string why;
        for (const std::string& v : violations) why += (why.empty() ? "" : "; ") + v;
        const fs::path aside = RejectView(project_dir, view);
        throw fault(
            i, "rig",
            "--strict: " + why + "; the view is moved aside to " + aside.string() + ", not merged");
      }
    }
    view.provenance = provenance;
    mark_complete(view, dir);
    out << "scan: " << label << ": "
        << (report.read_back_deg ? StringPrintf("table at %.4f deg, ", *report.read_back_deg) : "")
        << report.capture.BriefReport() << std::endl;
    summary.captured.push_back(std::move(report));
    if (options.on_view) options.on_view(view.spec.name, i, true);
  }
  summary.complete = complete_views() == count;
  summary.seconds = SecondsSince(t_start);
  return summary;
}

}  // namespace slshadow::multiview
