// The virtual device's colour stream, depth-to-colour registration, frames dropped by a source
// slower than real time, and the end of a finite source, as any OpenNI2 program sees them.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <fstream>
#include <string>
#include <thread>
#include <vector>

#include <OpenNI.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/image_io.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::ScratchDir;

// Long enough for a frame at 30 Hz on a loaded machine, short enough to keep the test quick.
constexpr int kFrameWaitMs = 2000;

bool ReadOne(openni::VideoStream& stream, openni::VideoFrameRef* frame) {
  openni::VideoStream* streams[] = {&stream};
  int ready = -1;
  if (openni::OpenNI::waitForAnyStream(streams, 1, &ready, kFrameWaitMs) != openni::STATUS_OK) return false;
  return stream.readFrame(frame) == openni::STATUS_OK && frame->isValid();
}

// `romunect render` of the stock rig before a step 1 m away (its near half on +x, the side of
// the colour camera), with the rendered ground truth as the frames' depth: the registration is
// then checked against the geometry alone, not the depth engine's edge fattening.
std::filesystem::path RenderStepWithTrueDepth(const std::filesystem::path& dir) {
  const auto r = testing::RunRomunect("render " + dir.string() + " --rig kinect-v1 --target step --distance 1.0");
  EXPECT_EQ(r.exit_code, 0) << r.output;
  nlohmann::json manifest = nlohmann::json::parse(testing::ReadText(dir / "frames.json"));
  for (auto& frame : manifest["frames"]) frame["depth"] = frame["gt_depth"];
  std::filesystem::remove(dir / "frames.json");
  testing::WriteText(dir / "frames.json", manifest.dump());
  return dir;
}

TEST(VirtualDeviceColor, OffersThePs1080sColourModesWithRgb888VgaFirst) {
  ScratchDir dir("step");
  RenderStepWithTrueDepth(dir.path() / "frames");
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  VirtualDeviceOptions looped;
  looped.loop = true;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path() / "frames", looped).c_str()), openni::STATUS_OK);
  const openni::SensorInfo* info = device.getSensorInfo(openni::SENSOR_COLOR);
  ASSERT_NE(info, nullptr);
  std::vector<std::string> modes;
  for (int i = 0; i < info->getSupportedVideoModes().getSize(); ++i) {
    const openni::VideoMode& m = info->getSupportedVideoModes()[i];
    modes.push_back(std::to_string(m.getPixelFormat()) + " " + std::to_string(m.getResolutionX()) + "x" +
                    std::to_string(m.getResolutionY()) + "@" + std::to_string(m.getFps()));
  }
  const std::vector<std::string> expected = {"200 640x480@30", "200 320x240@30", "201 640x480@30",
                                             "201 320x240@30", "205 640x480@30", "205 320x240@30"};
  EXPECT_EQ(modes, expected);
  EXPECT_TRUE(device.isImageRegistrationModeSupported(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR));

  openni::VideoStream color;
  ASSERT_EQ(color.create(device, openni::SENSOR_COLOR), openni::STATUS_OK);
  EXPECT_EQ(color.getVideoMode().getPixelFormat(), openni::PIXEL_FORMAT_RGB888);
  ASSERT_EQ(color.start(), openni::STATUS_OK);
  openni::VideoFrameRef frame;
  ASSERT_TRUE(ReadOne(color, &frame));
  EXPECT_EQ(frame.getWidth(), 640);
  EXPECT_EQ(frame.getStrideInBytes(), 640 * 3);
  // The same pixels as the directory's colour image, which the renderer shaded.
  const cv::Mat rendered = ReadPngRgb8(dir.path() / "frames" / "color" / "000000.png");
  EXPECT_EQ(std::memcmp(frame.getData(), rendered.data, 640 * 480 * 3), 0);
  color.stop();
  // QVGA YUV422: 2 bytes a pixel, U Y V Y.
  ASSERT_EQ(color.setVideoMode(info->getSupportedVideoModes()[3]), openni::STATUS_OK);
  ASSERT_EQ(color.start(), openni::STATUS_OK);
  ASSERT_TRUE(ReadOne(color, &frame));
  EXPECT_EQ(frame.getWidth(), 320);
  EXPECT_EQ(frame.getDataSize(), 320 * 240 * 2);
  color.stop();
  color.destroy();
  device.close();
}

// Per row, the first column of the step's near half: where the colour image brightens most (the
// near half is closer to the headlight) and where registered depth drops most.
int FirstNearColumnInColour(const uint8_t* rgb, int width, int v) {
  int best = -1, best_jump = 0;
  for (int u = 1; u < width; ++u) {
    const uint8_t* a = rgb + (v * width + u - 1) * 3;
    const uint8_t* b = rgb + (v * width + u) * 3;
    const int jump = (b[0] + b[1] + b[2]) - (a[0] + a[1] + a[2]);
    if (jump > best_jump) best_jump = jump, best = u;
  }
  return best;
}

