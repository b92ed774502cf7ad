// Fusion benchmark (docs/performance.md): the analytic bin workload (50 frames of 640 x 480, seed 1) fused at
// 0.25 mm over 150 x 80 x 64 mm with our grid (1 and 2 threads; pages on first touch, as fuse
// runs it, and paged in before the loop, as scan runs it), the plain reference of
// tests/fusion, and, when built with ROMUNECT_BENCH_PEERS, Open3D's ScalableTSDFVolume and
// OctoMap. Prints one table (our rows extract on their thread count) and writes JSON (--json
// PATH, default in the build folder), then runs the Google Benchmark cases (insert one frame;
// extract on 1 and 2 threads; the machine's cost of one masked vote block, BM_MaskedVoteBlock)
// unless --no_gbench. --no_reference and --no_peers leave those rows out; --octomap_budget_s
// caps OctoMap's time (it runs >= 1 frame); --frames N renders a shorter approach and --threads N
// keeps only those rows of ours (callgrind).
//
// Times: wall and process CPU time per frame, medians. The machine is shared: say its load when
// quoting numbers. Memory: growth of resident memory while the method's state is alive (the
// pre-rendered frames are excluded), and the state's own size where the library reports it.
#include <malloc.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <string>
#include <vector>

#if defined(__x86_64__)
#include <immintrin.h>
#endif

#include <benchmark/benchmark.h>
#include <nlohmann/json.hpp>

#include "../fusion/reference_fusion.h"
#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/testing/analytic_bin.h"

#ifdef ROMUNECT_BENCH_PEERS
#include <octomap/OcTree.h>

#include <open3d/camera/PinholeCameraIntrinsic.h>
#include <open3d/geometry/Image.h>
#include <open3d/geometry/PointCloud.h>
#include <open3d/geometry/RGBDImage.h>
#include <open3d/pipelines/integration/ScalableTSDFVolume.h>
#endif

