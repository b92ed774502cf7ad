#include "romunect/sensor/frame_pipeline.h"

#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace romunect {
namespace {

// A frame-sized work item whose bytes depend only on its index and on the stages it went through.
struct Work {
  int index = -1;
  std::vector<uint32_t> pixels;
  std::unique_ptr<int> move_only;  // items need not be copyable
};

// Stage bodies: each a pure function of the item (plus, for Accumulate, the items before it).
void Fill(Work* w, int index) {
  w->index = index;
  w->pixels.resize(4096);
  std::mt19937 rng(static_cast<uint32_t>(index) * 7919u + 1u);
  for (uint32_t& p : w->pixels) p = rng();
  w->move_only = std::make_unique<int>(index);
}
void Mix(Work* w) {
  for (size_t i = 1; i < w->pixels.size(); ++i) w->pixels[i] ^= w->pixels[i - 1] * 2654435761u;
}
// A stateful stage (like fusion): its output depends on the order of the items.
struct Accumulate {
  uint64_t state = 1469598103934665603ull;
  std::vector<uint64_t> out;
  void operator()(const Work& w) {
    for (uint32_t p : w.pixels) state = (state ^ p) * 1099511628211ull;
    out.push_back(state);
  }
};

// Sleeps a pseudo-random 0..max_us, different per run, so the threads interleave differently.
void Jitter(std::minstd_rand* rng, int max_us) {
  std::this_thread::sleep_for(std::chrono::microseconds((*rng)() % (max_us + 1)));
}

TEST(FramePipelineTest, StagesSeeTheItemsInOrderOnThreadsOfTheirOwn) {
  constexpr int kItems = 40;
  FramePipeline<Work> pipeline;
  int made = 0;
  std::vector<std::thread::id> threads(4);
  std::vector<std::vector<int>> seen(4);
  pipeline.SetSource({"make"}, [&](Work* w) {
    threads[0] = std::this_thread::get_id();
    if (made == kItems) return false;
    Fill(w, made);
    seen[0].push_back(made++);
    return true;
  });
  for (int s = 1; s < 4; ++s) {
    pipeline.AddStage({"stage" + std::to_string(s), s}, [&, s](Work* w) {
      threads[s] = std::this_thread::get_id();
      seen[s].push_back(w->index);
    });
  }
  pipeline.Run();
  for (int s = 0; s < 4; ++s) {
    ASSERT_EQ(seen[s].size(), static_cast<size_t>(kItems)) << "stage " << s;
    for (int i = 0; i < kItems; ++i) EXPECT_EQ(seen[s][i], i);
    EXPECT_NE(threads[s], std::this_thread::get_id());
    for (int t = 0; t < s; ++t) EXPECT_NE(threads[s], threads[t]);
  }
  const std::vector<PipelineStageTiming> timings = pipeline.timings();
  ASSERT_EQ(timings.size(), 4u);
  EXPECT_EQ(timings[0].name, "make");
  EXPECT_EQ(timings[3].name, "stage3");
  for (const PipelineStageTiming& t : timings) {
    EXPECT_EQ(t.items, kItems);
    EXPECT_GE(t.busy_s, 0.0);
    EXPECT_GE(t.cpu_s, 0.0);
    EXPECT_GE(t.wait_s, 0.0);
    EXPECT_GE(t.block_s, 0.0);
  }
}

// The same bytes as the stages run one after the other, whatever the threads' timing.
TEST(FramePipelineTest, OutputIsBitEqualToARunInSequenceWhateverTheTiming) {
  constexpr int kItems = 30;
  Accumulate serial;
  for (int i = 0; i < kItems; ++i) {
    Work w;
    Fill(&w, i);
    Mix(&w);
    serial(w);
  }
  for (uint32_t run = 0; run < 4; ++run) {
    SCOPED_TRACE("run " + std::to_string(run));
    std::minstd_rand rng_a(run + 1), rng_b(run + 100), rng_c(run + 1000);
    Accumulate piped;
    int made = 0;
    FramePipeline<Work> pipeline;
    pipeline.SetSource({"fill"}, [&](Work* w) {
      if (made == kItems) return false;
      Jitter(&rng_a, 300);
      Fill(w, made++);
      return true;
    });
    pipeline.AddStage({"mix", 1 + static_cast<int>(run)}, [&](Work* w) {
      Jitter(&rng_b, 300);
      Mix(w);
    });
    pipeline.AddStage({"accumulate", 2}, [&](Work* w) {
      Jitter(&rng_c, 300);
      piped(*w);
    });
    pipeline.Run();
    EXPECT_EQ(piped.out, serial.out);
  }
}

// A slow last stage holds the rest back: no more items exist at once than the queues and the
// stages hold (each stage's queue_depth, plus one item in each stage).
TEST(FramePipelineTest, QueuesAreBounded) {
  std::atomic<int> made{0}, done{0}, most_in_flight{0};
  FramePipeline<Work> pipeline;
  pipeline.SetSource({"make"}, [&](Work* w) {
    if (made.load() == 50) return false;
    w->index = made++;
    return true;
  });
  pipeline.AddStage({"a", 2}, [](Work*) {});
  pipeline.AddStage({"slow", 3}, [&](Work*) {
    std::this_thread::sleep_for(std::chrono::microseconds(500));
    most_in_flight = std::max(most_in_flight.load(), made.load() - done.load());
    ++done;
  });
  pipeline.Run();
  EXPECT_EQ(done.load(), 50);
  // source 1 + (a: 2 queued + 1) + (slow: 3 queued + 1)
  EXPECT_LE(most_in_flight.load(), 8);
  EXPECT_GE(most_in_flight.load(), 4);  // it did run ahead
  const std::vector<PipelineStageTiming> timings = pipeline.timings();
  EXPECT_GT(timings[1].block_s, 0.0);  // "a" waited for room in front of "slow"
}

// A stage (or the source) that throws on item 5: the items before it go through every stage,
// the ones after it are dropped, and Run() rethrows, once.
TEST(FramePipelineTest, AnExceptionInAnyStageReachesTheCallerAfterTheItemsBeforeIt) {
  constexpr int kFailAt = 5;
  auto message = [](int stage) { return std::string("stage ").append(std::to_string(stage)).append(" failed"); };
  for (int failing = 0; failing < 4; ++failing) {
    SCOPED_TRACE(message(failing));
    int made = 0;
    std::vector<int> finished;
    std::atomic<int> after_failure{0};
    auto maybe_throw = [&](int stage, const Work& w) {
      if (stage == failing && w.index == kFailAt) throw std::runtime_error(message(stage));
    };
    FramePipeline<Work> pipeline;
    pipeline.SetSource({"make"}, [&](Work* w) {
      if (made == 1000) return false;
      w->index = made++;
      maybe_throw(0, *w);
      return true;
    });
    for (int s = 1; s < 4; ++s) {
      pipeline.AddStage({std::string(1, static_cast<char>('0' + s)), 2}, [&, s](Work* w) {
        if (failing > 0 && s > failing && w->index > kFailAt) ++after_failure;
        maybe_throw(s, *w);
        if (s == 3) finished.push_back(w->index);
      });
    }
    try {
      pipeline.Run();
      ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
      EXPECT_EQ(e.what(), message(failing));
    }
    EXPECT_EQ(finished, (std::vector<int>{0, 1, 2, 3, 4}));
    EXPECT_EQ(after_failure.load(), 0);  // nothing after the failed item reached a later stage
    EXPECT_LT(made, 1000);               // the source stopped early
    EXPECT_NO_THROW(pipeline.Finish());  // reported once
  }
}

// Two failures: the earliest item's wins, whichever stage met it first in time.
TEST(FramePipelineTest, TheEarliestItemsFailureIsTheOneRethrown) {
  for (int run = 0; run < 5; ++run) {
    int made = 0;
    FramePipeline<Work> pipeline;
    pipeline.SetSource({"make"}, [&](Work* w) {
      if (made == 100) return false;
      w->index = made++;
      return true;
    });
    pipeline.AddStage({"early", 1}, [](Work* w) {
      if (w->index == 6) throw std::runtime_error("item 6");
    });
    pipeline.AddStage({"late", 4}, [](Work* w) {
      std::this_thread::sleep_for(std::chrono::microseconds(300));
      if (w->index == 4) throw std::runtime_error("item 4");
    });
    try {
      pipeline.Run();
      ADD_FAILURE() << "no exception";
    } catch (const std::runtime_error& e) {
      EXPECT_STREQ(e.what(), "item 4");
    }
  }
}

// Destroying a running pipeline stops it after each stage's current item and joins its threads.
TEST(FramePipelineTest, DestroyingARunningPipelineStopsIt) {
  std::atomic<int> made{0}, consumed{0};
  {
    FramePipeline<Work> pipeline;
    pipeline.SetSource({"make"}, [&](Work* w) {
      std::this_thread::sleep_for(std::chrono::microseconds(200));
      w->index = made++;
      return true;  // an endless stream
    });
    pipeline.AddStage({"consume", 2}, [&](Work*) { ++consumed; });
    pipeline.Start();
    while (consumed.load() < 3) std::this_thread::sleep_for(std::chrono::microseconds(100));
  }
  const int after = made.load();
  std::this_thread::sleep_for(std::chrono::milliseconds(5));
  EXPECT_EQ(made.load(), after);  // no thread is left making items
  EXPECT_LT(after, 1000);
  // Never started, or finished: destruction is a no-op.
  { FramePipeline<Work> idle; }
  {
    FramePipeline<Work> empty;
    empty.SetSource({"none"}, [](Work*) { return false; });
    empty.AddStage({"never"}, [](Work*) { ADD_FAILURE(); });
    empty.Run();
    EXPECT_EQ(empty.timings()[1].items, 0);
  }
}

// A stage started with a nice value runs at that lower priority; the caller's is untouched.
TEST(FramePipelineTest, AStageRunsAtTheLowerPriorityAskedFor) {
  auto own_nice = [] { return getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))); };
  const int caller = own_nice();
  std::atomic<int> stage_nice{-100}, plain_nice{-100};
  int made = 0;
  FramePipeline<Work> pipeline;
  pipeline.SetSource({"make"}, [&](Work*) { return made++ < 3; });
  pipeline.AddStage({"plain"}, [&](Work*) { plain_nice = own_nice(); });
  pipeline.AddStage({"low", 4, 10}, [&](Work*) { stage_nice = own_nice(); });
  pipeline.Run();
  EXPECT_EQ(stage_nice.load(), std::min(19, caller + 10));
  EXPECT_EQ(plain_nice.load(), caller);
  EXPECT_EQ(own_nice(), caller);
}

}  // namespace
}  // namespace romunect
