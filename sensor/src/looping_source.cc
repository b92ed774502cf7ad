#include "romunect/sensor/looping_source.h"

#include <cmath>
#include <utility>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect {

LoopingSource::LoopingSource(Opener open, double gap_s) : open_(std::move(open)), gap_s_(gap_s) {
  ROMUNECT_CHECK(open_ != nullptr);
  ROMUNECT_CHECK(std::isfinite(gap_s_) && gap_s_ > 0.0);
  source_ = open_();
  ROMUNECT_CHECK(source_ != nullptr);
  camera_ = source_->camera();
  passes_ = 1;
}

std::string LoopingSource::Describe() const { return source_->Describe() + ", looped"; }

void LoopingSource::OpenNextPass() {
  std::unique_ptr<FrameSource> next = open_();
  ROMUNECT_CHECK(next != nullptr);
  // Consumers size their buffers from camera() once; a pass of another size cannot follow.
  if (!(next->camera() == camera_)) {
    throw InputError(next->Describe(), "camera",
                     "changed between passes of a looped source (pass " + std::to_string(passes_ + 1) + ")");
  }
  source_ = std::move(next);
  ++passes_;
  pass_delivered_ = false;
  pass_started_ = false;
}

FrameStatus LoopingSource::Next(Frame* frame, std::string* error) {
  ROMUNECT_CHECK(frame != nullptr && error != nullptr);
  for (;;) {
    const FrameStatus status = source_->Next(frame, error);
    if (status == FrameStatus::kEndOfStream) {
      if (!pass_delivered_) return FrameStatus::kEndOfStream;  // an empty pass: nothing to repeat
      OpenNextPass();
      continue;
    }
    pass_delivered_ = true;
    if (status == FrameStatus::kBadFrame) return status;
    if (!pass_started_) {
      pass_started_ = true;
      // The first pass keeps the source's own times; later ones continue from the last frame.
      if (passes_ > 1 && last_time_s_) {
        time_shift_s_ = *last_time_s_ + gap_s_ - frame->time_s;
        index_shift_ = last_index_ + 1 - frame->index;
      }
    }
    frame->time_s += time_shift_s_;
    frame->index += index_shift_;
    last_time_s_ = frame->time_s;
    last_index_ = frame->index;
    return FrameStatus::kOk;
  }
}

}  // namespace romunect
