// The virtual device as any OpenNI2 program sees it, through OpenNI2's own C++ API: stream
// start and stop against the realtime producer thread.
#include <dlfcn.h>

#include <atomic>
#include <chrono>
#include <thread>

#include <OpenNI.h>
#include <gtest/gtest.h>

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

}  // namespace
}  // namespace romunect::openni2
