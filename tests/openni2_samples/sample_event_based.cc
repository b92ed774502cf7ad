// EventBasedRead's behaviour: frames arrive through a listener on OpenNI2's own thread.
#include <atomic>
#include <chrono>
#include <thread>

#include "sample_common.h"

class Counter : public openni::VideoStream::NewFrameListener {
 public:
  void onNewFrame(openni::VideoStream& stream) override {
    openni::VideoFrameRef frame;
    if (stream.readFrame(&frame) == openni::STATUS_OK && samples::CentreNear1m(frame)) ++good;
  }
  std::atomic<int> good{0};
};

int main() {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  openni::Device device;
  if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
  openni::VideoStream depth;
  if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
  Counter counter;
  depth.addNewFrameListener(&counter);
  if (depth.start() != openni::STATUS_OK) return samples::Fail("start");
  for (int i = 0; i < 300 && counter.good < 10; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  depth.stop();
  depth.removeNewFrameListener(&counter);
  std::printf("%d frames through the listener\n", counter.good.load());
  if (counter.good < 10) return samples::Fail("listener frames");
  device.close();
  openni::OpenNI::shutdown();
  return 0;
}
