#include "romunect/sensor/parallel_rows.h"

#include <array>
#include <memory>

namespace romunect {

WorkerPool::WorkerPool(int threads) {
  for (int t = 1; t < threads; ++t) workers_.emplace_back([this, t] { WorkerLoop(t); });
}

WorkerPool::~WorkerPool() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stop_ = true;
  }
  start_cv_.notify_all();
  for (std::thread& w : workers_) w.join();
}

void WorkerPool::Run(void (*fn)(void*, int), void* context) {
  if (workers_.empty()) {
    fn(context, 0);
    return;
  }
  {
    std::lock_guard<std::mutex> lock(mutex_);
    fn_ = fn;
    context_ = context;
    pending_ = static_cast<int>(workers_.size());
    ++generation_;
  }
  start_cv_.notify_all();
  auto wait_for_workers = [this] {
    std::unique_lock<std::mutex> lock(mutex_);
    done_cv_.wait(lock, [this] { return pending_ == 0; });
  };
  try {
    fn(context, 0);
  } catch (...) {
    wait_for_workers();  // they still use the job's context
    throw;
  }
  wait_for_workers();
}

void WorkerPool::WorkerLoop(int thread) {
  uint64_t seen = 0;
  for (;;) {
    void (*fn)(void*, int);
    void* context;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      start_cv_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
      fn = fn_;
      context = context_;
    }
    fn(context, thread);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      if (--pending_ == 0) done_cv_.notify_one();
    }
  }
}

namespace parallel_internal {

bool RunOnSharedPool(int threads, void (*fn)(void*, int), void* context) {
  // One pool per thread count up to kMaxShared, made on first use and kept until the process
  // ends (its workers park on a condition variable: no cost while idle). Never destroyed: at
  // exit another thread may still be in a job. Larger counts get threads of their own.
  constexpr int kMaxShared = 64;
  struct Slot {
    std::mutex busy;
    std::unique_ptr<WorkerPool> pool;
  };
  static auto* const slots = new std::array<Slot, kMaxShared + 1>;
  if (threads < 2 || threads > kMaxShared) return false;
  Slot& slot = (*slots)[threads];
  std::unique_lock<std::mutex> busy(slot.busy, std::try_to_lock);
  if (!busy.owns_lock()) return false;
  if (slot.pool == nullptr) slot.pool = std::make_unique<WorkerPool>(threads);
  slot.pool->Run(fn, context);
  return true;
}

}  // namespace parallel_internal
}  // namespace romunect
