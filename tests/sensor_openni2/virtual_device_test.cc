// The virtual device as any OpenNI2 program sees it, through OpenNI2's own C++ API: stream
// start and stop against the realtime producer thread, what it announces, and the PS1080's
// stream properties (mirroring, cropping).
#include <dlfcn.h>

#include <atomic>
#include <chrono>
#include <thread>
#include <vector>

#include <OpenNI.h>
#include <gtest/gtest.h>

#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"
#include "virtual_device_uri.h"

namespace romunect::openni2 {
namespace {

using testing::ScratchDir;

// Long enough for a frame at 30 Hz on a loaded machine, short enough to keep the test quick.
constexpr int kFrameWaitMs = 2000;
// How long the hook holds the producer inside its check-then-wait window: far longer than the
// test thread needs to start a stream.
constexpr int kWindowHoldMs = 300;

std::atomic<int> g_hook_arrivals{0};
std::atomic<bool> g_hook_holds{false};

void HoldTheWindow() {
  ++g_hook_arrivals;
  if (g_hook_holds) std::this_thread::sleep_for(std::chrono::milliseconds(kWindowHoldMs));
}

using SetWaitHook = void (*)(void (*)());

SetWaitHook WaitHookSetter() {
  void* driver = dlopen((DriverDirectory() / kVirtualDriverFile).c_str(), RTLD_NOW | RTLD_NOLOAD);
  if (driver == nullptr) return nullptr;
  auto setter = reinterpret_cast<SetWaitHook>(dlsym(driver, kVirtualDeviceWaitHookSymbol));
  dlclose(driver);  // balances the NOLOAD open; OpenNI2 keeps its own reference
  return setter;
}

bool FrameArrives(openni::VideoStream& stream) {
  openni::VideoStream* streams[] = {&stream};
  int ready = -1;
  if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, kFrameWaitMs) != openni::STATUS_OK) return false;
  openni::VideoFrameRef frame;
  return stream.readFrame(&frame) == openni::STATUS_OK && frame.isValid();
}

// A stream started while the producer has found no stream running but not yet begun to wait
// used to be lost: the producer then waited for ever and the device sent nothing. The hook holds
// the producer in that window while the IR stream starts.
TEST(VirtualDeviceThreads, AStartInsideTheProducersCheckIsNotLost) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 5, 41);
  VirtualDeviceOptions looped;
  looped.loop = true;
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  const SetWaitHook set_hook = WaitHookSetter();
  ASSERT_NE(set_hook, nullptr);
  openni::Device device;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), looped).c_str()), openni::STATUS_OK);
  openni::VideoStream depth, ir;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(ir.create(device, openni::SENSOR_IR), openni::STATUS_OK);
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  ASSERT_TRUE(FrameArrives(depth));

  set_hook(&HoldTheWindow);
  g_hook_holds = true;
  depth.stop();  // the producer finds nothing running and comes to the window
  for (int i = 0; i < kFrameWaitMs && g_hook_arrivals == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  ASSERT_GT(g_hook_arrivals.load(), 0);
  ASSERT_EQ(ir.start(), openni::STATUS_OK);  // while the producer is held in the window
  g_hook_holds = false;
  EXPECT_TRUE(FrameArrives(ir)) << "the start was lost: no IR frame in " << kFrameWaitMs << " ms";
  set_hook(nullptr);
  ir.stop();
  ir.destroy();
  depth.destroy();
  device.close();
}

// The device's clock runs while its streams are stopped, as a PS1080's: after a pause the next
// frame's timestamp has moved on by the pause (it used to move on by one frame period).
TEST(VirtualDeviceThreads, TheClockKeepsRunningWhileStreamsAreStopped) {
  constexpr int kPauseMs = 600;
  // At least the pause less scheduling slack on a loaded machine; frames at 30 Hz.
  constexpr double kMinAdvanceS = 0.4;
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 5, 45);
  VirtualDeviceOptions looped;
  looped.loop = true;
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), looped).c_str()), openni::STATUS_OK);
  openni::VideoStream depth;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  auto read = [&depth](openni::VideoFrameRef* frame) {
    openni::VideoStream* streams[] = {&depth};
    int ready = -1;
    return openni::OpenNI::waitForAnyStream(streams, 1, &ready, kFrameWaitMs) == openni::STATUS_OK &&
           depth.readFrame(frame) == openni::STATUS_OK;
  };
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  openni::VideoFrameRef before, after;
  ASSERT_TRUE(read(&before));
  depth.stop();
  std::this_thread::sleep_for(std::chrono::milliseconds(kPauseMs));
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  ASSERT_TRUE(read(&after));
  const double advance_s = (static_cast<double>(after.getTimestamp()) - static_cast<double>(before.getTimestamp())) *
                           1e-6;
  EXPECT_GE(advance_s, kMinAdvanceS);
  depth.stop();
  depth.destroy();
  device.close();
}

