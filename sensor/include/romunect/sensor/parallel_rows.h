// Splits rows [0, rows) into contiguous blocks, one per thread. Each block's result depends on
// its rows only, so outputs are the same bytes at any thread count.
#pragma once

#include <algorithm>
#include <thread>
#include <vector>

namespace romunect {

template <typename Fn>
void ParallelRows(int threads, int rows, const Fn& fn) {
  threads = std::max(1, std::min(threads, rows));
  if (threads == 1) {
    fn(0, rows);
    return;
  }
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int t = 1; t < threads; ++t) {
    pool.emplace_back([&fn, t, threads, rows] { fn(rows * t / threads, rows * (t + 1) / threads); });
  }
  fn(0, rows / threads);
  for (std::thread& th : pool) th.join();
}

}  // namespace romunect
