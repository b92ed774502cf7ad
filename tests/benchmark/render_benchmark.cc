// Render benchmark (docs/performance.md): the Embree renderer on a procedural 300k-triangle
// bin at 640 x 480 (the `romunect` rig preset: camera at 200 mm above the bin floor), at 1 and
// 2 threads and 1 and 4 samples per pixel (samples -4: the adaptive quality mode, 4 samples at
// edges only), and with each kernel of its own per-ray work; the one-off static BVH build; a per-frame pose
// update of a moving part; and, when the sensor model's IR synthesis and depth engine are
// present, the full frame (render + IR synthesis + depth engine), sequential and pipelined
// (rendering frame n+1 while frame n is synthesized and matched).
//
// Times are wall time (UseRealTime) with the process CPU time beside it; JSON goes to
// render_benchmark.json in the working directory unless --benchmark_out is given.
#include <benchmark/benchmark.h>

#include <cstdlib>
#include <ctime>
#include <future>
#include <string>
#include <vector>

#include "romunect/sensor/clock.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/mesh.h"
#include "romunect/sensor/rig.h"

#if __has_include("romunect/sensor/ir_synthesis.h") && __has_include("romunect/sensor/depth_engine.h")
#define ROMUNECT_HAVE_FULL_FRAME 1
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/ir_synthesis.h"
#endif

namespace romunect::embree {
namespace {

constexpr int kBinTriangles = 300000;

// The bin floor 10 mm behind the rig's 200 mm focus, objects of 5120 triangles, 3-5 mm: a
// shallow pile, mostly within the depth engine's search range around 200 mm.
BinSceneOptions BenchmarkBin() {
  BinSceneOptions bin;
  bin.triangle_count = kBinTriangles;
  bin.distance_m = 0.21;
  bin.min_object_radius_m = 0.003;
  bin.max_object_radius_m = 0.005;
  bin.object_subdivisions = 4;
  return bin;
}

RayScene MakeBinRayScene(int build_threads) {
  const BinSceneOptions bin = BenchmarkBin();
  RaySceneOptions options;
  options.build_threads = build_threads;
  RayScene scene(options);
  scene.AddStatic(MakeBinScene(bin), Pose::Identity(), IrMaterial{0.6f, 0.05f, 30.0f}, 1);
  return scene;
}

// One scene for all benchmarks: the 300k bin plus a small moving plate (a gripper finger).
struct Fixture {
  Rig rig = RigPreset("romunect");
  RayScene scene = MakeBinRayScene(2);
  int plate = -1;
  Fixture() {
    plate = scene.AddMoving(MakeBoxOnPlaneTarget(0.0, 0.01, 0.004, 0.002), PlatePose(0), IrMaterial{0.3f}, 2);
    scene.Commit();
  }
  static Pose PlatePose(int frame) {
    return MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.015, 0.01 - 1e-4 * (frame % 100), 0.19));
  }
  // samples: 1, 4 (thin lens everywhere) or -4 (adaptive: 4 samples at edges only).
  RenderOptions Options(int threads, int samples) const {
    RenderOptions o;
    o.threads = threads;
    o.samples_per_pixel = std::abs(samples);
    o.adaptive = samples < 0;
    o.focus_distance_m = rig.optics.focus_distance_m;
    o.aperture_radius_m = 0.5 * rig.optics.aperture_m;
    return o;
  }
};

Fixture& GetFixture() {
  static Fixture fixture;
  return fixture;
}

void SetRenderCounters(benchmark::State& state, const RenderStats& stats, int64_t frames) {
  state.counters["camera_rays_per_s"] = benchmark::Counter(static_cast<double>(stats.camera_rays) * frames,
                                                           benchmark::Counter::kIsRate);
  state.counters["hit_fraction"] = static_cast<double>(stats.hits) / stats.camera_rays;
  state.counters["lit_fraction"] = static_cast<double>(stats.lit) / std::max<int64_t>(1, stats.hits);
  state.counters["triangles"] = kBinTriangles;
  const CameraModel& camera = GetFixture().rig.camera;
  state.counters["refined_fraction"] = static_cast<double>(stats.refined_pixels) / (camera.width * camera.height);
}

// Renders the fixture from the identity pose once (warm-up) and then once per iteration.
void RunRender(benchmark::State& state, const RenderOptions& options) {
  Fixture& f = GetFixture();
  GeometryRenderer renderer;
  GeometryBuffer buffer;
  RenderStats stats = renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffer);
  for (auto _ : state) {
    stats = renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffer);
    benchmark::DoNotOptimize(buffer.layers[0].p_C.data);
  }
  SetRenderCounters(state, stats, state.iterations());
}

