// The hardware path's throughput at the real sensor's size (640 x 480): frames per second through
// libOpenNI2 from the virtual device (step pace: the driver loads each frame from disk) and from
// an .oni recording (OpenNI2's file driver), and the depth conversion kernel alone. The sensor
// delivers 30 Hz; these must stay well above that. Real time: the work runs on OpenNI2's and the
// driver's threads as well as the caller's. Depth-to-colour registration of a VGA frame alone.
#include <filesystem>

#include <benchmark/benchmark.h>

#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

constexpr int kFrames = 30;

CameraModel Vga() {
  CameraModel c;  // the stock 640 x 480 defaults
  return c;
}

// A 640 x 480 frame directory and its .oni recording, made once per process.
const std::filesystem::path& Fixture() {
  static const std::filesystem::path dir = [] {
    const std::filesystem::path d = std::filesystem::temp_directory_path() / "romunect_openni2_benchmark";
    std::filesystem::remove_all(d);
    testing::WriteSampleFrameDirectory(d / "frames", Vga(), kFrames, 7);
    OpenNI2SourceOptions o;
    VirtualDeviceOptions step;
    step.pace = VirtualDeviceOptions::Pace::kStep;
    o.uri = VirtualDeviceUri(d / "frames", step);
    o.record_oni = d / "scan.oni";
    OpenNI2Source source(o);
    Frame f;
    std::string error;
    while (source.Next(&f, &error) == FrameStatus::kOk) {
    }
    return d;
  }();
  return dir;
}

void ReadAll(benchmark::State& state, const std::string& uri) {
  int frames = 0;
  for (auto _ : state) {
    OpenNI2SourceOptions o;
    o.uri = uri;
    OpenNI2Source source(o);
    Frame f;
    std::string error;
    while (source.Next(&f, &error) == FrameStatus::kOk) ++frames;
  }
  state.counters["frames_per_s"] = benchmark::Counter(frames, benchmark::Counter::kIsRate);
}

void BM_VirtualDeviceStepVga(benchmark::State& state) {
  VirtualDeviceOptions step;
  step.pace = VirtualDeviceOptions::Pace::kStep;
  ReadAll(state, VirtualDeviceUri(Fixture() / "frames", step));
}
BENCHMARK(BM_VirtualDeviceStepVga)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

void BM_OniPlaybackVga(benchmark::State& state) { ReadAll(state, (Fixture() / "scan.oni").string()); }
BENCHMARK(BM_OniPlaybackVga)->Unit(benchmark::kMillisecond)->UseRealTime()->Iterations(3);

void BM_DequantizeDepthVga(benchmark::State& state) {
  cv::Mat counts(480, 640, CV_16U), depth(480, 640, CV_32F);
  cv::randu(counts, 1500, 2500);
  for (auto _ : state) {
    for (int v = 0; v < counts.rows; ++v) {
      const uint16_t* in = counts.ptr<uint16_t>(v);
      float* out = depth.ptr<float>(v);
      for (int u = 0; u < counts.cols; ++u) out[u] = DequantizeDepth(in[u], DepthUnit::k100um);
    }
    benchmark::DoNotOptimize(depth.data);
  }
  state.SetItemsProcessed(state.iterations() * counts.total());
}
BENCHMARK(BM_DequantizeDepthVga)->Unit(benchmark::kMicrosecond);

// Depth-to-colour registration of one VGA frame (the stock IR camera's 1 m plane, with a tilt so
// every row lands differently), as the virtual device does for each depth frame when it is on.
void BM_RegisterDepthToColorVga(benchmark::State& state) {
  CameraModel ir;
  ir.fx = ir.fy = 580.0;
  cv::Mat depth(480, 640, CV_32F);
  for (int v = 0; v < depth.rows; ++v) {
    for (int u = 0; u < depth.cols; ++u) depth.at<float>(v, u) = 1.0f + 2e-4f * static_cast<float>(u);
  }
  const ColorCamera color = StockColorCamera();
  for (auto _ : state) {
    cv::Mat registered = RegisterDepthToColor(depth, ir, color, depth.size());
    benchmark::DoNotOptimize(registered.data);
  }
  state.SetItemsProcessed(state.iterations() * depth.total());
}
BENCHMARK(BM_RegisterDepthToColorVga)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace romunect::openni2

BENCHMARK_MAIN();
