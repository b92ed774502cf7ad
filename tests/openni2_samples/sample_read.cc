// SimpleRead's behaviour: open the first device, start depth in its default mode, poll frames.
#include "sample_common.h"

int main() {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  openni::Device device;
  if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
  openni::VideoStream depth;
  if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
  if (depth.getVideoMode().getPixelFormat() != openni::PIXEL_FORMAT_DEPTH_1_MM) return samples::Fail("default unit");
  if (depth.start() != openni::STATUS_OK) return samples::Fail("start");
  for (int i = 0; i < 10; ++i) {
    openni::VideoStream* streams[] = {&depth};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, 3000) != openni::STATUS_OK) return samples::Fail("wait");
    openni::VideoFrameRef frame;
    if (depth.readFrame(&frame) != openni::STATUS_OK) return samples::Fail("read");
    if (!samples::CentreNear1m(frame)) return samples::Fail("centre depth");
  }
  depth.stop();
  depth.destroy();
  device.close();
  openni::OpenNI::shutdown();
  return 0;
}
