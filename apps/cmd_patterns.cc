// slshadow patterns generate SPEC --out DIR
// slshadow patterns show SPEC
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>

#include "apps/commands.h"
#include "core/error.h"
#include "core/file_util.h"
#include "core/image_set.h"
#include "patterns/codec.h"
#include "patterns/pattern_spec.h"

namespace slshadow::app {

namespace {

std::string FrameFileName(int index, int count) {
  char name[32];
  std::snprintf(name, sizeof(name), count <= 100 ? "pattern_%02d.png" : "pattern_%03d.png", index);
  return name;
}

}  // namespace

int RunPatterns(int argc, char** argv) {
  CLI::App app{
      "Structured-light pattern sequences (docs/formats.md, \"Pattern spec\").\n\n"
      "  generate SPEC --out DIR   write the projector images of SPEC as 8-bit PNGs, one per frame "
      "in\n"
      "                            projection order (DIR/pattern_00.png, ...; 3 digits past 100 "
      "frames),\n"
      "                            plus DIR/patterns.json (the spec, with num_images; loads back "
      "as a\n"
      "                            SPEC) and DIR/frames.json (file name and role of every frame).\n"
      "                            Each image has the projector's resolution (pixels). The folder "
      "is\n"
      "                            written under a temporary name and renamed when complete.\n"
      "  show SPEC                 print the spec, its image count and the role of every frame.\n\n"
      "SPEC is a .yaml or .json file with the spec's fields, or an ImageSet manifest.json (its\n"
      "\"patterns\" member). Examples: config/patterns/graycode_phase.yaml (Gray code + 4-step "
      "phase\n"
      "shift, 1280x800), config/patterns/kamino_opencv_graycode.yaml (OpenCV GrayCodePattern "
      "order),\n"
      "config/patterns/phase12_gray7_no_inverse.yaml (12 steps, Gray bits without inverse, phase "
      "offset\n"
      "and direction), phase_shifted_gray.yaml (shifted Gray code), phase_frame_order.yaml (own "
      "frame\n"
      "order). The frame names `show` prints, as a `frame_order` list, read back as the same "
      "sequence.",
      argv[0]};
  app.require_subcommand(1);
  std::string spec_path, out_dir;
  bool overwrite = false;
  auto* generate = app.add_subcommand("generate", "write the projector images of a pattern spec");
  generate->add_option("SPEC", spec_path, "pattern spec (.yaml / .json) or ImageSet manifest")
      ->required();
  generate
      ->add_option("--out", out_dir, "output folder (created; must not exist unless --overwrite)")
      ->required();
  generate->add_flag("--overwrite", overwrite,
                     "replace an existing output folder (default: refuse)");
  auto* show =
      app.add_subcommand("show", "describe a pattern spec: kind, image count, frame roles");
  show->add_option("SPEC", spec_path, "pattern spec (.yaml / .json) or ImageSet manifest")
      ->required();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return ExitOnParseError(app, e);
  }

  const PatternSpec spec = LoadPatternSpec(spec_path);
  const std::vector<FrameInfo> frames = spec.Frames();
  if (show->parsed()) {
    std::printf("%s\n", PatternSpecToJson(spec).dump(2).c_str());
    for (size_t i = 0; i < frames.size(); ++i)
      std::printf("%3zu  %s\n", i, frames[i].Name().c_str());
    return 0;
  }

  const std::filesystem::path target = out_dir;
  SLSHADOW_THROW_IF(std::filesystem::exists(target) && !overwrite, target.string(),
                    ": output folder exists (pass --overwrite to replace it)");
  const std::vector<cv::Mat> images = GeneratePatterns(spec);
  const std::filesystem::path staged = TemporarySibling(target);
  std::filesystem::create_directories(staged);
  try {
    nlohmann::json listing = PatternSpecToJson(spec);
    nlohmann::json files = nlohmann::json::array();
    const int count = static_cast<int>(images.size());
    for (int i = 0; i < count; ++i) {
      const std::string name = FrameFileName(i, count);
      WriteGrayImage(staged / name, images[static_cast<size_t>(i)]);
      files.push_back({{"file", name}, {"frame", frames[static_cast<size_t>(i)].Name()}});
    }
    // patterns.json loads back as a spec: "frames" is informational and not a spec field, so it is
    // written to a sibling file.
    WriteTextFileAtomically(staged / "patterns.json", listing.dump(2) + "\n");
    WriteTextFileAtomically(staged / "frames.json", files.dump(2) + "\n");
    CommitDirectory(staged, target, overwrite);
  } catch (...) {
    std::error_code ec;
    std::filesystem::remove_all(staged, ec);
    throw;
  }
  std::printf("wrote %zu %dx%d pattern images and patterns.json to %s\n", images.size(),
              spec.projector_width, spec.projector_height, target.string().c_str());
  return 0;
}

}  // namespace slshadow::app