void BM_Render(benchmark::State& state) {
  RunRender(state, GetFixture().Options(static_cast<int>(state.range(0)), static_cast<int>(state.range(1))));
}
BENCHMARK(BM_Render)
    ->ArgNames({"threads", "samples"})
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({1, 4})
    ->Args({2, 4})
    ->Args({1, -4})
    ->Args({2, -4})
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

// One thread, one sample per pixel, with each kernel of the renderer's own per-ray work
// (Isa: 2 sse2, 3 avx2, 4 avx512); skipped where the CPU lacks it.
void BM_RenderKernel(benchmark::State& state) {
  RenderOptions options = GetFixture().Options(1, 1);
  options.isa = static_cast<Isa>(state.range(0));
  if (!options.Problem().empty()) {
    state.SkipWithError(options.Problem().c_str());
    return;
  }
  RunRender(state, options);
  state.SetLabel(ToString(options.isa));
}
BENCHMARK(BM_RenderKernel)
    ->ArgNames({"isa"})
    ->Arg(static_cast<int>(Isa::kAvx512))
    ->Arg(static_cast<int>(Isa::kAvx2))
    ->Arg(static_cast<int>(Isa::kSse2))
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

void BM_StaticBuild(benchmark::State& state) {
  const TriangleMesh mesh = MakeBinScene(BenchmarkBin());
  for (auto _ : state) {
    RaySceneOptions options;
    options.build_threads = static_cast<int>(state.range(0));
    RayScene scene(options);
    scene.AddStatic(mesh, Pose::Identity(), IrMaterial{}, 1);
    scene.Commit();
    benchmark::DoNotOptimize(scene.stats().static_build_s);
  }
}
BENCHMARK(BM_StaticBuild)
    ->ArgNames({"threads"})
    ->Arg(1)
    ->Arg(2)
    ->Iterations(3)
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

void BM_PoseUpdate(benchmark::State& state) {
  Fixture& f = GetFixture();
  int frame = 0;
  for (auto _ : state) {
    f.scene.SetPose(f.plate, Fixture::PlatePose(++frame));
    f.scene.Commit();
  }
  state.counters["static_builds"] = f.scene.stats().static_builds;
}
BENCHMARK(BM_PoseUpdate)->UseRealTime()->MeasureProcessCPUTime()->Unit(benchmark::kMicrosecond);

#ifdef ROMUNECT_HAVE_FULL_FRAME

// IR synthesis alone on the rendered bin (1 or 4 samples), `threads` threads.
void BM_IrSynthesis(benchmark::State& state) {
  Fixture& f = GetFixture();
  GeometryRenderer renderer;
  GeometryBuffer buffer;
  renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, f.Options(2, static_cast<int>(state.range(1))),
                  &buffer);
  IrSynthesisOptions options;
  options.threads = static_cast<int>(state.range(0));
  IrSynthesizer synthesizer(options);
  cv::Mat ir;
  uint64_t seed = 0;
  synthesizer.Prepare(f.rig);  // the pattern's blur levels, once (BM_PatternLevels)
  for (auto _ : state) {
    synthesizer.Synthesize(f.rig, buffer, ++seed, &ir, nullptr);
    benchmark::DoNotOptimize(ir.data);
  }
}
BENCHMARK(BM_IrSynthesis)
    ->ArgNames({"threads", "samples"})
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({1, 4})
    ->Args({1, -4})
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

// The rig's pattern blur levels (IrSynthesizer::Prepare): once per rig, before the first frame.
void BM_PatternLevels(benchmark::State& state) {
  const Fixture& f = GetFixture();
  for (auto _ : state) {
    IrSynthesizer synthesizer;
    synthesizer.Prepare(f.rig);
  }
}
BENCHMARK(BM_PatternLevels)->UseRealTime()->MeasureProcessCPUTime()->Unit(benchmark::kMillisecond);

