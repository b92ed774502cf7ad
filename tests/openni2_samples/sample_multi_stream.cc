// MultipleStreamRead's behaviour: depth and IR together, read from whichever is ready.
#include "sample_common.h"

int main() {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  openni::Device device;
  if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
  openni::VideoStream depth, ir;
  if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
  if (ir.create(device, openni::SENSOR_IR) != openni::STATUS_OK) return samples::Fail("create IR");
  if (depth.start() != openni::STATUS_OK || ir.start() != openni::STATUS_OK) return samples::Fail("start");
  int depth_frames = 0, ir_frames = 0;
  for (int i = 0; i < 40 && (depth_frames < 5 || ir_frames < 5); ++i) {
    openni::VideoStream* streams[] = {&depth, &ir};
    int ready = -1;
    if (openni::OpenNI::waitForAnyStream(streams, 2, &ready, 3000) != openni::STATUS_OK) return samples::Fail("wait");
    openni::VideoFrameRef frame;
    if (streams[ready]->readFrame(&frame) != openni::STATUS_OK) return samples::Fail("read");
    if (ready == 0) {
      ++depth_frames;
      if (!samples::CentreNear1m(frame)) return samples::Fail("centre depth");
    } else {
      ++ir_frames;
    }
  }
  std::printf("%d depth and %d IR frames\n", depth_frames, ir_frames);
  if (depth_frames < 5 || ir_frames < 5) return samples::Fail("both streams");
  depth.stop();
  ir.stop();
  device.close();
  openni::OpenNI::shutdown();
  return 0;
}
