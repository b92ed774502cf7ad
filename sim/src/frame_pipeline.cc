#include "romunect/sim/frame_pipeline.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <utility>

#include "romunect/sensor/check.h"

namespace romunect::sim {
namespace {

const CameraModel& CheckedCamera(const FrameSource* source, int depth) {
  ROMUNECT_CHECK(source != nullptr && depth >= 1);
  return source->camera();
}

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

}  // namespace

PrefetchingSource::PrefetchingSource(FrameSource* source, int depth)
    : source_(source),
      depth_(static_cast<size_t>(depth)),
      camera_(CheckedCamera(source, depth)),
      description_(source->Describe()),
      thread_([this] { Produce(); }) {}

PrefetchingSource::~PrefetchingSource() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  changed_.notify_all();
  if (thread_.joinable()) thread_.join();  // Next() joined it at the end of the stream
}

const CameraModel& PrefetchingSource::camera() const { return camera_; }
std::string PrefetchingSource::Describe() const { return description_; }

void PrefetchingSource::Produce() {
  for (;;) {
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [this] { return stop_ || queue_.size() < depth_; });
      if (stop_) return;
    }
    Item item;
    try {
      item.status = source_->Next(&item.frame, &item.error);
    } catch (...) {
      item.exception = std::current_exception();
    }
    const bool last = item.exception || item.status == FrameStatus::kEndOfStream;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      queue_.push_back(std::move(item));
    }
    changed_.notify_all();
    if (last) return;
  }
}

FrameStatus PrefetchingSource::Next(Frame* frame, std::string* error) {
  ROMUNECT_CHECK(frame != nullptr && error != nullptr);
  Item item;
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (ended_) return FrameStatus::kEndOfStream;
    const auto start = Clock::now();
    changed_.wait(lock, [this] { return !queue_.empty(); });
    wait_s_ += Seconds(start);
    item = std::move(queue_.front());
    queue_.pop_front();
    ended_ = item.exception || item.status == FrameStatus::kEndOfStream;
  }
  changed_.notify_all();
  if (ended_) thread_.join();  // the producer has returned: the source is the caller's again
  if (item.exception) std::rethrow_exception(item.exception);
  *frame = std::move(item.frame);
  *error = std::move(item.error);
  return item.status;
}

FrameWorker::FrameWorker(std::function<void(const Frame&)> job, int depth, int nice)
    : job_(std::move(job)), depth_(static_cast<size_t>(depth)), nice_(nice), thread_([this] { Run(); }) {
  ROMUNECT_CHECK(depth >= 1 && nice >= 0 && nice <= 19);
}

FrameWorker::~FrameWorker() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    closing_ = true;
  }
  changed_.notify_all();
  thread_.join();
}

void FrameWorker::Run() {
  // Lower the thread's priority (always allowed): it runs on what the other stages leave.
  if (nice_ != 0) {
    const id_t self = static_cast<id_t>(syscall(SYS_gettid));
    setpriority(PRIO_PROCESS, self, std::min(19, getpriority(PRIO_PROCESS, self) + nice_));
  }
  for (;;) {
    Frame frame;
    bool skip = false;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [this] { return closing_ || !queue_.empty(); });
      if (queue_.empty()) return;  // closing and drained
      frame = std::move(queue_.front());
      queue_.pop_front();
      busy_ = true;
      skip = failed_;  // after a failure, later frames are dropped
    }
    changed_.notify_all();
    const auto start = Clock::now();
    std::exception_ptr failure;
    if (!skip) {
      try {
        job_(frame);
      } catch (...) {
        failure = std::current_exception();
      }
    }
    {
      std::lock_guard<std::mutex> lock(mutex_);
      busy_s_ += Seconds(start);
      if (failure) {
        exception_ = failure;
        failed_ = true;
      }
      busy_ = false;
    }
    changed_.notify_all();
  }
}

void FrameWorker::RethrowLocked() {
  if (exception_) std::rethrow_exception(std::exchange(exception_, nullptr));
}

void FrameWorker::Push(const Frame& frame) {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [this] { return exception_ || queue_.size() < depth_; });
  RethrowLocked();
  queue_.push_back(frame);
  lock.unlock();
  changed_.notify_all();
}

void FrameWorker::Finish() {
  std::unique_lock<std::mutex> lock(mutex_);
  changed_.wait(lock, [this] { return queue_.empty() && !busy_; });
  RethrowLocked();
}

}  // namespace romunect::sim
