#include "scan_resume.h"

#include <string>
#include <utility>

#include <nlohmann/json.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/tools/jobs/run_folder.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;

fs::path FrameAt(const fs::path& frames, const char* folder, int index, const char* extension) {
  return frames / FrameFile(folder, index, extension);
}

class ResumingImager : public sim::FrameImager {
 public:
  ResumingImager(std::unique_ptr<sim::FrameImager> inner, fs::path frames, int reused)
      : inner_(std::move(inner)), frames_(std::move(frames)), reused_(reused) {}

  bool Replay(const Rig& rig, Frame* frame) override {
    if (frame->index >= reused_) return false;
    const int i = frame->index;
    frame->ir = ReadPng16(FrameAt(frames_, "ir", i, "png"), Size(rig));
    frame->raw = ReadPng16(FrameAt(frames_, "raw", i, "png"), Size(rig));
    frame->depth_m = ReadDepthExr(FrameAt(frames_, "depth", i, "exr"), Size(rig));
    frame->gt_depth_m = ReadDepthExr(FrameAt(frames_, "gt_depth", i, "exr"), Size(rig));
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
  // The threads do not change the bytes.
  if (const auto changed = FindChangedOption(work_dir / kScanOptionsFile, ScanOptionsFileText(options), {"threads"})) {
    throw InputError("--resume", changed->key,
                     "the interrupted run in " + work_dir.string() + " used " + changed->recorded + ", this one " +
                         changed->now + ": resume with the interrupted run's options");
  }
  // A frames.json written just before the kill (the temporaries went with RunFolder::Resume).
  const fs::path frames = work_dir / "frames";
  fs::remove(frames / "frames.json");
  // Complete frames: every image of the frame renamed into place, from frame 0 on.
  int complete = 0;
  while (fs::exists(FrameAt(frames, "depth", complete, "exr")) &&
         fs::exists(FrameAt(frames, "gt_depth", complete, "exr")) &&
         (options.ideal_depth || (fs::exists(FrameAt(frames, "ir", complete, "png")) &&
                                  fs::exists(FrameAt(frames, "raw", complete, "png"))))) {
    ++complete;
  }
  return complete;
}

std::unique_ptr<sim::FrameImager> MakeResumingImager(std::unique_ptr<sim::FrameImager> inner, const fs::path& frames_dir,
                                                     int reused) {
  return std::make_unique<ResumingImager>(std::move(inner), frames_dir, reused);
}

}  // namespace romunect::jobs
