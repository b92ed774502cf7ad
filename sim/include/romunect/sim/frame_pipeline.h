// A two-stage pipeline for the scan loop on a few cores: PrefetchingSource runs a FrameSource
// (the simulator's physics, rendering and imaging) on its own thread, a few frames ahead of
// the caller, which meanwhile fuses the previous frame; FrameWorker runs a per-frame job (the
// frame directory's writing) on another thread. Frames keep their order and their bytes: each
// frame is produced exactly as without the pipeline (the source alone decides its content),
// so the same seed gives the same output. Frames handed over own their images (a source must
// not reuse a delivered frame's buffers; the Scanner does not).
#pragma once

#include <condition_variable>
#include <cstddef>
#include <deque>
#include <exception>
#include <functional>
#include <mutex>
#include <string>
#include <thread>

#include "romunect/sensor/frame_source.h"

namespace romunect::sim {

class PrefetchingSource : public FrameSource {
 public:
  // Starts producing from *source at once, at most `depth` (>= 1) frames ahead. The source
  // belongs to the background thread until Next() has returned kEndOfStream or this is
  // destroyed: the caller must not touch it (nor what it drives) in between.
  PrefetchingSource(FrameSource* source, int depth = 2);
  ~PrefetchingSource() override;  // stops the producer after its current frame and joins it
  PrefetchingSource(const PrefetchingSource&) = delete;
  PrefetchingSource& operator=(const PrefetchingSource&) = delete;

  const CameraModel& camera() const override;
  std::string Describe() const override;
  // The source's next frame, status and error, in order. Rethrows what the source threw (the
  // stream ends there). After kEndOfStream the producer has stopped and the source is free.
  FrameStatus Next(Frame* frame, std::string* error) override;

  // Wall time the caller spent waiting in Next() for the producer (s).
  double wait_s() const { return wait_s_; }

 private:
  struct Item {
    FrameStatus status = FrameStatus::kOk;
    Frame frame;
    std::string error;
    std::exception_ptr exception;
  };
  void Produce();

  FrameSource* source_;
  const size_t depth_;
  const CameraModel camera_;
  const std::string description_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Item> queue_;
  bool stop_ = false;
  bool ended_ = false;  // the consumer has seen the end
  double wait_s_ = 0.0;
  std::thread thread_;
};

// Runs `job` on each pushed frame on a background thread, in push order, with at most
// `depth` frames waiting. An exception from the job is rethrown by the next Push() or by
// Finish() (later frames are dropped). `nice` (0..19) lowers the thread's priority by that much
// (to 19 at most), for a job that may lag behind the others by up to `depth` frames.
class FrameWorker {
 public:
  FrameWorker(std::function<void(const Frame&)> job, int depth = 4, int nice = 0);
  ~FrameWorker();  // finishes the queued frames (exceptions are dropped here: call Finish())
  FrameWorker(const FrameWorker&) = delete;
  FrameWorker& operator=(const FrameWorker&) = delete;

  void Push(const Frame& frame);  // blocks while `depth` frames wait
  void Finish();                  // waits for every pushed frame; rethrows the job's exception
  double busy_s() const { return busy_s_; }  // wall time spent in the job (s)

 private:
  void Run();
  void RethrowLocked();

  std::function<void(const Frame&)> job_;
  const size_t depth_;
  const int nice_;
  std::mutex mutex_;
  std::condition_variable changed_;
  std::deque<Frame> queue_;
  bool closing_ = false;
  bool busy_ = false;
  std::exception_ptr exception_;  // not yet rethrown
  bool failed_ = false;
  double busy_s_ = 0.0;
  std::thread thread_;
};

}  // namespace romunect::sim
