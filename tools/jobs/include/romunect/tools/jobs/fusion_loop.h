// The one fusion loop of the jobs: frames from a source are inserted, one by one, into a voting
// grid, with the completeness curve and the insert times per frame. `romunect scan` runs its body
// (FrameFuser) as a stage of the frame pipeline, `romunect fuse` pulls frames from a directory, a
// recording or a device (FuseFrames); what differs between them (bad frames, depth models, poses, progress lines, side
// outputs) comes in through FrameHooks.
#pragma once

#include <cstddef>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "romunect/fusion/outputs.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/frame_source.h"

namespace romunect::jobs {

// What the loop measured. `report` holds frames, bad frames and their messages, the insert
// times, the inserter's stats, threads and the completeness per frame; the caller completes
// it (box, extraction, metrics) after the loop.
struct FusionSummary {
  fusion::FusionReport report;
  std::vector<double> completeness_ms;  // per fused frame: the completeness update
  Eigen::AlignedBox3d cameras_W;        // where the cameras were (a box no ray enters says so)
  std::optional<std::string> stopped;   // why the source stopped before its end (KeepAfterSourceError)
};

// A job's part of the loop; every step has a default that does nothing.
class FrameHooks {
 public:
  virtual ~FrameHooks() = default;
  // The source threw InputError: true keeps what was fused (the summary says why it stopped),
  // false rethrows.
  virtual bool KeepAfterSourceError(const InputError& error) { return false; }
  // The i-th delivery was a bad frame (already counted in the summary); throw to end the run.
  virtual void OnBadFrame(size_t i, const Frame& frame, const std::string& error) {}
  // The i-th delivery before it is inserted: complete it (depth model, pose), hand it on, or
  // throw when it cannot be fused.
  virtual void Prepare(size_t i, Frame* frame) {}
  // The i-th delivery after it was inserted and counted (summary.report's curves end with it).
  virtual void OnFused(size_t i, const Frame& frame, const FusionSummary& summary) {}
};

// The loop's body, for callers that are handed frames instead of pulling them from a source (the
// scan's fuse stage of its frame pipeline): one call per delivery, in order. Prepare must leave
// every frame with depth of `camera`'s size and a camera pose (checked: a frame without them is a
// programming error here).
class FrameFuser {
 public:
  FrameFuser(const CameraModel& camera, fusion::VotingGrid& grid, int threads, FrameHooks& hooks);
  ~FrameFuser();
  FrameFuser(const FrameFuser&) = delete;
  FrameFuser& operator=(const FrameFuser&) = delete;

  void Fuse(Frame* frame);                                      // the next delivery, a good frame
  void BadFrame(const Frame& frame, const std::string& error);  // the next delivery, a bad frame
  void Stopped(const std::string& why) { summary_.stopped = why; }
  FusionSummary& summary() { return summary_; }

 private:
  struct State;
  const CameraModel& camera_;
  FrameHooks& hooks_;
  std::unique_ptr<State> state_;  // the inserter and the completeness tracker
  FusionSummary summary_;
  size_t deliveries_ = 0;
};

// Inserts every frame of `source` into `grid` with `threads` inserter threads, in order, until
// the source ends (FrameFuser on each delivery).
FusionSummary FuseFrames(FrameSource& source, const CameraModel& camera, fusion::VotingGrid& grid, int threads,
                         FrameHooks& hooks);

}  // namespace romunect::jobs
