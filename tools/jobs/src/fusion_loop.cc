#include "romunect/jobs/fusion_loop.h"

#include "romunect/fusion/frame_inserter.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"

namespace romunect::jobs {

FusionSummary FuseFrames(FrameSource& source, const CameraModel& camera, fusion::VotingGrid& grid, int threads,
                         FrameHooks& hooks) {
  fusion::FrameInserter inserter(&grid, fusion::InserterOptions{threads});
  fusion::CompletenessTracker tracker(grid);  // the per-frame curve, without extracting every frame
  FusionSummary summary;
  fusion::FusionReport& report = summary.report;
  report.threads = inserter.threads();
  Frame frame;
  std::string error;
  for (size_t i = 0;; ++i) {
    FrameStatus status;
    try {
      status = source.Next(&frame, &error);
    } catch (const InputError& e) {
      if (!hooks.KeepAfterSourceError(e)) throw;
      summary.stopped = e.what();
      break;
    }
    if (status == FrameStatus::kEndOfStream) break;
    if (status == FrameStatus::kBadFrame) {
      ++report.bad_frames;
      report.bad_frame_messages.push_back(error);
      hooks.OnBadFrame(i, frame, error);
      continue;
    }
    hooks.Prepare(i, &frame);
    ROMUNECT_CHECK(frame.T_W_C.has_value());
    ROMUNECT_CHECK(frame.depth_m.rows == camera.height && frame.depth_m.cols == camera.width);
    summary.cameras_W.extend(frame.T_W_C->translation());
    const Stopwatch insert;
    inserter.Insert(camera, frame.depth_m, *frame.T_W_C, &report.stats);
    report.insert_ms.push_back(insert.milliseconds());
    ++report.frames;
    const Stopwatch update;
    report.completeness_per_frame.push_back(tracker.Update(inserter.changed_columns()));
    summary.completeness_ms.push_back(update.milliseconds());
    hooks.OnFused(i, frame, summary);
  }
  return summary;
}

}  // namespace romunect::jobs