VirtualDeviceOptions StepPace() {
  VirtualDeviceOptions o;
  o.pace = VirtualDeviceOptions::Pace::kStep;
  return o;
}

TEST(VirtualDeviceAnnounces, PrimeSensesVendorNameAndUsbIdsWhenImpersonatingAPs1080) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 42);
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  VirtualDeviceOptions impersonating = StepPace();
  impersonating.impersonate_ps1080 = true;
  openni::Device device;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), impersonating).c_str()), openni::STATUS_OK);
  const openni::DeviceInfo& info = device.getDeviceInfo();
  EXPECT_STREQ(info.getVendor(), "PrimeSense");
  EXPECT_STREQ(info.getName(), "PS1080");
  EXPECT_EQ(info.getUsbVendorId(), 0x1d27);
  EXPECT_EQ(info.getUsbProductId(), 0x0600);
  device.close();
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), StepPace()).c_str()), openni::STATUS_OK);
  EXPECT_STREQ(device.getDeviceInfo().getVendor(), "romunect");
  device.close();
}

// Mirroring flips each row; cropping then sends a sub-rectangle of the flipped image, as the
// PS1080 does. Compared pixel by pixel with the frame directory's depth on the wire (100 um).
TEST(VirtualDeviceStreams, MirroringAndCroppingAsAPs1080) {
  ScratchDir dir("frames");
  const CameraModel camera = testing::SmallCamera();
  testing::WriteSampleFrameDirectory(dir.path(), camera, 2, 43);
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), StepPace()).c_str()), openni::STATUS_OK);
  openni::VideoStream depth;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  openni::VideoMode mode = depth.getVideoMode();
  mode.setPixelFormat(openni::PIXEL_FORMAT_DEPTH_100_UM);
  mode.setResolution(camera.width, camera.height);
  ASSERT_EQ(depth.setVideoMode(mode), openni::STATUS_OK);
  ASSERT_TRUE(depth.isPropertySupported(ONI_STREAM_PROPERTY_MIRRORING));
  ASSERT_EQ(depth.setMirroringEnabled(true), openni::STATUS_OK);
  EXPECT_TRUE(depth.getMirroringEnabled());
  constexpr int kX0 = 10, kY0 = 5, kW = 30, kH = 20;
  EXPECT_NE(depth.setCropping(70, 0, 20, 10), openni::STATUS_OK);  // beyond the 80-px image
  ASSERT_EQ(depth.setCropping(kX0, kY0, kW, kH), openni::STATUS_OK);
  int x0 = 0, y0 = 0, w = 0, h = 0;
  ASSERT_TRUE(depth.getCropping(&x0, &y0, &w, &h));
  EXPECT_EQ(std::vector<int>({x0, y0, w, h}), std::vector<int>({kX0, kY0, kW, kH}));
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  ASSERT_EQ(device.invoke(kVirtualDeviceStepCommand, nullptr, 0), openni::STATUS_OK);
  openni::VideoStream* streams[] = {&depth};
  int ready = -1;
  ASSERT_EQ(openni::OpenNI::waitForAnyStream(streams, 1, &ready, kFrameWaitMs), openni::STATUS_OK);
  openni::VideoFrameRef frame;
  ASSERT_EQ(depth.readFrame(&frame), openni::STATUS_OK);
  ASSERT_EQ(frame.getWidth(), kW);
  ASSERT_EQ(frame.getHeight(), kH);
  EXPECT_TRUE(frame.getCroppingEnabled());
  EXPECT_EQ(frame.getCropOriginX(), kX0);
  EXPECT_EQ(frame.getCropOriginY(), kY0);
  FrameDirectorySource truth(dir.path());
  const Frame expected = LoadFrame(dir.path(), truth.manifest(), 0);
  const auto* data = static_cast<const uint8_t*>(frame.getData());
  int mismatches = 0;
  for (int v = 0; v < kH; ++v) {
    const auto* row = reinterpret_cast<const uint16_t*>(data + static_cast<size_t>(v) * frame.getStrideInBytes());
    for (int u = 0; u < kW; ++u) {
      const float d = expected.depth_m.at<float>(kY0 + v, camera.width - 1 - (kX0 + u));
      if (row[u] != QuantizeDepth(d, DepthUnit::k100um)) ++mismatches;
    }
  }
  EXPECT_EQ(mismatches, 0);
  depth.stop();
  depth.destroy();
  device.close();
}

