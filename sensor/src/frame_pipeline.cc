#include "romunect/sensor/frame_pipeline.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>

#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"

namespace romunect {
namespace {

// Lowers the calling thread's priority by `nice` (always allowed, never raised back).
void LowerThreadPriority(int nice) {
  if (nice == 0) return;
  const id_t self = static_cast<id_t>(syscall(SYS_gettid));
  setpriority(PRIO_PROCESS, self, std::min(19, getpriority(PRIO_PROCESS, self) + nice));
}

void CheckOptions(const PipelineStageOptions& options) {
  ROMUNECT_CHECK_MSG(options.queue_depth >= 1 && options.nice >= 0 && options.nice <= 19,
                     ("pipeline stage '" + options.name + "': queue_depth >= 1, nice 0..19").c_str());
}

}  // namespace

PipelineEngine::~PipelineEngine() { StopAndJoin(); }

void PipelineEngine::SetSource(PipelineStageOptions options, Source source) {
  CheckOptions(options);
  ROMUNECT_CHECK_MSG(!started_ && stages_.empty(), "FramePipeline: the source comes first, before Start()");
  source_ = std::move(source);
  stages_.emplace_back();
  stages_.back().options = std::move(options);
  stages_.back().timing.name = stages_.back().options.name;
}

void PipelineEngine::AddStage(PipelineStageOptions options, Stage stage) {
  CheckOptions(options);
  ROMUNECT_CHECK_MSG(!started_ && !stages_.empty(), "FramePipeline: stages go after the source, before Start()");
  stages_.emplace_back();
  stages_.back().options = std::move(options);
  stages_.back().stage = std::move(stage);
  stages_.back().timing.name = stages_.back().options.name;
}

void PipelineEngine::Start() {
  ROMUNECT_CHECK_MSG(!started_ && !stages_.empty(), "FramePipeline::Start: once, with a source");
  started_ = true;
  threads_.reserve(stages_.size());
  threads_.emplace_back([this] { RunSource(); });
  for (size_t i = 1; i < stages_.size(); ++i) threads_.emplace_back([this, i] { RunStage(i); });
}

void PipelineEngine::Finish() {
  ROMUNECT_CHECK_MSG(started_, "FramePipeline::Finish before Start");
  for (std::thread& thread : threads_) {
    if (thread.joinable()) thread.join();
  }
  std::exception_ptr failure;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    finished_ = true;
    failure = std::exchange(failure_, nullptr);  // reported once
  }
  if (failure) std::rethrow_exception(failure);
}

std::vector<PipelineStageTiming> PipelineEngine::timings() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::vector<PipelineStageTiming> out;
  for (const StageSlot& slot : stages_) out.push_back(slot.timing);
  return out;
}

void PipelineEngine::StopAndJoin() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  changed_.notify_all();
  for (std::thread& thread : threads_) {
    if (thread.joinable()) thread.join();
  }
}

void PipelineEngine::FailLocked(int64_t sequence, std::exception_ptr failure) {
  // The earliest item's failure wins: the one a run of the stages in sequence would have met.
  if (failed_at_ < 0 || sequence < failed_at_) {
    failed_at_ = sequence;
    failure_ = std::move(failure);
  }
}

bool PipelineEngine::PushLocked(std::unique_lock<std::mutex>* lock, size_t index, Entry entry, double* block_s) {
  if (index >= stages_.size()) return true;  // past the last stage: the item is done
  StageSlot& next = stages_[index];
  const auto since = SteadyClock::now();
  // A full queue always drains: a failed stage goes on dropping what comes after its item.
  changed_.wait(*lock, [&] { return stopping_ || next.input.size() < static_cast<size_t>(next.options.queue_depth); });
  *block_s += SecondsSince(since);
  if (stopping_) return false;
  next.input.push_back(std::move(entry));
  changed_.notify_all();
  return true;
}

void PipelineEngine::RunSource() {
  StageSlot& self = stages_[0];
  LowerThreadPriority(self.options.nice);
  std::unique_lock<std::mutex> lock(mutex_);
  for (int64_t sequence = 0; !stopping_ && failed_at_ < 0; ++sequence) {
    lock.unlock();
    Entry entry;
    entry.sequence = sequence;
    bool more = false;
    std::exception_ptr failure;
    const auto start = SteadyClock::now();
    const double cpu_start = ThreadCpuSeconds();
    try {
      more = source_(&entry.item);
    } catch (...) {
      failure = std::current_exception();
    }
    const double busy_s = SecondsSince(start), cpu_s = ThreadCpuSeconds() - cpu_start;
    if (stages_.size() == 1) entry.item.reset();  // no stage after the source
    lock.lock();
    self.timing.busy_s += busy_s;
    self.timing.cpu_s += cpu_s;
    if (failure) {
      FailLocked(sequence, failure);
      break;
    }
    if (!more) break;
    ++self.timing.items;
    if (!PushLocked(&lock, 1, std::move(entry), &self.timing.block_s)) break;
  }
  self.done = true;
  changed_.notify_all();
}

void PipelineEngine::RunStage(size_t index) {
  StageSlot& self = stages_[index];
  const StageSlot& before = stages_[index - 1];
  LowerThreadPriority(self.options.nice);
  std::unique_lock<std::mutex> lock(mutex_);
  for (;;) {
    const auto since = SteadyClock::now();
    changed_.wait(lock, [&] { return stopping_ || !self.input.empty() || before.done; });
    self.timing.wait_s += SecondsSince(since);
    if (stopping_ || self.input.empty()) break;  // stopped, or the stream has ended
    Entry entry = std::move(self.input.front());
    self.input.pop_front();
    changed_.notify_all();                                         // room in this queue
    if (failed_at_ >= 0 && entry.sequence > failed_at_) continue;  // after a failure: dropped
    lock.unlock();
    std::exception_ptr failure;
    const auto start = SteadyClock::now();
    const double cpu_start = ThreadCpuSeconds();
    try {
      self.stage(entry.item.get());
    } catch (...) {
      failure = std::current_exception();
    }
    const double busy_s = SecondsSince(start), cpu_s = ThreadCpuSeconds() - cpu_start;
    // A failed item goes no further; the last stage's items are done. Either is freed off the lock.
    if (failure || index + 1 == stages_.size()) entry.item.reset();
    lock.lock();
    self.timing.busy_s += busy_s;
    self.timing.cpu_s += cpu_s;
    ++self.timing.items;
    if (failure) {
      FailLocked(entry.sequence, failure);
      changed_.notify_all();
      continue;
    }
    if (!PushLocked(&lock, index + 1, std::move(entry), &self.timing.block_s)) break;
  }
  self.done = true;
  changed_.notify_all();
}

}  // namespace romunect