int FirstNearColumnInDepth(const uint16_t* depth, int width, int v) {
  int best = -1, best_drop = 0;
  for (int u = 1; u < width; ++u) {
    const int a = depth[v * width + u - 1], b = depth[v * width + u];
    if (a == 0 || b == 0) continue;
    if (a - b > best_drop) best_drop = a - b, best = u;
  }
  return best;
}

TEST(VirtualDeviceColor, RegisteredDepthsEdgeLandsOnTheColourImagesEdge) {
  // One pixel: a point lands on the colour pixel nearest its projection (0.5 px), and each image
  // puts the edge between two pixels (0.5 px).
  constexpr int kEdgeTolerancePx = 1;
  ScratchDir dir("step");
  RenderStepWithTrueDepth(dir.path() / "frames");
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  VirtualDeviceOptions looped;
  looped.loop = true;
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path() / "frames", looped).c_str()), openni::STATUS_OK);
  openni::VideoStream depth, color;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(color.create(device, openni::SENSOR_COLOR), openni::STATUS_OK);
  openni::VideoMode vga = depth.getVideoMode();
  vga.setResolution(640, 480);
  ASSERT_EQ(depth.setVideoMode(vga), openni::STATUS_OK);

  // Unregistered, the edge sits where the depth camera sees it: the colour camera, 25 mm to +x,
  // sees the near half's edge 525 px * 25 mm / 0.83 m ~ 16 px further left.
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  ASSERT_EQ(color.start(), openni::STATUS_OK);
  openni::VideoFrameRef d, c;
  ASSERT_TRUE(ReadOne(depth, &d));
  ASSERT_TRUE(ReadOne(color, &c));
  const auto* rgb = static_cast<const uint8_t*>(c.getData());
  const int v0 = 240;
  const int unregistered_shift = FirstNearColumnInDepth(static_cast<const uint16_t*>(d.getData()), 640, v0) -
                                 FirstNearColumnInColour(rgb, 640, v0);
  EXPECT_GT(unregistered_shift, 10);

  ASSERT_EQ(device.setImageRegistrationMode(openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR), openni::STATUS_OK);
  EXPECT_EQ(device.getImageRegistrationMode(), openni::IMAGE_REGISTRATION_DEPTH_TO_COLOR);
  // Frames already queued were registered or not as they were sent: read until one arrives
  // after the switch, as a PS1080's application does.
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(ReadOne(depth, &d));
  ASSERT_TRUE(ReadOne(color, &c));
  rgb = static_cast<const uint8_t*>(c.getData());
  const auto* registered = static_cast<const uint16_t*>(d.getData());
  int rows = 0;
  for (int v = 120; v < 360; v += 10) {
    const int in_colour = FirstNearColumnInColour(rgb, 640, v);
    const int in_depth = FirstNearColumnInDepth(registered, 640, v);
    ASSERT_GE(in_colour, 0);
    EXPECT_LE(std::abs(in_depth - in_colour), kEdgeTolerancePx) << "row " << v;
    ++rows;
  }
  EXPECT_EQ(rows, 24);
  // Behind the near half's edge, where the colour camera sees the near half over far floor that
  // only the depth camera saw, the nearest point wins: the near depth (~830 mm), not 1000 mm.
  const int edge = FirstNearColumnInColour(rgb, 640, v0);
  EXPECT_LT(registered[v0 * 640 + edge + 2], 900);
  depth.stop();
  color.stop();
  depth.destroy();
  color.destroy();
  device.close();
}