// A fresh stream starts in the PS1080's default mode: depth in 1 mm at half the frames' size
// (QVGA of VGA frames), every 2nd depth pixel of every 2nd row; IR at half size is 2 x 2 binned.
TEST(VirtualDeviceStreams, DefaultModesAreThePs1080s1mmQvgaWithDecimatedDepthAndBinnedIr) {
  ScratchDir dir("frames");
  const CameraModel camera = testing::SmallCamera();
  testing::WriteSampleFrameDirectory(dir.path(), camera, 2, 44);
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path(), StepPace()).c_str()), openni::STATUS_OK);
  openni::VideoStream depth, ir;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(ir.create(device, openni::SENSOR_IR), openni::STATUS_OK);
  const openni::VideoMode mode = depth.getVideoMode();
  EXPECT_EQ(mode.getPixelFormat(), openni::PIXEL_FORMAT_DEPTH_1_MM);
  EXPECT_EQ(mode.getResolutionX(), camera.width / 2);
  EXPECT_EQ(mode.getResolutionY(), camera.height / 2);
  EXPECT_EQ(mode.getFps(), 30);
  EXPECT_EQ(ir.getVideoMode().getResolutionX(), camera.width / 2);
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  ASSERT_EQ(ir.start(), openni::STATUS_OK);
  ASSERT_EQ(device.invoke(kVirtualDeviceStepCommand, nullptr, 0), openni::STATUS_OK);
  FrameDirectorySource truth(dir.path());
  const Frame expected = LoadFrame(dir.path(), truth.manifest(), 0);
  for (openni::VideoStream* stream : {&depth, &ir}) {
    openni::VideoStream* streams[] = {stream};
    int ready = -1;
    ASSERT_EQ(openni::OpenNI::waitForAnyStream(streams, 1, &ready, kFrameWaitMs), openni::STATUS_OK);
    openni::VideoFrameRef frame;
    ASSERT_EQ(stream->readFrame(&frame), openni::STATUS_OK);
    ASSERT_EQ(frame.getWidth(), camera.width / 2);
    ASSERT_EQ(frame.getHeight(), camera.height / 2);
    int mismatches = 0;
    for (int v = 0; v < frame.getHeight(); ++v) {
      const auto* row = reinterpret_cast<const uint16_t*>(static_cast<const uint8_t*>(frame.getData()) +
                                                          static_cast<size_t>(v) * frame.getStrideInBytes());
      for (int u = 0; u < frame.getWidth(); ++u) {
        uint16_t want = 0;
        if (stream == &depth) {
          want = QuantizeDepth(expected.depth_m.at<float>(2 * v, 2 * u), DepthUnit::k1mm);
        } else {
          const cv::Mat& i = expected.ir;
          want = static_cast<uint16_t>((i.at<uint16_t>(2 * v, 2 * u) + i.at<uint16_t>(2 * v, 2 * u + 1) +
                                        i.at<uint16_t>(2 * v + 1, 2 * u) + i.at<uint16_t>(2 * v + 1, 2 * u + 1) + 2) /
                                       4);
        }
        if (row[u] != want) ++mismatches;
      }
    }
    EXPECT_EQ(mismatches, 0) << (stream == &depth ? "depth" : "IR");
  }
  depth.stop();
  ir.stop();
  depth.destroy();
  ir.destroy();
  device.close();
}

}  // namespace
}  // namespace romunect::openni2
