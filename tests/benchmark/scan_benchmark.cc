// The default scan's wall time (docs/performance.md): settle a pile (range(0) objects), plan the
// approach, then per 30 Hz frame advance the physics, update the instances, render at the
// romunect rig's full resolution, and (range(1) = 1) image it: IR synthesis, depth engine and
// ground-truth depth correction (SensorImager), with rendering, IR synthesis and the depth engine
// on a thread each (the scan pipeline, frame_pipeline.h). range(2) = 1 also fuses every frame
// (insert and the completeness curve's CompletenessTracker, as `romunect scan` does) on a
// pipeline stage of its own; 2: the same, every stage serially on the caller (Scanner::Next);
// range(3): fusion's threads.
// Counters: per-frame milliseconds per stage, the wall time per frame and the real-time
// factor (simulated approach time / wall time of its frames).
#include <benchmark/benchmark.h>

#include <memory>
#include <string>
#include <vector>

#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/frame_pipeline.h"
#include "romunect/sim/scanner.h"
#include "romunect/sim/sensor_imager.h"

namespace romunect::sim {
namespace {

void BM_DefaultScan(benchmark::State& state) {
  for (auto _ : state) {
    ScanOptions options;
    options.pile.num_objects = static_cast<int>(state.range(0));
    options.threads = 2;
    // Serially (fusion:2) every stage runs alone, so its process CPU is its own.
    const bool pipelined = state.range(2) != 2;
    const Stopwatch setup;
    Scanner scanner(options);
    if (state.range(1) == 1) {
      SensorImagerOptions imager;
      imager.threads = 1;  // as romunect scan: imaging on threads of its own beside rendering
      scanner.SetImager(std::make_unique<SensorImager>(options.rig, imager));
    }
    const double setup_s = setup.seconds();
    const ScanBox region = ScanRegionBox(scanner.world(), scanner.options().approach);
    fusion::GridOptions box;
    box.min_W = region.min_W;
    box.max_W = region.max_W;
    std::unique_ptr<fusion::VotingGrid> grid;
    std::unique_ptr<fusion::FrameInserter> inserter;
    std::unique_ptr<fusion::CompletenessTracker> completeness;
    if (state.range(2) > 0) {
      box.prefault = true;  // as romunect scan: no first touches in the loop
      grid = std::make_unique<fusion::VotingGrid>(box);
      inserter = std::make_unique<fusion::FrameInserter>(grid.get(),
                                                         fusion::InserterOptions{static_cast<int>(state.range(3))});
      completeness = std::make_unique<fusion::CompletenessTracker>(*grid);
    }
    double fusion_s = 0.0;
    // Process CPU per stage: meaningful when the stages run one after the other (fusion:2),
    // where nothing else runs between the two clock reads.
    double simulator_cpu_s = 0.0, fusion_cpu_s = 0.0;
    auto fuse = [&](const Frame& frame) {
      benchmark::DoNotOptimize(frame.gt_depth_m.data);
      if (!inserter) return;
      const Stopwatch t;
      const double cpu = ProcessCpuSeconds();
      inserter->Insert(scanner.camera(), frame.depth_m, *frame.T_W_C, nullptr);
      benchmark::DoNotOptimize(completeness->Update(inserter->changed_columns()));
      fusion_cpu_s += ProcessCpuSeconds() - cpu;
      fusion_s += t.seconds();
    };
    const double cpu_start = ProcessCpuSeconds();  // all threads
    const Stopwatch frames_wall;
    std::vector<PipelineStageTiming> timings;
    if (pipelined) {
      FramePipeline<ScanWork> pipeline;
      AddScanStages(&scanner, &pipeline);
      pipeline.AddStage({"fuse", 2}, [&fuse](ScanWork* work) { fuse(work->frame); });
      pipeline.Run();
      timings = pipeline.timings();
    } else {
      Frame frame;
      std::string error;
      for (;;) {
        const double cpu = ProcessCpuSeconds();
        if (scanner.Next(&frame, &error) != FrameStatus::kOk) break;
        simulator_cpu_s += ProcessCpuSeconds() - cpu;
        fuse(frame);
      }
    }
    const double frames_s = frames_wall.seconds();
    const double cpu_s = ProcessCpuSeconds() - cpu_start;
    const ScanStats& s = scanner.stats();
    const double n = s.frames;
    state.counters["frames"] = n;
    state.counters["settle_wall_s"] = s.settle.wall_s;
    state.counters["settle_sim_s"] = s.settle.simulated_s;
    state.counters["setup_s"] = setup_s - s.settle.wall_s;
    state.counters["physics_ms_per_frame"] = 1e3 * s.physics_s / n;
    state.counters["render_ms_per_frame"] = 1e3 * s.render_s / n;
    state.counters["imaging_ms_per_frame"] = 1e3 * s.imaging_s / n;
    state.counters["fusion_ms_per_frame"] = 1e3 * fusion_s / n;
    if (!pipelined) {
      state.counters["simulator_cpu_ms_per_frame"] = 1e3 * simulator_cpu_s / n;
      if (inserter) state.counters["fusion_cpu_ms_per_frame"] = 1e3 * fusion_cpu_s / n;
    }
    if (pipelined && inserter) state.counters["fusion_wait_ms_per_frame"] = 1e3 * timings.back().wait_s / n;
    state.counters["frame_ms"] = 1e3 * frames_s / n;
    // CPU per frame over all threads: on an idle machine with C cores a frame needs at least
    // cpu / C of wall time (real time on 2 cores needs <= 67 ms of CPU per 30 Hz frame).
    state.counters["cpu_ms_per_frame"] = 1e3 * cpu_s / n;
    // Real time: the approach's simulated duration over the wall time of its frames.
    state.counters["realtime_factor"] = s.simulated_s / frames_s;
    state.counters["tracking_max_mm"] = 1e3 * s.tracking.max_position_error_m;
  }
}
BENCHMARK(BM_DefaultScan)
    ->ArgNames({"objects", "imaging", "fusion", "fusion_threads"})
    ->Args({12, 0, 0, 1})
    ->Args({12, 1, 0, 1})
    ->Args({12, 1, 2, 1})
    ->Args({12, 1, 2, 2})
    ->Args({12, 1, 1, 1})
    ->Args({12, 1, 1, 2})
    ->Unit(benchmark::kMillisecond)
    ->Iterations(1);

}  // namespace
}  // namespace romunect::sim

BENCHMARK_MAIN();
