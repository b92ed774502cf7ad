// A program that reads a finite device to its end and waits, as for an unplugged sensor, for
// OpenNI2's device-disconnected notification (after the device's state turns EOF, as a
// recording's does).
#include <atomic>
#include <chrono>
#include <thread>

#include "sample_common.h"

class EndWatcher : public openni::OpenNI::DeviceDisconnectedListener,
                   public openni::OpenNI::DeviceStateChangedListener {
 public:
  void onDeviceDisconnected(const openni::DeviceInfo* info) override {
    std::printf("disconnected: %s\n", info->getUri());
    disconnected = true;
  }
  void onDeviceStateChanged(const openni::DeviceInfo* /*info*/, openni::DeviceState state) override {
    if (state == openni::DEVICE_STATE_EOF) eof = true;
  }
  std::atomic<bool> disconnected{false}, eof{false};
};

int main() {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  EndWatcher watcher;
  openni::OpenNI::addDeviceDisconnectedListener(&watcher);
  openni::OpenNI::addDeviceStateChangedListener(&watcher);
  openni::Device device;
  if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
  openni::VideoStream depth;
  if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
  if (depth.start() != openni::STATUS_OK) return samples::Fail("start");
  int frames = 0;
  for (int i = 0; i < 300 && !watcher.disconnected; ++i) {
    openni::VideoStream* streams[] = {&depth};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, 10) == openni::STATUS_OK) {
      openni::VideoFrameRef frame;
      if (depth.readFrame(&frame) == openni::STATUS_OK && samples::CentreNear1m(frame)) ++frames;
    }
  }
  std::printf("%d frames, end of file %s, disconnected %s\n", frames, watcher.eof ? "yes" : "no",
              watcher.disconnected ? "yes" : "no");
  depth.stop();
  depth.destroy();
  device.close();
  openni::OpenNI::removeDeviceDisconnectedListener(&watcher);
  openni::OpenNI::removeDeviceStateChangedListener(&watcher);
  openni::OpenNI::shutdown();
  if (frames < 1 || !watcher.eof || !watcher.disconnected) return samples::Fail("end of the source");
  return 0;
}
