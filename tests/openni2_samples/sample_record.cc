// Recording with the SDK's Recorder, then playing the file back through OpenNI2's file driver.
//   sample_record <out.oni>
#include <chrono>
#include <thread>

#include "sample_common.h"

int main(int argc, char** argv) {
  if (argc != 2) return samples::Fail("usage: sample_record <out.oni>");
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  {
    openni::Device device;
    if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
    openni::VideoStream depth;
    if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
    openni::Recorder recorder;
    if (recorder.create(argv[1]) != openni::STATUS_OK) return samples::Fail("create recorder");
    if (recorder.attach(depth, false) != openni::STATUS_OK) return samples::Fail("attach");
    if (depth.start() != openni::STATUS_OK || recorder.start() != openni::STATUS_OK) return samples::Fail("start");
    std::this_thread::sleep_for(std::chrono::milliseconds(700));  // ~20 frames at 30 Hz
    recorder.stop();
    recorder.destroy();
    depth.stop();
    device.close();
  }
  openni::Device file;
  if (file.open(argv[1]) != openni::STATUS_OK) return samples::Fail("open the recording");
  openni::VideoStream depth;
  if (depth.create(file, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create playback depth");
  const int frames = file.getPlaybackControl()->getNumberOfFrames(depth);
  std::printf("the recording holds %d depth frames\n", frames);
  if (frames < 5) return samples::Fail("recorded frames");
  if (depth.start() != openni::STATUS_OK) return samples::Fail("start playback");
  openni::VideoStream* streams[] = {&depth};
  int ready = -1;
  if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, 3000) != openni::STATUS_OK) return samples::Fail("wait");
  openni::VideoFrameRef frame;
  if (depth.readFrame(&frame) != openni::STATUS_OK || !samples::CentreNear1m(frame)) return samples::Fail("playback");
  depth.stop();
  depth.destroy();  // before the device: libOniFile's player thread may still touch a live stream
  file.close();
  openni::OpenNI::shutdown();
  return 0;
}
