// The dataset job's cost (docs/performance.md): CPU per annotated image against the CPU of a
// `romunect scan` frame in the same process, images per hour and megabytes per image, and the
// extrapolation to a 16-core node. An annotated image costs everything its scene costs (the
// pile's settling, the approach's physics, the views' IK), rendering, IR synthesis, the depth
// engine, a silhouette render per object and every file; a scan frame its loop's CPU
// (rendering, imaging, fusion, the frame directory).
//   dataset_benchmark --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>

#include <unistd.h>

#include <filesystem>
#include <string>

#include "romunect/tools/jobs/dataset.h"
#include "romunect/tools/jobs/scan.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

// Scenes are independent processes' work (shards): a node runs one single-threaded shard per
// core, so its rate is cores / (CPU seconds per image), less what the cores share (memory
// bandwidth, file system), which this does not model.
constexpr int kNodeCores = 16;

void BM_DatasetVsScan(benchmark::State& state) {
  const fs::path dir = fs::temp_directory_path() / ("romunect_dataset_benchmark_" + std::to_string(getpid()));
  for (auto _ : state) {
    fs::remove_all(dir);
    ScanJobOptions scan;
    scan.out = (dir / "scan").string();
    scan.threads = 1;
    const ScanSummary scanned = RunScan(scan);
    const double scan_frame_cpu_s = scanned.report.loop_cpu_s / scanned.report.scan_stats.frames;

    DatasetOptions options;
    options.out = (dir / "dataset").string();
    options.scenes = static_cast<int>(state.range(0));
    options.threads = 1;
    options.quiet = true;
    const DatasetSummary data = RunDataset(options);
    const double image_cpu_s = data.image_cpu_s / data.images;
    state.counters["scan_frame_cpu_ms"] = 1e3 * scan_frame_cpu_s;
    state.counters["image_cpu_ms"] = 1e3 * image_cpu_s;
    state.counters["image_over_frame"] = image_cpu_s / scan_frame_cpu_s;
    state.counters["images"] = data.images;
    state.counters["instances_per_image"] = static_cast<double>(data.annotations) / data.images;
    state.counters["mb_per_image"] = data.mb_written / data.images;
    state.counters["images_per_hour_1_core"] = 3600.0 / image_cpu_s;
    state.counters["images_per_hour_16_cores"] = kNodeCores * 3600.0 / image_cpu_s;
  }
  fs::remove_all(dir);
}
BENCHMARK(BM_DatasetVsScan)->Arg(4)->Iterations(1)->Unit(benchmark::kSecond);

}  // namespace
}  // namespace romunect::jobs

BENCHMARK_MAIN();
