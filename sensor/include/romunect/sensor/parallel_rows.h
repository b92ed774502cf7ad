// Threads for the modules' data-parallel loops. WorkerPool: a fixed set of threads that run one
// job at a time, parked between jobs. ParallelRows: splits rows [0, rows) into contiguous blocks,
// one per thread; each block's result depends on its rows only, so outputs are the same bytes at
// any thread count.
//
// Why parked threads and not a thread per call: a thread that ends returns its stack's pages
// (glibc madvise), which flushes the TLB of every core that runs the process; on this project's
// virtual machines a 2-thread extraction of the fusion grid took 10-12 ms instead of ~1 ms in
// most runs when its helper thread ended while the caller was still reading the grid.
#pragma once

#include <algorithm>
#include <condition_variable>
#include <cstdint>
#include <mutex>
#include <thread>
#include <vector>

namespace romunect {

class WorkerPool {
 public:
  // `threads` >= 1 includes the caller: threads - 1 workers start now.
  explicit WorkerPool(int threads);
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  int threads() const { return static_cast<int>(workers_.size()) + 1; }

  // Runs f(t) for every t in [0, threads()), f(0) on the caller; returns when all are done (also
  // when f(0) throws, which is then rethrown; f must not throw on a worker). One job at a time:
  // callers on several threads must not share a pool. Allocates nothing.
  template <class F>
  void Run(F& f) {
    Run(&Trampoline<F>, &f);
  }
  // The same for fn(context, t).
  void Run(void (*fn)(void*, int), void* context);

 private:
  template <class F>
  static void Trampoline(void* context, int thread) {
    (*static_cast<F*>(context))(thread);
  }
  void WorkerLoop(int thread);

  std::vector<std::thread> workers_;
  std::mutex mutex_;
  std::condition_variable start_cv_, done_cv_;
  uint64_t generation_ = 0;
  int pending_ = 0;
  bool stop_ = false;
  void (*fn_)(void*, int) = nullptr;
  void* context_ = nullptr;
};

namespace parallel_internal {
// Runs fn(context, t) for t in [0, threads) on a process-wide pool of that many threads, parked
// between calls; false (nothing run) where that pool is busy: a call from another thread at the
// same time, or from inside one of its jobs.
bool RunOnSharedPool(int threads, void (*fn)(void*, int), void* context);
}  // namespace parallel_internal

template <typename Fn>
void ParallelRows(int threads, int rows, const Fn& fn) {
  threads = std::max(1, std::min(threads, rows));
  if (threads == 1) {
    fn(0, rows);
    return;
  }
  auto block = [&fn, threads, rows](int t) { fn(rows * t / threads, rows * (t + 1) / threads); };
  auto trampoline = [](void* context, int t) { (*static_cast<decltype(block)*>(context))(t); };
  if (parallel_internal::RunOnSharedPool(threads, trampoline, &block)) return;
  // The shared pool is busy: threads of this call's own.
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) pool.emplace_back(block, t);
  try {
    block(0);
  } catch (...) {
    for (std::thread& th : pool) th.join();  // they still use fn
    throw;
  }
  for (std::thread& th : pool) th.join();
}

}  // namespace romunect
