#include "romunect/sensor/parallel_rows.h"

#include <atomic>
#include <chrono>
#include <stdexcept>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace romunect {
namespace {

// Every row visited exactly once, in blocks whose bounds are ParallelRows' split.
void ExpectEachRowOnce(int threads, int rows) {
  std::vector<std::atomic<int>> visits(rows);
  std::atomic<int> blocks{0};
  ParallelRows(threads, rows, [&](int begin, int end) {
    ++blocks;
    for (int r = begin; r < end; ++r) ++visits[r];
  });
  for (int r = 0; r < rows; ++r) {
    EXPECT_EQ(visits[r].load(), 1) << "row " << r << " of " << rows << ", " << threads << " threads";
  }
  EXPECT_EQ(blocks.load(), std::max(1, std::min(threads, rows)));
}

TEST(ParallelRows, VisitsEveryRowOnceAtAnyThreadCount) {
  for (int threads : {1, 2, 3, 7, 65}) {  // 65: above the shared pools, threads of its own
    for (int rows : {1, 2, 5, 64, 1000}) ExpectEachRowOnce(threads, rows);
  }
}

TEST(ParallelRows, RepeatedCallsReuseTheSharedPool) {
  // the 30 Hz loops call it every frame: many jobs in a row on the same parked threads
  for (int i = 0; i < 2000; ++i) ExpectEachRowOnce(2 + i % 3, 97);
}

TEST(ParallelRows, CallersOnSeveralThreadsAndNestedCallsAllComplete) {
  // A pool runs one job at a time; a busy pool sends the call to threads of its own instead of
  // waiting, so neither a second caller nor a call from inside a job can deadlock.
  std::vector<std::thread> callers;
  std::atomic<int> inner_rows{0};
  for (int c = 0; c < 4; ++c) {
    callers.emplace_back([&] {
      for (int i = 0; i < 200; ++i) {
        ExpectEachRowOnce(2, 50);
        ParallelRows(2, 4, [&](int begin, int end) {
          ParallelRows(2, 10, [&](int b, int e) { inner_rows += (e - b) * (end - begin); });
        });
      }
    });
  }
  for (std::thread& t : callers) t.join();
  EXPECT_EQ(inner_rows.load(), 4 * 200 * 4 * 10);
}

TEST(ParallelRows, AnExceptionOnTheCallerWaitsForTheWorkersAndThePoolStaysUsable) {
  std::atomic<int> worker_rows{0};
  EXPECT_THROW(ParallelRows(2, 100,
                            [&](int begin, int end) {
                              if (begin == 0) throw std::runtime_error("caller's block");
                              std::this_thread::sleep_for(std::chrono::milliseconds(20));
                              worker_rows += end - begin;
                            }),
               std::runtime_error);
  EXPECT_EQ(worker_rows.load(), 50);  // the worker's block finished before the throw left
  ExpectEachRowOnce(2, 100);
  // the same from inside a job, where the shared pool is busy and the call has threads of its own
  std::atomic<int> caught{0};
  ParallelRows(2, 2, [&](int, int) {
    try {
      ParallelRows(2, 100, [](int begin, int) {
        if (begin == 0) throw std::runtime_error("caller's block");
      });
    } catch (const std::runtime_error&) {
      ++caught;
    }
  });
  EXPECT_EQ(caught.load(), 2);
}

TEST(WorkerPool, RunsEveryThreadIndexOncePerJob) {
  for (int threads : {1, 2, 4}) {
    WorkerPool pool(threads);
    EXPECT_EQ(pool.threads(), threads);
    std::vector<std::atomic<int>> runs(threads);
    auto job = [&](int t) { ++runs[t]; };
    for (int i = 0; i < 500; ++i) pool.Run(job);
    for (int t = 0; t < threads; ++t) EXPECT_EQ(runs[t].load(), 500) << "thread " << t << " of " << threads;
  }
}

}  // namespace
}  // namespace romunect
