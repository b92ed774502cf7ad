// A finite FrameSource replayed without end: each time it runs out, a new one is opened and
// its frames continue the stream. Used by viewers that show a short capture over and over (the
// virtual OpenNI2 device's loop=1) and by anything else that wants a capture as an endless feed.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/frame_source.h"

namespace romunect {

class LoopingSource : public FrameSource {
 public:
  // Opens one pass of the source from its start (e.g. a new FrameDirectorySource). Throws
  // InputError when the source cannot be opened.
  using Opener = std::function<std::unique_ptr<FrameSource>()>;

  // Opens the first pass now (the opener's exceptions pass through). `gap_s` (> 0) is the time
  // between the last frame of a pass and the first of the next one, usually one frame interval.
  LoopingSource(Opener open, double gap_s);

  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override;

  // Frames of pass p come with time_s and index shifted so that the stream goes on: the first
  // frame of a pass follows the previous pass's last frame by gap_s and by one index. Bad frames
  // pass through. The stream ends only when a pass delivers nothing at all (not even a bad
  // frame): there is nothing to repeat. A pass whose camera differs from the first pass's throws
  // InputError, as do the opener's failures.
  FrameStatus Next(Frame* frame, std::string* error) override;

  int passes() const { return passes_; }  // passes opened so far, the first included

 private:
  void OpenNextPass();

  Opener open_;
  double gap_s_;
  std::unique_ptr<FrameSource> source_;
  CameraModel camera_;
  int passes_ = 0;
  bool pass_delivered_ = false;  // the current pass has delivered a frame or a bad frame
  bool pass_started_ = false;    // the current pass's first good frame has set the shifts
  double time_shift_s_ = 0.0;
  int index_shift_ = 0;
  std::optional<double> last_time_s_;  // the last good frame as delivered (shifted)
  int last_index_ = 0;
};

}  // namespace romunect
