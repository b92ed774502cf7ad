// A frame pipeline for a few cores: a source stage makes one work item per frame (say, advances
// the physics and renders), and ordered stages (IR synthesis, depth engine, fusion, writing) each
// run a function on it, every stage on a thread of its own with a bounded queue in front of it.
// Each stage sees the items in the source's order, one at a time, so a stage may keep state from
// frame to frame (a fusion grid, a writer) and the output does not depend on the threads'
// timing: as long as an item's content is decided by what the stages do to it in order, the same
// inputs give the same bytes as running the stages one after the other.
//
// Errors: an exception in any stage (the source included) ends the stream: items after the failed
// one are dropped, items before it still go through the later stages, the threads are joined,
// and Run() rethrows the exception of the earliest failed item. Destroying a pipeline that runs
// (Start() without Finish()) stops it after each stage's current item and drops the rest.
#pragma once

#include <condition_variable>
#include <cstdint>
#include <deque>
#include <exception>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace romunect {

struct PipelineStageOptions {
  std::string name;     // for timings and errors
  int queue_depth = 1;  // items that may wait in front of the stage (>= 1); ignored for the source
  // Lowers the stage thread's priority by this much (0..19, to 19 at most), for a stage that may
  // lag behind by up to queue_depth items (writing) and should run on what the others leave.
  int nice = 0;
};

// One stage's wall times over a run (romunect/sensor/clock.h), in seconds.
struct PipelineStageTiming {
  std::string name;
  int items = 0;         // items the stage function ran on
  double busy_s = 0.0;   // in the stage function
  double cpu_s = 0.0;    // CPU time of the stage's thread in the stage function
  double wait_s = 0.0;   // waiting for an item from the stage before (starved)
  double block_s = 0.0;  // waiting for room in the next stage's queue (back pressure)
};

// The untyped engine behind FramePipeline: items travel as shared_ptr<void> (move-only items
// allowed), one allocation per frame.
class PipelineEngine {
 public:
  using Item = std::shared_ptr<void>;
  using Source = std::function<bool(Item*)>;  // makes and fills the next item; false at the end
  using Stage = std::function<void(void*)>;

  PipelineEngine() = default;
  ~PipelineEngine();  // stops a running pipeline and joins its threads
  PipelineEngine(const PipelineEngine&) = delete;
  PipelineEngine& operator=(const PipelineEngine&) = delete;

  void SetSource(PipelineStageOptions options, Source source);
  void AddStage(PipelineStageOptions options, Stage stage);
  void Start();   // starts a thread per stage; once
  void Finish();  // waits for the end of the stream, joins, rethrows the first failure
  std::vector<PipelineStageTiming> timings() const;  // after Finish(): per stage, source first

 private:
  struct Entry {
    int64_t sequence = 0;
    Item item;
  };
  struct StageSlot {
    PipelineStageOptions options;
    Stage stage;
    std::deque<Entry> input;  // empty for the source
    bool done = false;        // the stage has ended (its thread returns)
    PipelineStageTiming timing;
  };
  void RunSource();
  void RunStage(size_t index);
  // Hands an item to stage `index` (blocks while its queue is full); false when stopping.
  bool PushLocked(std::unique_lock<std::mutex>* lock, size_t index, Entry entry, double* block_s);
  void FailLocked(int64_t sequence, std::exception_ptr failure);
  void StopAndJoin();

  Source source_;
  std::vector<StageSlot> stages_;  // [0] is the source
  mutable std::mutex mutex_;
  std::condition_variable changed_;
  bool started_ = false, finished_ = false, stopping_ = false;
  int64_t failed_at_ = -1;  // sequence of the earliest failed item; -1: none
  std::exception_ptr failure_;
  std::vector<std::thread> threads_;
};

// The typed pipeline: a work item type (a frame and what its stages need, such as a geometry
// buffer between rendering and IR synthesis), a source and stages in order.
//
//   FramePipeline<Work> pipeline;
//   pipeline.SetSource({"render"}, [&](Work* w) { return scanner.Render(w); });
//   pipeline.AddStage({"fuse", 2}, [&](Work* w) { Fuse(w->frame); });
//   pipeline.AddStage({"write", 16, 10}, [&](Work* w) { writer.Add(w->frame); });
//   pipeline.Run();  // rethrows a stage's exception
template <class Item>
class FramePipeline {
 public:
  // `source` fills a default-constructed item for the next frame; false: the stream has ended.
  void SetSource(PipelineStageOptions options, std::function<bool(Item*)> source) {
    engine_.SetSource(std::move(options), [source = std::move(source)](PipelineEngine::Item* item) {
      auto next = std::make_shared<Item>();
      if (!source(next.get())) return false;
      *item = std::move(next);
      return true;
    });
  }
  void AddStage(PipelineStageOptions options, std::function<void(Item*)> stage) {
    engine_.AddStage(std::move(options), [stage = std::move(stage)](void* item) { stage(static_cast<Item*>(item)); });
  }
  void Start() { engine_.Start(); }
  void Finish() { engine_.Finish(); }
  void Run() {
    Start();
    Finish();
  }
  std::vector<PipelineStageTiming> timings() const { return engine_.timings(); }

 private:
  PipelineEngine engine_;
};

}  // namespace romunect
