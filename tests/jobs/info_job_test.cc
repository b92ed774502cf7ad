// The info job in-process on a frame directory written by the test.
#include <cstdlib>
#include <filesystem>
#include <string>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
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

// Raw-only frames: a quarter of each frame without a measurement (2047), the rest 11-bit codes.
void WriteRawFrames(const std::filesystem::path& dir, const CameraModel& camera, int scale) {
  FrameDirectoryWriter writer(dir, camera);
  for (int i = 0; i < 2; ++i) {
    Frame frame;
    frame.raw = cv::Mat(camera.height, camera.width, CV_16U, cv::Scalar(700 + i));
    frame.raw.rowRange(0, camera.height / 4).setTo(2047);
    frame.raw *= scale;
    frame.T_W_C = Pose::Identity();
    frame.index = i;
    frame.time_s = i / 30.0;
    writer.Add(frame);
  }
  writer.Finish();
}

TEST(InfoJob, ReportsRawValidityAndRefusesRawThatIsNotElevenBits) {
  testing::ScratchDir dir("info_job_raw");
  const CameraModel camera = testing::SmallCamera();
  WriteRawFrames(dir / "raw", camera, 1);
  const FrameDirectoryInfo info = InspectFrameDirectory(dir / "raw");
  EXPECT_EQ(info.with_raw, 2u);
  EXPECT_DOUBLE_EQ(info.raw_valid_mean, 0.75);  // exactly the rows without 2047
  EXPECT_THAT(FrameDirectoryInfoText(info), HasSubstr("valid raw pixels (11-bit, below 2047): mean 75.0 %"));
  // Raw stored x 32 (16-bit scaled): refused, naming the file and what to do, not read as depths.
  WriteRawFrames(dir / "raw32", camera, 32);
  try {
    InspectFrameDirectory(dir / "raw32");
    ADD_FAILURE() << "raw x 32 was accepted";
  } catch (const InputError& e) {
    testing::ExpectContains(e.what(), {"raw32", ".png", "raw depth is 11 bits", "found 65504", "divided back"});
  }
}

// docs/frame-directory.md's Python recipe, as written there, makes a directory info accepts (with
// Debian 12's python3-opencv and python3-numpy, which scripts/setup.sh installs).
TEST(InfoJob, TheDocsPythonRecipeWritesADirectoryInfoAccepts) {
  ASSERT_EQ(std::system("/usr/bin/python3 -c 'import cv2, numpy' >/dev/null 2>&1"), 0)
      << "needs python3-opencv and python3-numpy: run scripts/setup.sh";
  const std::string doc = testing::ReadText(std::filesystem::path(ROMUNECT_SOURCE_DIR) / "docs" / "frame-directory.md");
  const size_t begin = doc.find("```python\n", doc.find("## Writing one from another tool (Python)"));
  ASSERT_NE(begin, std::string::npos);
  const size_t code = begin + 10, end = doc.find("```", code);
  testing::ScratchDir dir("info_job_python_recipe");
  testing::WriteText(dir / "recipe.py", doc.substr(code, end - code));
  const std::string command = "cd '" + dir.path().string() + "' && /usr/bin/python3 recipe.py";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  const FrameDirectoryInfo info = InspectFrameDirectory(dir / "scan");
  EXPECT_EQ(info.frames, 3u);
  EXPECT_EQ(info.with_depth, 3u);
  EXPECT_EQ(info.with_raw, 3u);
  EXPECT_DOUBLE_EQ(info.valid_mean, 1.0);
  EXPECT_DOUBLE_EQ(info.raw_valid_mean, 1.0);
}

}  // namespace
}  // namespace romunect::jobs
