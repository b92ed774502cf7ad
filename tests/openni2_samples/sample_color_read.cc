// A colour + depth reader, as a viewer that overlays depth on colour: colour in its default mode
// (the PS1080's RGB888 VGA), depth registered to the colour camera, read frame by frame from both.
#include "sample_common.h"

namespace {

bool ReadFrom(openni::VideoStream& stream, openni::VideoFrameRef* frame) {
  openni::VideoStream* streams[] = {&stream};
  int ready = -1;
  return openni::OpenNI::waitForAnyStream(streams, 1, &ready, 3000) == openni::STATUS_OK &&
         stream.readFrame(frame) == openni::STATUS_OK;
}

}  // namespace

int main() {
  if (openni::OpenNI::initialize() != openni::STATUS_OK) return samples::Fail("initialize");
  openni::Device device;
  if (device.open(openni::ANY_DEVICE) != openni::STATUS_OK) return samples::Fail("open");
  if (!device.hasSensor(openni::SENSOR_COLOR)) return samples::Fail("no colour sensor");
  if (device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR) != openni::STATUS_OK) {
    return samples::Fail("registration");
  }
  openni::VideoStream depth, color;
  if (depth.create(device, openni::SENSOR_DEPTH) != openni::STATUS_OK) return samples::Fail("create depth");
  if (color.create(device, openni::SENSOR_COLOR) != openni::STATUS_OK) return samples::Fail("create colour");
  const openni::VideoMode mode = color.getVideoMode();
  if (mode.getPixelFormat() != openni::PIXEL_FORMAT_RGB888 || mode.getResolutionX() != 640 ||
      mode.getResolutionY() != 480 || mode.getFps() != 30) {
    return samples::Fail("default colour mode");
  }
  if (depth.start() != openni::STATUS_OK || color.start() != openni::STATUS_OK) return samples::Fail("start");
  for (int i = 0; i < 5; ++i) {
    openni::VideoFrameRef d, c;
    if (!ReadFrom(depth, &d) || !ReadFrom(color, &c)) return samples::Fail("read");
    // The plane fills the view: registered depth at the centre is still the plane's 1 m, and
    // the colour image shows it lit (not black).
    if (!samples::CentreNear1m(d)) return samples::Fail("registered centre depth");
    const auto* rgb = static_cast<const openni::RGB888Pixel*>(c.getData());
    const openni::RGB888Pixel centre = rgb[240 * 640 + 320];
    std::printf("colour frame %d: centre RGB %d %d %d\n", c.getFrameIndex(), centre.r, centre.g, centre.b);
    if (centre.r + centre.g + centre.b < 30) return samples::Fail("colour centre is black");
  }
  depth.stop();
  color.stop();
  depth.destroy();
  color.destroy();
  device.close();
  openni::OpenNI::shutdown();
  return 0;
}