TEST(VirtualDeviceClock, FramesOfASourceSlowerThanRealTimeAreDroppedNotSlowed) {
  // The source takes 70 ms a frame, 2.1 frame intervals at the 30 Hz it announces.
  constexpr double kPeriodUs = 1e6 / 30.0;
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  const std::string uri = std::string("romunect-sim:?feed=") + ROMUNECT_TEST_SLOW_FEED + "&delay_ms=70&frames=12";
  ASSERT_EQ(device.open(uri.c_str()), openni::STATUS_OK) << openni::OpenNI::getExtendedError();
  openni::VideoStream depth;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  std::vector<int> indices;
  std::vector<uint64_t> stamps;
  std::vector<double> wall_us;
  const auto t0 = std::chrono::steady_clock::now();
  openni::VideoFrameRef frame;
  while (indices.size() < 8 && ReadOne(depth, &frame)) {
    indices.push_back(frame.getFrameIndex());
    stamps.push_back(frame.getTimestamp());
    wall_us.push_back(std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count());
  }
  depth.stop();
  depth.destroy();
  device.close();
  ASSERT_EQ(indices.size(), 8u);
  for (size_t i = 1; i < indices.size(); ++i) {
    const int step = indices[i] - indices[i - 1];
    EXPECT_GE(step, 1);
    // Frame times keep to the device's 30 Hz grid: a skipped number is a skipped interval (1 us:
    // timestamps are whole microseconds).
    EXPECT_NEAR(static_cast<double>(stamps[i] - stamps[i - 1]), step * kPeriodUs, 1.0) << "frame " << i;
  }
  // At 70 ms a frame at least every other frame number is skipped (more on a loaded machine).
  EXPECT_GE(indices.back() - indices.front(), 2 * static_cast<int>(indices.size() - 1));
  // Not slowed: the frames' times span the wall time they arrived over, within three intervals
  // (a frame is stamped with the interval it is sent in; the reader may wake a little later).
  EXPECT_NEAR(static_cast<double>(stamps.back() - stamps.front()), wall_us.back() - wall_us.front(), 3 * kPeriodUs);
}

class EndListener : public openni::OpenNI::DeviceDisconnectedListener,
                    public openni::OpenNI::DeviceStateChangedListener {
 public:
  void onDeviceDisconnected(const openni::DeviceInfo* info) override {
    uri = info->getUri();
    disconnected = true;
  }
  void onDeviceStateChanged(const openni::DeviceInfo* /*info*/, openni::DeviceState state) override {
    if (state == openni::DEVICE_STATE_EOF) eof = true;
  }
  std::atomic<bool> disconnected{false}, eof{false};
  std::string uri;
};

TEST(VirtualDeviceEnd, AFiniteSourceEndsWithEndOfFileAndADisconnect) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 43);
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  EndListener listener;
  ASSERT_EQ(openni::OpenNI::addDeviceDisconnectedListener(&listener), openni::STATUS_OK);
  ASSERT_EQ(openni::OpenNI::addDeviceStateChangedListener(&listener), openni::STATUS_OK);
  const std::string uri = VirtualDeviceUri(dir.path());
  openni::Device device;
  ASSERT_EQ(device.open(uri.c_str()), openni::STATUS_OK);
  openni::VideoStream depth;
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  int frames = 0;
  openni::VideoFrameRef frame;
  while (ReadOne(depth, &frame)) ++frames;
  for (int i = 0; i < kFrameWaitMs && !listener.disconnected; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  EXPECT_EQ(frames, 3);
  EXPECT_TRUE(listener.eof);
  EXPECT_TRUE(listener.disconnected);
  EXPECT_EQ(listener.uri, uri);
  depth.stop();
  depth.destroy();
  device.close();
  openni::OpenNI::removeDeviceDisconnectedListener(&listener);
  openni::OpenNI::removeDeviceStateChangedListener(&listener);
}

// A program that closes the device from its disconnect listener, as one does for an unplugged
// sensor: the events come on the driver's own thread, so the close (which waits for the device's
// producer) neither deadlocks nor leaves a thread on a freed device.
class ClosingListener : public openni::OpenNI::DeviceDisconnectedListener {
 public:
  ClosingListener(openni::Device* device, openni::VideoStream* stream) : device_(device), stream_(stream) {}
  void onDeviceDisconnected(const openni::DeviceInfo* /*info*/) override {
    stream_->stop();
    stream_->destroy();
    device_->close();
    closed = true;
  }
  std::atomic<bool> closed{false};

 private:
  openni::Device* device_;
  openni::VideoStream* stream_;
};

TEST(VirtualDeviceEnd, TheDisconnectListenerMayCloseTheDevice) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 44);
  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  openni::VideoStream depth;
  ClosingListener listener(&device, &depth);
  ASSERT_EQ(openni::OpenNI::addDeviceDisconnectedListener(&listener), openni::STATUS_OK);
  ASSERT_EQ(device.open(VirtualDeviceUri(dir.path()).c_str()), openni::STATUS_OK);
  ASSERT_EQ(depth.create(device, openni::SENSOR_DEPTH), openni::STATUS_OK);
  ASSERT_EQ(depth.start(), openni::STATUS_OK);
  for (int i = 0; i < 2 * kFrameWaitMs && !listener.closed; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  EXPECT_TRUE(listener.closed);
  EXPECT_FALSE(device.isValid());
  openni::OpenNI::removeDeviceDisconnectedListener(&listener);
}

}  // namespace
}  // namespace romunect::openni2