// Render, IR synthesis and depth engine of one frame, all with `threads` threads.
void BM_FullFrame(benchmark::State& state) {
  Fixture& f = GetFixture();
  const int threads = static_cast<int>(state.range(0));
  const RenderOptions options = f.Options(threads, static_cast<int>(state.range(1)));
  GeometryRenderer renderer;
  GeometryBuffer buffer;
  IrSynthesisOptions synthesis_options;
  synthesis_options.threads = threads;
  IrSynthesizer synthesizer(synthesis_options);
  DepthEngineOptions engine_options = f.rig.depth_engine;
  engine_options.threads = threads;
  DepthEngine engine(engine_options);
  cv::Mat ir;
  DepthEngineOutput depth;
  uint64_t seed = 0;
  // Warm-up: ray tables, the pattern's blur levels, buffers.
  renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffer);
  synthesizer.Synthesize(f.rig, buffer, seed, &ir, nullptr);
  engine.Compute(ir, &depth);
  // Per stage: wall time and the process' CPU time (all threads), as the machine is shared.
  double render_s = 0.0, synthesis_s = 0.0, matching_s = 0.0, cpu_s[3] = {0.0, 0.0, 0.0};
  for (auto _ : state) {
    const double c0 = ProcessCpuSeconds();
    const RenderStats r = renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffer);
    const double c1 = ProcessCpuSeconds();
    IrSynthesisStats s;
    synthesizer.Synthesize(f.rig, buffer, ++seed, &ir, &s);
    const double c2 = ProcessCpuSeconds();
    engine.Compute(ir, &depth);
    const double c3 = ProcessCpuSeconds();
    render_s += r.seconds;
    synthesis_s += s.seconds;
    matching_s += depth.stats.seconds;
    cpu_s[0] += c1 - c0;
    cpu_s[1] += c2 - c1;
    cpu_s[2] += c3 - c2;
  }
  const double n = static_cast<double>(state.iterations());
  state.counters["render_ms"] = 1e3 * render_s / n;
  state.counters["synthesis_ms"] = 1e3 * synthesis_s / n;
  state.counters["matching_ms"] = 1e3 * matching_s / n;
  state.counters["render_cpu_ms"] = 1e3 * cpu_s[0] / n;
  state.counters["synthesis_cpu_ms"] = 1e3 * cpu_s[1] / n;
  state.counters["matching_cpu_ms"] = 1e3 * cpu_s[2] / n;
  state.counters["valid_fraction"] = static_cast<double>(depth.stats.valid) /
                                     (f.rig.camera.width * f.rig.camera.height);
  state.counters["fps"] = benchmark::Counter(n, benchmark::Counter::kIsRate);
}
BENCHMARK(BM_FullFrame)
    ->ArgNames({"threads", "samples"})
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({2, 4})
    ->Args({2, -4})
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

// Two stages on two threads: render frame n+1 (1 thread) while frame n is synthesized and
// matched (1 thread). Throughput is bounded by the slower stage.
void BM_FullFramePipelined(benchmark::State& state) {
  Fixture& f = GetFixture();
  const RenderOptions options = f.Options(1, static_cast<int>(state.range(0)));
  GeometryRenderer renderer;
  GeometryBuffer buffers[2];
  IrSynthesizer synthesizer;
  DepthEngine engine(f.rig.depth_engine);
  cv::Mat ir;
  DepthEngineOutput depth;
  uint64_t seed = 0;
  int current = 0;
  renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffers[current]);
  synthesizer.Synthesize(f.rig, buffers[current], seed, &ir, nullptr);  // warm-up
  for (auto _ : state) {
    auto next = std::async(std::launch::async, [&] {
      renderer.Render(f.scene, f.rig.camera, Pose::Identity(), f.rig.T_C_P, options, &buffers[1 - current]);
    });
    synthesizer.Synthesize(f.rig, buffers[current], ++seed, &ir, nullptr);
    engine.Compute(ir, &depth);
    next.get();
    current = 1 - current;
  }
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_FullFramePipelined)
    ->ArgNames({"samples"})
    ->Arg(1)
    ->Arg(4)
    ->Arg(-4)
    ->UseRealTime()
    ->MeasureProcessCPUTime()
    ->Unit(benchmark::kMillisecond);

#endif  // ROMUNECT_HAVE_FULL_FRAME

}  // namespace
}  // namespace romunect::embree

int main(int argc, char** argv) {
  std::vector<char*> args(argv, argv + argc);
  bool has_out = false;
  for (int i = 1; i < argc; ++i) has_out |= std::string(argv[i]).rfind("--benchmark_out=", 0) == 0;
  std::string out = "--benchmark_out=render_benchmark.json";
  std::string format = "--benchmark_out_format=json";
  if (!has_out) {
    args.push_back(out.data());
    args.push_back(format.data());
  }
  int count = static_cast<int>(args.size());
  benchmark::Initialize(&count, args.data());
  if (benchmark::ReportUnrecognizedArguments(count, args.data())) return 1;
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
