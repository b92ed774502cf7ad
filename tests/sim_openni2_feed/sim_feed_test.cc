// The live twin through OpenNI2: the virtual device loads the simulator's feed library
// (libRomunectSimFeed.so) and OpenNI2Source reads its frames through libOpenNI2; they must equal
// the simulator's own frames read directly, bit for bit at the device's depth unit.
#include "romunect/sim/openni2_feed/sim_feed.h"

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include <OpenNI.h>
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/open_source.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::sim_feed {
namespace {

using ::testing::HasSubstr;
using testing::ImagesBitEqual;

// A small pile at a quarter of the rig's resolution, ideal depth and few frames: fast.
constexpr const char* kQuery = "seed=2&objects=4&scale=4&depth=ideal&frames=3";
constexpr int kFrames = 3;
// The device's fields of view travel as floats: the pinhole rebuilt from them is exact to
// float precision only.
constexpr double kFovFocalRelTol = 1e-6;

cv::Mat Quantized(const cv::Mat& depth_m) {
  cv::Mat out(depth_m.size(), CV_32F);
  for (int v = 0; v < depth_m.rows; ++v) {
    for (int u = 0; u < depth_m.cols; ++u) {
      using openni2::DepthUnit;
      out.at<float>(v, u) = openni2::DequantizeDepth(openni2::QuantizeDepth(depth_m.at<float>(v, u), DepthUnit::k100um),
                                                     DepthUnit::k100um);
    }
  }
  return out;
}

TEST(SimFeed, ParsesItsQueryAndRejectsUnknownKeysAndBadValues) {
  const SimFeedOptions o = SimFeedOptions::Parse(kQuery);
  EXPECT_EQ(o.seed, 2u);
  EXPECT_EQ(o.objects, 4);
  EXPECT_EQ(o.scale, 4);
  EXPECT_TRUE(o.ideal_depth);
  EXPECT_EQ(o.frames, 3);
  for (const auto& [query, message] :
       std::vector<std::pair<std::string, std::string>>{{"bogus=1", "unknown or malformed key 'bogus=1'"},
                                                        {"scale=3", "scale = 3: must be 1, 2 or 4"},
                                                        {"seed=x", "'x' is not an integer"},
                                                        {"depth=fuzzy", "unknown or malformed key 'depth=fuzzy'"},
                                                        {"rig=kinect-v3", "rig = kinect-v3"}}) {
    try {
      SimFeedOptions::Parse(query);
      ADD_FAILURE() << query;
    } catch (const InputError& e) {
      EXPECT_THAT(e.what(), HasSubstr(message)) << query;
    }
  }
}

TEST(SimFeed, OpenNI2SourceOverTheLiveFeedGivesTheSimulatorsFrames) {
  openni2::VirtualDeviceOptions step;
  step.pace = openni2::VirtualDeviceOptions::Pace::kStep;
  openni2::OpenNI2SourceOptions options;
  options.uri = openni2::SimFeedUri(kQuery, step);
  options.ir = false;  // ideal depth: the feed has no IR
  openni2::OpenNI2Source device(options);

  sim::Scanner direct(ScanOptionsFor(SimFeedOptions::Parse(kQuery)));
  const CameraModel& truth = direct.camera();
  ASSERT_EQ(device.camera().width, truth.width);
  ASSERT_EQ(device.camera().height, truth.height);
  EXPECT_NEAR(device.camera().fx, truth.fx, kFovFocalRelTol * truth.fx);
  EXPECT_NEAR(device.camera().fy, truth.fy, kFovFocalRelTol * truth.fy);
  EXPECT_THAT(device.Describe(), HasSubstr("romunect live feed"));

  Frame live, expected;
  std::string error;
  for (int i = 0; i < kFrames; ++i) {
    ASSERT_EQ(device.Next(&live, &error), FrameStatus::kOk) << error;
    ASSERT_EQ(direct.Next(&expected, &error), FrameStatus::kOk) << error;
    EXPECT_EQ(live.index, i);
    // The device sends whole microseconds since the first frame.
    EXPECT_EQ(live.time_s, static_cast<double>(std::llround(expected.time_s * 1e6)) * 1e-6) << i;
    EXPECT_TRUE(ImagesBitEqual(live.depth_m, Quantized(expected.depth_m))) << i;
    EXPECT_GT(cv::countNonZero(live.depth_m), live.depth_m.total() / 2) << "the bin fills most of the view";
  }
  EXPECT_EQ(device.Next(&live, &error), FrameStatus::kEndOfStream);
  EXPECT_EQ(device.stats().dropped_frames, 0);
}

// The stock Kinect preset in the live twin: its approach is planned from its own range (about
// 0.48-3.0 m, the bin seen from ~0.7 m), and the device delivers its frames.
TEST(SimFeed, TheStockKinectPresetDeliversFrames) {
  openni2::VirtualDeviceOptions step;
  step.pace = openni2::VirtualDeviceOptions::Pace::kStep;
  openni2::OpenNI2SourceOptions options;
  options.uri = openni2::SimFeedUri("rig=kinect-v1&seed=2&objects=2&scale=4&depth=ideal&frames=3", step);
  options.ir = false;  // ideal depth: the feed has no IR
  openni2::OpenNI2Source device(options);
  Frame live;
  std::string error;
  for (int i = 0; i < 3; ++i) {
    ASSERT_EQ(device.Next(&live, &error), FrameStatus::kOk) << error;
    EXPECT_GT(cv::countNonZero(live.depth_m), live.depth_m.total() / 2) << "the table and the bin fill the view";
  }
  EXPECT_EQ(device.Next(&live, &error), FrameStatus::kEndOfStream);
}

// The live feed's colour stream: the stock colour camera rendered beside the IR camera, scaled
// as the images; what an OpenNI2 program reads is the simulator's own colour image, byte for byte.
TEST(SimFeed, TheLiveFeedsColourStreamIsTheSimulatorsColourImage) {
  const std::string query = "rig=kinect-v1&seed=2&objects=2&scale=4&depth=ideal&frames=3";
  SimFeed direct(SimFeedOptions::Parse(query));
  ASSERT_TRUE(direct.color_camera().has_value());
  EXPECT_EQ(direct.color_camera()->camera.width, 160);
  std::vector<cv::Mat> colors;
  Frame frame;
  while (direct.Next(&frame)) colors.push_back(frame.color.clone());
  ASSERT_EQ(colors.size(), 3u);
  EXPECT_GT(cv::countNonZero(colors[0].reshape(1)), static_cast<int>(colors[0].total())) << "a lit scene";

  ASSERT_EQ(openni::OpenNI::initialize(), openni::STATUS_OK);
  openni::Device device;
  ASSERT_EQ(device.open(openni2::SimFeedUri(query).c_str()), openni::STATUS_OK);
  openni::VideoStream color;
  ASSERT_EQ(color.create(device, openni::SENSOR_COLOR), openni::STATUS_OK);
  EXPECT_EQ(color.getVideoMode().getPixelFormat(), openni::PIXEL_FORMAT_RGB888);
  EXPECT_EQ(color.getVideoMode().getResolutionX(), 160);
  ASSERT_EQ(color.start(), openni::STATUS_OK);
  openni::VideoStream* streams[] = {&color};
  int ready = -1, compared = 0;
  // Realtime pace: a frame the simulator is late with is dropped; those that come are compared.
  while (openni::OpenNI::waitForAnyStream(streams, 1, &ready, 3000) == openni::STATUS_OK) {
    openni::VideoFrameRef f;
    ASSERT_EQ(color.readFrame(&f), openni::STATUS_OK);
    const int i = f.getFrameIndex() - 1;
    if (i < 0 || i >= 3) continue;  // a dropped frame's number lies beyond the source's
    ASSERT_EQ(f.getDataSize(), 160 * 120 * 3);
    EXPECT_EQ(std::memcmp(f.getData(), colors[static_cast<size_t>(i)].data, 160 * 120 * 3), 0) << "frame " << i;
    ++compared;
    if (i == 2) break;  // the source's last frame
  }
  EXPECT_GE(compared, 1);
  color.stop();
  color.destroy();
  device.close();
}

TEST(SimFeed, ABadFeedQueryIsAClearErrorThroughOpenNI2) {
  openni2::OpenNI2SourceOptions options;
  options.uri = openni2::SimFeedUri("bogus=1");
  try {
    openni2::OpenNI2Source device(options);
    ADD_FAILURE() << "opened";
  } catch (const InputError& e) {
    EXPECT_THAT(e.what(), HasSubstr("unknown or malformed key 'bogus=1'"));
  }
}

}  // namespace
}  // namespace romunect::sim_feed
