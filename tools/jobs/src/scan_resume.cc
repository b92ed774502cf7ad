#include "scan_resume.h"

#include <cstdio>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/input_limits.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

// A frame's file in the frame directory (frame_io: <folder>/<6-digit index>.<extension>).
fs::path FramePath(const fs::path& frames, const char* folder, int index, const char* extension) {
  char name[32];
  std::snprintf(name, sizeof(name), "%06d.%s", index, extension);
  return frames / folder / name;
}

class ResumingImager : public sim::FrameImager {
 public:
  ResumingImager(std::unique_ptr<sim::FrameImager> inner, fs::path frames, int reused)
      : inner_(std::move(inner)), frames_(std::move(frames)), reused_(reused) {}

  bool Replay(const Rig& rig, Frame* frame) override {
    if (frame->index >= reused_) return false;
    const int i = frame->index;
    frame->ir = ReadPng16(FramePath(frames_, "ir", i, "png"), Size(rig));
    frame->raw = ReadPng16(FramePath(frames_, "raw", i, "png"), Size(rig));
    frame->depth_m = ReadDepthExr(FramePath(frames_, "depth", i, "exr"), Size(rig));
    frame->gt_depth_m = ReadDepthExr(FramePath(frames_, "gt_depth", i, "exr"), Size(rig));
    return true;
  }

  void SynthesizeIr(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) override {
    inner_->SynthesizeIr(rig, geometry, seed, frame);
  }
  void ComputeDepth(const Rig& rig, Frame* frame) override { inner_->ComputeDepth(rig, frame); }

 private:
  static cv::Size Size(const Rig& rig) { return {rig.camera.width, rig.camera.height}; }

  std::unique_ptr<sim::FrameImager> inner_;
  fs::path frames_;
  int reused_;
};

}  // namespace

std::string ScanOptionsFileText(const ScanJobOptions& options) {
  json j = json::parse(ScanOptionsJson(options));
  j["perturb"] = options.perturb;
  return j.dump(2) + "\n";
}

int PrepareResume(const ScanJobOptions& options, const fs::path& work_dir) {
  const fs::path file = work_dir / kScanOptionsFile;
  if (!fs::exists(file)) {
    throw InputError(file.string(), "", "missing: the folder holds no interrupted scan to resume; run without --resume");
  }
  json before;
  try {
    before = json::parse(ReadInputFile(file, 1 << 20, "scan options file"));
  } catch (const json::exception& e) {
    throw InputError(file.string(), "", std::string("not valid JSON: ") + e.what());
  }
  const json now = json::parse(ScanOptionsFileText(options));
  for (const auto& [key, value] : now.items()) {
    if (key == "threads") continue;  // the same bytes at any thread count
    if (!before.contains(key) || before[key] != value) {
      throw InputError("--resume", key,
                       "the interrupted run in " + work_dir.string() + " used " +
                           (before.contains(key) ? before[key].dump() : std::string("none")) + ", this one " +
                           value.dump() + ": resume with the interrupted run's options");
    }
  }
  // A frames.json written just before the kill (the temporaries went with RunFolder::Resume).
  const fs::path frames = work_dir / "frames";
  fs::remove(frames / "frames.json");
  // Complete frames: every image of the frame renamed into place, from frame 0 on.
  int complete = 0;
  while (fs::exists(FramePath(frames, "depth", complete, "exr")) &&
         fs::exists(FramePath(frames, "gt_depth", complete, "exr")) &&
         (options.ideal_depth || (fs::exists(FramePath(frames, "ir", complete, "png")) &&
                                  fs::exists(FramePath(frames, "raw", complete, "png"))))) {
    ++complete;
  }
  return complete;
}

std::unique_ptr<sim::FrameImager> MakeResumingImager(std::unique_ptr<sim::FrameImager> inner, const fs::path& frames_dir,
                                                     int reused) {
  return std::make_unique<ResumingImager>(std::move(inner), frames_dir, reused);
}

}  // namespace romunect::jobs
