// The info job in-process on a frame directory written by the test.
#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/info.h"

namespace romunect::jobs {
namespace {
using ::testing::HasSubstr;

TEST(InfoJob, CountsFramesImagesAndPoses) {
  testing::ScratchDir dir("info_job");
  testing::WriteSampleFrameDirectory(dir / "frames", testing::SmallCamera(), 3, 5);
  const FrameDirectoryInfo info = InspectFrameDirectory(dir / "frames");
  EXPECT_EQ(info.frames, 3u);
  EXPECT_EQ(info.camera.width, 80);
  EXPECT_EQ(info.with_depth, 3u);
  EXPECT_EQ(info.with_pose, 3u);
  EXPECT_GT(info.path_m, 0.0);
  EXPECT_LE(info.valid_min, info.valid_mean);
  EXPECT_LE(info.valid_mean, info.valid_max);
  const std::string text = FrameDirectoryInfoText(info);
  EXPECT_THAT(text, HasSubstr("frames: 3"));
  EXPECT_THAT(text, HasSubstr("camera positions (world, m)"));
  EXPECT_EQ(info.with_hand_pose, 2u);  // the sample gives every other frame a robot hand pose
  EXPECT_THAT(text, HasSubstr("poses T_W_C 3, T_B_H 2"));
  EXPECT_THAT(text, HasSubstr("valid: all 3 frames read and checked\n"));
}

}  // namespace
}  // namespace romunect::jobs