namespace romunect::fusion {
namespace {

using testing::AnalyticBin;
using testing::AnalyticBinOptions;

double WallMs() { return std::chrono::duration<double, std::milli>(SteadyClock::now().time_since_epoch()).count(); }
double CpuMs() { return 1e3 * ProcessCpuSeconds(); }
double Median(std::vector<double> v) { return Quantile(std::move(v), 0.5); }

int g_frames = 50;  // --frames N: a shorter approach (e.g. for callgrind)

AnalyticBinOptions WorkloadOptions() {
  AnalyticBinOptions options;
  options.frames = g_frames;
  return options;
}

struct Workload {
  AnalyticBin bin{WorkloadOptions()};
  std::vector<Frame> frames;
  GridOptions grid;
  cv::Mat gt;  // exact height map at the grid's cells
};

const Workload& GetWorkload() {
  static const Workload* workload = [] {
    auto* w = new Workload;
    const double t0 = WallMs();
    for (int i = 0; i < w->bin.frames(); ++i) w->frames.push_back(w->bin.RenderFrame(i));
    w->grid.min_W = AnalyticBin::RegionMin();
    w->grid.max_W = AnalyticBin::RegionMax();
    const Eigen::Vector3i n = w->grid.Dims();
    w->gt = w->bin.GroundTruthHeightMap(w->grid.min_W, w->grid.voxel_m, n.x(), n.y());
    size_t valid = 0;
    for (const Frame& f : w->frames) valid += cv::countNonZero(f.depth_m);
    std::fprintf(stderr, "workload: %zu frames of %d x %d, %.1f %% valid pixels, rendered in %.1f s\n",
                 w->frames.size(), w->bin.camera().width, w->bin.camera().height,
                 100.0 * valid / (w->frames.size() * w->bin.camera().width * w->bin.camera().height),
                 (WallMs() - t0) / 1e3);
    return w;
  }();
  return *workload;
}

// Resident memory before a method's state exists, with the memory that earlier rows freed handed
// back first: the allocator keeps freed chunks resident, and a row's allocations reusing them
// would go uncounted (the 1-thread paged-in row's ray table and hit lists did: 7 MB).
double BaselineRssMb() {
  malloc_trim(0);
  return CurrentRssMb();
}

struct Row {
  std::string method;
  int frames = 0;
  double insert_wall_ms = 0, insert_cpu_ms = 0, insert_p90_ms = 0, extract_ms = 0, memory_mb = 0;
  double state_mb = 0;         // the method's own accounting, where it has one
  double critical_cpu_ms = 0;  // ours: CPU time of the busiest thread per frame (median)
  HeightMapMetrics metrics;
  std::vector<double> completeness_per_frame;
  std::string note;
};

// `paged_in`: the grid's pages are in before the first frame (GridOptions::prefault, as scan
// runs it), so no frame waits for first touches; they cost the most where threads fault at once.
Row RunOurs(int threads, bool paged_in) {
  const Workload& w = GetWorkload();
  Row row;
  row.method = "romunect voting grid, " + std::to_string(threads) + " thread" + (threads > 1 ? "s" : "") +
               (paged_in ? ", paged in" : "");
  const double rss0 = BaselineRssMb();
  GridOptions options = w.grid;
  options.prefault = paged_in;
  VotingGrid grid(options);
  FrameInserter inserter(&grid, InserterOptions{threads});
  std::vector<double> wall, cpu, critical;
  InsertStats stats;
  for (const Frame& f : w.frames) {
    InsertStats frame_stats;
    const double c0 = CpuMs(), t0 = WallMs();
    inserter.Insert(w.bin.camera(), f.depth_m, *f.T_W_C, &frame_stats);
    wall.push_back(WallMs() - t0);
    cpu.push_back(CpuMs() - c0);
    critical.push_back(frame_stats.critical_path_cpu_ms);
    stats.Add(frame_stats);
    row.completeness_per_frame.push_back(Completeness(ExtractHeightMap(grid)));
  }
  std::vector<double> extract;
  cv::Mat height;
  for (int r = 0; r < 15; ++r) {
    const double t0 = WallMs();
    height = ExtractHeightMap(grid, Isa::kAuto, threads);
    extract.push_back(WallMs() - t0);
  }
  row.frames = static_cast<int>(w.frames.size());
  row.insert_wall_ms = Median(wall);
  row.insert_p90_ms = Quantile(wall, 0.9);
  row.insert_cpu_ms = Median(cpu);
  row.critical_cpu_ms = Median(critical);
  row.extract_ms = Median(extract);
  row.memory_mb = CurrentRssMb() - rss0;
  row.state_mb = grid.memory_bytes() / 1e6;
  row.metrics = CompareHeightMaps(height, w.gt);
  row.note = std::string("isa ") + ToString(inserter.isa()) + "; " + stats.BriefReport();
  return row;
}

Row RunReference() {
  const Workload& w = GetWorkload();
  Row row;
  row.method = "plain reference (3D walk, dense)";
  const double rss0 = BaselineRssMb();
  const Eigen::Vector3i n = w.grid.Dims();
  reference::ReferenceGrid ref(w.grid.min_W, w.grid.voxel_m, n.x(), n.y(), n.z());
  reference::ReferenceCounts counts;
  std::vector<double> wall, cpu;
  for (const Frame& f : w.frames) {
    const double c0 = CpuMs(), t0 = WallMs();
    reference::ReferenceInsert(w.bin.camera(), f.depth_m, *f.T_W_C, &ref, &counts);
    wall.push_back(WallMs() - t0);
    cpu.push_back(CpuMs() - c0);
  }
  const double t0 = WallMs();
  const cv::Mat height = reference::ReferenceExtract(ref);
  row.extract_ms = WallMs() - t0;
  row.frames = static_cast<int>(w.frames.size());
  row.insert_wall_ms = Median(wall);
  row.insert_p90_ms = Quantile(wall, 0.9);
  row.insert_cpu_ms = Median(cpu);
  row.memory_mb = CurrentRssMb() - rss0;
  row.state_mb = ref.votes.size() * sizeof(int16_t) / 1e6;
  row.metrics = CompareHeightMaps(height, w.gt);
  return row;
}

#ifdef ROMUNECT_BENCH_PEERS
cv::Mat HeightMapFromPoints(const std::vector<Eigen::Vector3d>& points, const GridOptions& grid) {
  const Eigen::Vector3i n = grid.Dims();
  cv::Mat height(n.y(), n.x(), CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (const Eigen::Vector3d& p : points) {
    const int i = static_cast<int>(std::floor((p.x() - grid.min_W.x()) / grid.voxel_m));
    const int j = static_cast<int>(std::floor((p.y() - grid.min_W.y()) / grid.voxel_m));
    if (i < 0 || j < 0 || i >= n.x() || j >= n.y()) continue;
    float& cell = height.at<float>(j, i);
    if (!(cell >= static_cast<float>(p.z()))) cell = static_cast<float>(p.z());
  }
  return height;
}

Row RunOpen3d() {
  namespace o3d = open3d;
  const Workload& w = GetWorkload();
  Row row;
  row.method = "Open3D ScalableTSDFVolume";
  const double sdf_trunc_m = 4 * w.grid.voxel_m;  // 1 mm: ten times the depth noise
  row.note = "sdf_trunc 1 mm, no colour, height = highest extracted point per cell";
  const double rss0 = BaselineRssMb();
  o3d::pipelines::integration::ScalableTSDFVolume volume(w.grid.voxel_m, sdf_trunc_m,
                                                         o3d::pipelines::integration::TSDFVolumeColorType::NoColor);
  const CameraModel& c = w.bin.camera();
  const o3d::camera::PinholeCameraIntrinsic intrinsic(c.width, c.height, c.fx, c.fy, c.cx, c.cy);
  o3d::geometry::RGBDImage rgbd;
  rgbd.depth_.Prepare(c.width, c.height, 1, 4);
  rgbd.color_.Prepare(c.width, c.height, 3, 1);
  std::vector<double> wall, cpu;
  for (const Frame& f : w.frames) {
    std::memcpy(rgbd.depth_.data_.data(), f.depth_m.data, rgbd.depth_.data_.size());
    const Eigen::Matrix4d T_C_W = f.T_W_C->inverse().matrix();
    const double c0 = CpuMs(), t0 = WallMs();
    volume.Integrate(rgbd, intrinsic, T_C_W);
    wall.push_back(WallMs() - t0);
    cpu.push_back(CpuMs() - c0);
  }
  const double t0 = WallMs();
  const auto cloud = volume.ExtractPointCloud();
  const cv::Mat height = HeightMapFromPoints(cloud->points_, w.grid);
  row.extract_ms = WallMs() - t0;
  row.frames = static_cast<int>(w.frames.size());
  row.insert_wall_ms = Median(wall);
  row.insert_p90_ms = Quantile(wall, 0.9);
  row.insert_cpu_ms = Median(cpu);
  row.memory_mb = CurrentRssMb() - rss0;
  row.metrics = CompareHeightMaps(height, w.gt);
  return row;
}

Row RunOctomap(double budget_s) {
  const Workload& w = GetWorkload();
  Row row;
  row.method = "OctoMap OcTree";
  const double rss0 = BaselineRssMb();
  octomap::OcTree tree(w.grid.voxel_m);
  std::vector<double> wall, cpu;
  const double start = WallMs();
  const CameraModel& c = w.bin.camera();
  const cv::Mat rays = c.RayTable();
  // Frames in an order that spreads over the approach, so a cut-off run still sees all heights.
  std::vector<size_t> order;
  for (size_t stride = 8; stride >= 1; stride /= 2) {
    for (size_t i = 0; i < w.frames.size(); i += stride) {
      if (std::find(order.begin(), order.end(), i) == order.end()) order.push_back(i);
    }
    if (stride == 1) break;
  }
  for (const size_t i : order) {
    if ((WallMs() - start) / 1e3 > budget_s) break;
    const Frame& f = w.frames[i];
    octomap::Pointcloud cloud;
    for (int v = 0; v < c.height; ++v) {
      for (int u = 0; u < c.width; ++u) {
        const float d = f.depth_m.at<float>(v, u);
        if (!(d > 0.0f)) continue;
        const cv::Vec2f r = rays.at<cv::Vec2f>(v, u);
        const Eigen::Vector3d p = *f.T_W_C * Eigen::Vector3d(d * r[0], d * r[1], d);
        cloud.push_back(static_cast<float>(p.x()), static_cast<float>(p.y()), static_cast<float>(p.z()));
      }
    }
    const Eigen::Vector3d o = f.T_W_C->translation();
    const double c0 = CpuMs(), t0 = WallMs();
    tree.insertPointCloud(cloud, octomap::point3d(o.x(), o.y(), o.z()), -1.0, false, true);
    wall.push_back(WallMs() - t0);
    cpu.push_back(CpuMs() - c0);
  }
  const double t0 = WallMs();
  std::vector<Eigen::Vector3d> points;
  for (auto it = tree.begin_leafs(); it != tree.end_leafs(); ++it) {
    if (!tree.isNodeOccupied(*it)) continue;
    const double size = it.getSize(), half = size / 2 - w.grid.voxel_m / 2;
    for (double x = it.getX() - half; x <= it.getX() + half + 1e-9; x += w.grid.voxel_m) {
      for (double y = it.getY() - half; y <= it.getY() + half + 1e-9; y += w.grid.voxel_m) {
        points.emplace_back(x, y, it.getZ() + half);
      }
    }
  }
  const cv::Mat height = HeightMapFromPoints(points, w.grid);
  row.extract_ms = WallMs() - t0;
  row.frames = static_cast<int>(wall.size());
  row.insert_wall_ms = Median(wall);
  row.insert_p90_ms = Quantile(wall, 0.9);
  row.insert_cpu_ms = Median(cpu);
  row.memory_mb = CurrentRssMb() - rss0;
  row.state_mb = tree.memoryUsage() / 1e6;
  row.metrics = CompareHeightMaps(height, w.gt);
  row.note = "discretized insertion (one update per voxel and scan), default sensor model";
  if (row.frames < static_cast<int>(w.frames.size())) {
    row.note += "; stopped after " + std::to_string(row.frames) + " frames (time budget " +
                std::to_string(static_cast<int>(budget_s)) + " s), spread over the approach";
  }
  return row;
}
#endif

void PrintAndWrite(const std::vector<Row>& rows, const std::string& json_path) {
  const Row& ours = rows.front();
  std::printf("\nFusion benchmark: analytic bin, %d frames of 640 x 480, 0.25 mm over 150 x 80 x 64 mm\n", ours.frames);
  std::printf("%-42s %6s %10s %10s %9s %9s %10s %9s %8s %7s %7s %8s %9s\n", "method", "frames", "insert ms",
              "insert cpu", "crit cpu", "p90 ms", "extract ms", "memory MB", "complete", "rmse mm", "mae mm", "<=1 mm",
              "time x us");
  nlohmann::ordered_json j;
  j["workload"] = {{"frames", ours.frames},
                   {"width", 640},
                   {"height", 480},
                   {"voxel_m", 0.25e-3},
                   {"box_m", {-0.075, -0.04, -0.004, 0.075, 0.04, 0.06}},
                   {"seed", 1}};
  j["timing"] =
      "medians over frames in ms: wall, process CPU, and (ours) CPU of the busiest thread, i.e. the wall time "
      "on free cores; the machine is shared, so wall times include waiting for a core";
  for (const Row& r : rows) {
    std::printf("%-42s %6d %10.2f %10.2f %9.2f %9.2f %10.2f %9.1f %7.1f%% %7.3f %7.3f %7.1f%% %9.2f\n",
                r.method.c_str(), r.frames, r.insert_wall_ms, r.insert_cpu_ms, r.critical_cpu_ms, r.insert_p90_ms,
                r.extract_ms, r.memory_mb, 100 * r.metrics.completeness, r.metrics.rmse_mm, r.metrics.mae_mm,
                100 * r.metrics.within_1mm, r.insert_wall_ms / ours.insert_wall_ms);
    j["methods"].push_back({{"method", r.method},
                            {"frames", r.frames},
                            {"insert_ms_median", r.insert_wall_ms},
                            {"insert_cpu_ms_median", r.insert_cpu_ms},
                            {"insert_critical_path_cpu_ms_median", r.critical_cpu_ms},
                            {"insert_ms_p90", r.insert_p90_ms},
                            {"extract_ms", r.extract_ms},
                            {"memory_mb", r.memory_mb},
                            {"state_mb", r.state_mb},
                            {"completeness", r.metrics.completeness},
                            {"rmse_mm", r.metrics.rmse_mm},
                            {"mae_mm", r.metrics.mae_mm},
                            {"within_1mm", r.metrics.within_1mm},
                            {"insert_time_ratio_to_ours_1_thread", r.insert_wall_ms / ours.insert_wall_ms},
                            {"completeness_per_frame", r.completeness_per_frame},
                            {"note", r.note}});
  }
  for (const Row& r : rows) {
    if (!r.note.empty()) std::printf("  %s: %s\n", r.method.c_str(), r.note.c_str());
  }
  std::ofstream(json_path) << j.dump(2) << "\n";
  std::printf("JSON: %s\n", json_path.c_str());
}

// Google Benchmark cases on the same workload.
void BM_InsertFrame(benchmark::State& state) {
  const Workload& w = GetWorkload();
  VotingGrid grid(w.grid);
  FrameInserter inserter(&grid, InserterOptions{static_cast<int>(state.range(0))});
  size_t i = 0;
  for (auto _ : state) {
    const Frame& f = w.frames[i++ % w.frames.size()];
    inserter.Insert(w.bin.camera(), f.depth_m, *f.T_W_C, nullptr);
  }
}
BENCHMARK(BM_InsertFrame)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_ExtractAfterAllFrames(benchmark::State& state) {
  const Workload& w = GetWorkload();
  VotingGrid grid(w.grid);
  FrameInserter inserter(&grid, InserterOptions{2});
  for (const Frame& f : w.frames) inserter.Insert(w.bin.camera(), f.depth_m, *f.T_W_C, nullptr);
  const int threads = static_cast<int>(state.range(0));
  for (auto _ : state) benchmark::DoNotOptimize(ExtractHeightMap(grid, Isa::kAuto, threads));
}
BENCHMARK(BM_ExtractAfterAllFrames)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// The machine's floor for the insertion's votes: the AVX-512 walk applies each (ray, column) run
// as one masked read-modify-write of a 32-vote block (saturating -1). Here the same operation
// runs on a seeded stream of blocks like the walk's (1-12 votes, anywhere in a 64-byte line), at
// random lines of a window of range(0) KiB: from the core's L1 to about the grid's 94 MiB. The
// walk's own stream is mostly cache-local (in the workload, ~70 % of blocks touch a line used
// within the last 512 blocks), so its cost per block lies between the small and large windows;
// times the ~3.4 M blocks of a workload frame, this bounds what any order of the same blocks
// can cost on this machine.
#if defined(__x86_64__)
__attribute__((target("avx512f,avx512bw"))) void ApplyBlocks(Vote* votes, const uint32_t* offset, const uint32_t* bits,
                                                             size_t count) {
  const __m512i one = _mm512_set1_epi16(1), vote_min = _mm512_set1_epi16(-std::numeric_limits<Vote>::max());
  for (size_t i = 0; i < count; ++i) {
    const __mmask32 k = bits[i];
    const __m512i v = _mm512_maskz_loadu_epi16(k, votes + offset[i]);
    _mm512_mask_storeu_epi16(votes + offset[i], k, _mm512_max_epi16(_mm512_sub_epi16(v, one), vote_min));
  }
}

void BM_MaskedVoteBlock(benchmark::State& state) {
  if (!CpuSupports(Isa::kAvx512)) {
    state.SkipWithError("needs AVX-512 (the kernel it measures)");
    return;
  }
  const size_t lines = static_cast<size_t>(state.range(0)) * 1024 / 64;
  constexpr size_t kBlocks = 1 << 22;
  std::vector<uint32_t> offset(kBlocks), bits(kBlocks);
  std::mt19937 rng(7);
  for (size_t i = 0; i < kBlocks; ++i) {
    const uint32_t run = 1 + rng() % 12, lo = rng() % (33 - run);
    offset[i] = static_cast<uint32_t>((rng() % lines) * 32 + lo);
    bits[i] = (1u << run) - 1;
  }
  std::vector<Vote> votes(lines * 32 + 32);  // the last block may reach into the next line
  for (auto _ : state) {
    ApplyBlocks(votes.data(), offset.data(), bits.data(), kBlocks);
    benchmark::ClobberMemory();
  }
  state.counters["per_block"] = benchmark::Counter(static_cast<double>(kBlocks) * state.iterations(),
                                                   benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_MaskedVoteBlock)->Arg(32)->Arg(1024)->Arg(16 * 1024)->Arg(96 * 1024)->Unit(benchmark::kMillisecond);
#endif  // __x86_64__

}  // namespace
}  // namespace romunect::fusion

int main(int argc, char** argv) {
  std::string json_path = FUSION_BENCHMARK_JSON;
  bool gbench = true, reference = true, peers = true;
  double octomap_budget_s = 60.0;
  int only_threads = 0;  // --threads N: only our rows with N threads
  std::vector<char*> rest{argv[0]};
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--json" && i + 1 < argc) {
      json_path = argv[++i];
    } else if (a == "--no_gbench") {
      gbench = false;
    } else if (a == "--no_peers") {
      peers = false;
    } else if (a == "--no_reference") {
      reference = false;
    } else if (a == "--frames" && i + 1 < argc) {
      romunect::fusion::g_frames = std::stoi(argv[++i]);
    } else if (a == "--threads" && i + 1 < argc) {
      only_threads = std::stoi(argv[++i]);
      if (only_threads != 1 && only_threads != 2) {
        std::fprintf(stderr, "fusion_benchmark: --threads %d: our rows run 1 or 2 threads\n", only_threads);
        return 2;
      }
    } else if (a == "--octomap_budget_s" && i + 1 < argc) {
      octomap_budget_s = std::stod(argv[++i]);
    } else {
      rest.push_back(argv[i]);
    }
  }
  (void)octomap_budget_s;
  (void)peers;
  using namespace romunect::fusion;
  std::vector<Row> rows;
  for (const bool paged_in : {false, true}) {
    for (const int threads : {1, 2}) {
      if (only_threads == 0 || only_threads == threads) rows.push_back(RunOurs(threads, paged_in));
    }
  }
  if (reference) rows.push_back(RunReference());
#ifdef ROMUNECT_BENCH_PEERS
  if (peers) {
    rows.push_back(RunOpen3d());
    rows.push_back(RunOctomap(octomap_budget_s));
  }
#endif
  PrintAndWrite(rows, json_path);
  if (gbench) {
    int n = static_cast<int>(rest.size());
    benchmark::Initialize(&n, rest.data());
    benchmark::RunSpecifiedBenchmarks();
    benchmark::Shutdown();
  }
  return 0;
}
