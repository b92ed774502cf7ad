#include "romunect/sensor/openni2/open_source.h"

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::ScratchDir;

TEST(OpenSource, ClassifiesTheSourceForms) {
  EXPECT_EQ(ClassifySource("/data/scan1"), SourceKind::kFrameDirectory);
  EXPECT_EQ(ClassifySource("scan1/"), SourceKind::kFrameDirectory);
  EXPECT_EQ(ClassifySource("/data/scan1.oni"), SourceKind::kOniFile);
  EXPECT_EQ(ClassifySource("oni://"), SourceKind::kDevice);
  EXPECT_EQ(ClassifySource("oni://1d27/0601@1/5"), SourceKind::kDevice);
  EXPECT_EQ(ClassifySource("romunect:/data/scan1?pace=step"), SourceKind::kDevice);
}

TEST(OpenSource, OpensDirectoriesDevicesAndRecordingsAlike) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 21);
  auto directory = OpenSource(dir.path().string());
  EXPECT_NE(dynamic_cast<FrameDirectorySource*>(directory.get()), nullptr);

  VirtualDeviceOptions step;
  step.pace = VirtualDeviceOptions::Pace::kStep;
  OpenSourceOptions options;
  options.openni2.record_oni = dir / "rec.oni";
  auto device = OpenSource("oni://" + VirtualDeviceUri(dir.path(), step), options);
  ASSERT_NE(dynamic_cast<OpenNI2Source*>(device.get()), nullptr);
  Frame a, b;
  std::string error;
  int n = 0;
  while (device->Next(&a, &error) == FrameStatus::kOk) ++n;
  EXPECT_EQ(n, 3);
  device.reset();  // finishes the recording

  // The recording with a pose log: poses at the frame times.
  PoseLog({{0.0, Pose::Identity()}, {1.0, MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 1))}})
      .Save(dir / "poses.csv");
  OpenSourceOptions with_log;
  with_log.pose_log = dir / "poses.csv";
  auto recording = OpenSource((dir / "rec.oni").string(), with_log);
  ASSERT_NE(dynamic_cast<PoseLogSource*>(recording.get()), nullptr);
  ASSERT_EQ(recording->Next(&b, &error), FrameStatus::kOk) << error;
  ASSERT_EQ(recording->Next(&b, &error), FrameStatus::kOk) << error;
  EXPECT_EQ(b.index, 1);
  ASSERT_TRUE(b.T_B_H.has_value());
  EXPECT_NEAR(b.T_B_H->translation().z(), b.time_s, 1e-12);
}

TEST(OpenSource, RejectsWhatFitsNoForm) {
  try {
    OpenSource("/no/such/place");
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("/no/such/place: not a directory, a .oni file, oni://[URI] or romunect:DIR"),
              std::string::npos)
        << e.what();
  }
  EXPECT_THROW(OpenSource(""), InputError);
}

}  // namespace
}  // namespace romunect::openni2
