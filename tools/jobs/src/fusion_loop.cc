#include "romunect/tools/jobs/fusion_loop.h"

#include "romunect/fusion/frame_inserter.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"

namespace romunect::jobs {

struct FrameFuser::State {
  State(fusion::VotingGrid& grid, int threads) : inserter(&grid, fusion::InserterOptions{threads}), tracker(grid) {}
  fusion::FrameInserter inserter;
  fusion::CompletenessTracker tracker;  // the per-frame curve, without extracting every frame
};

FrameFuser::FrameFuser(const CameraModel& camera, fusion::VotingGrid& grid, int threads, FrameHooks& hooks)
    : camera_(camera), hooks_(hooks), state_(std::make_unique<State>(grid, threads)) {
  summary_.report.threads = state_->inserter.threads();
}

FrameFuser::~FrameFuser() = default;

void FrameFuser::Fuse(Frame* frame) {
  fusion::FusionReport& report = summary_.report;
  hooks_.Prepare(deliveries_, frame);
  ROMUNECT_CHECK(frame->T_W_C.has_value());
  ROMUNECT_CHECK(frame->depth_m.rows == camera_.height && frame->depth_m.cols == camera_.width);
  summary_.cameras_W.extend(frame->T_W_C->translation());
  const Stopwatch insert;
  state_->inserter.Insert(camera_, frame->depth_m, *frame->T_W_C, &report.stats);
  report.insert_ms.push_back(insert.milliseconds());
  ++report.frames;
  const Stopwatch update;
  report.completeness_per_frame.push_back(state_->tracker.Update(state_->inserter.changed_columns()));
  summary_.completeness_ms.push_back(update.milliseconds());
  hooks_.OnFused(deliveries_++, *frame, summary_);
}

void FrameFuser::BadFrame(const Frame& frame, const std::string& error) {
  ++summary_.report.bad_frames;
  summary_.report.bad_frame_messages.push_back(error);
  hooks_.OnBadFrame(deliveries_++, frame, error);
}

FusionSummary FuseFrames(FrameSource& source, const CameraModel& camera, fusion::VotingGrid& grid, int threads,
                         FrameHooks& hooks) {
  FrameFuser fuser(camera, grid, threads, hooks);
  Frame frame;
  std::string error;
  for (;;) {
    FrameStatus status;
    try {
      status = source.Next(&frame, &error);
    } catch (const InputError& e) {
      if (!hooks.KeepAfterSourceError(e)) throw;
      fuser.Stopped(e.what());
      break;
    }
    if (status == FrameStatus::kEndOfStream) break;
    if (status == FrameStatus::kBadFrame) {
      fuser.BadFrame(frame, error);
    } else {
      fuser.Fuse(&frame);
    }
  }
  return std::move(fuser.summary());
}

}  // namespace romunect::jobs
