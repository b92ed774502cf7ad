#include "romunect/sensor/openni2/pose_log.h"

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::ScratchDir;

// At and the reference below run the same InterpolatePose on the same bracket: the poses are
// identical, and ComparePoses' own rounding (acos near 1) reports up to a few 1e-17 rad.
constexpr double kSameOpsAngleRad = 1e-15, kSameOpsTranslationM = 0.0;
// Round trip through "%.17g" text and quaternion <-> matrix conversion.
constexpr double kTextRoundTripAngleRad = 1e-12, kTextRoundTripTranslationM = 1e-15;

std::vector<TimedPose> SamplePoses() {
  std::vector<TimedPose> poses;
  for (int i = 0; i < 6; ++i) {
    TimedPose p;
    p.time_s = 0.05 * i + (i == 3 ? 0.013 : 0.0);  // uneven spacing
    p.T_B_H = MakePose(Eigen::AngleAxisd(0.2 * i, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix(),
                       Eigen::Vector3d(0.5 + 0.01 * i, -0.1 * i, 0.3 - 0.02 * i));
    poses.push_back(p);
  }
  return poses;
}

// The slow, obvious reference: scan every segment for the one holding t.
std::optional<Pose> ReferenceAt(const std::vector<TimedPose>& poses, double t) {
  for (size_t i = 0; i + 1 < poses.size(); ++i) {
    if (t >= poses[i].time_s && t <= poses[i + 1].time_s) {
      if (t == poses[i + 1].time_s) continue;  // take the right bracket at an exact node
      return InterpolatePose(poses[i].T_B_H, poses[i + 1].T_B_H,
                             (t - poses[i].time_s) / (poses[i + 1].time_s - poses[i].time_s));
    }
  }
  if (!poses.empty() && t == poses.back().time_s) return poses.back().T_B_H;
  return std::nullopt;
}

TEST(PoseLog, InterpolatesLikeTheReferenceAndFlagsTimesOutside) {
  const std::vector<TimedPose> poses = SamplePoses();
  const PoseLog log(poses);
  for (double t = -0.01; t < 0.27; t += 0.0031) {
    const auto fast = log.At(t), slow = ReferenceAt(poses, t);
    ASSERT_EQ(fast.has_value(), slow.has_value()) << t;
    if (fast) {
      EXPECT_TRUE(testing::PosesNear(*fast, *slow, kSameOpsAngleRad, kSameOpsTranslationM)) << t;
    }
  }
  for (const TimedPose& p : poses) EXPECT_TRUE(testing::PosesNear(*log.At(p.time_s), p.T_B_H, 1e-12, 1e-15));
  EXPECT_FALSE(log.At(-1e-9).has_value());
  EXPECT_FALSE(log.At(poses.back().time_s + 1e-9).has_value());
}

TEST(PoseLog, SavesAndLoadsTheDocumentedCsv) {
  ScratchDir dir("log");
  const PoseLog log(SamplePoses());
  log.Save(dir / "poses.csv");
  const std::string text = testing::ReadText(dir / "poses.csv");
  EXPECT_NE(text.find("time_s,x_m,y_m,z_m,qw,qx,qy,qz"), std::string::npos);
  const PoseLog back = PoseLog::Load(dir / "poses.csv");
  ASSERT_EQ(back.poses().size(), log.poses().size());
  for (size_t i = 0; i < log.poses().size(); ++i) {
    EXPECT_EQ(back.poses()[i].time_s, log.poses()[i].time_s);
    EXPECT_TRUE(testing::PosesNear(back.poses()[i].T_B_H, log.poses()[i].T_B_H, kTextRoundTripAngleRad,
                                   kTextRoundTripTranslationM));
  }
  // A hand-written log: comments, spaces, a w-first quaternion (90 deg about z).
  testing::WriteText(
      dir / "hand.csv",
      "# robot log\n0.0, 0.5, 0, 0.3, 1, 0, 0, 0\n 1.0 ,0.5,0,0.2, 0.70710678,0,0,0.70710678 # turned\n");
  const PoseLog hand = PoseLog::Load(dir / "hand.csv");
  const Pose mid = *hand.At(0.5);
  EXPECT_NEAR(mid.translation().z(), 0.25, 1e-15);
  EXPECT_NEAR(RotationAngleRad(mid), M_PI / 4, 1e-8);           // half of 90 deg; input rounded to 8 digits
  EXPECT_NEAR(mid.rotation()(1, 0), std::sin(M_PI / 4), 1e-8);  // about +z
}

std::string LoadError(const ScratchDir& dir, const std::string& text) {
  testing::WriteText(dir / "bad.csv", text);
  try {
    PoseLog::Load(dir / "bad.csv");
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(PoseLog, RejectsBadLogsNamingLineAndColumn) {
  ScratchDir dir("log");
  EXPECT_NE(
      LoadError(dir, "0,0,0,0,1,0,0,0\n0,0,0,0,1,0,0,0\n").find("bad.csv: line 2: time_s: 0.000000 does not follow"),
      std::string::npos);
  EXPECT_NE(LoadError(dir, "0,0,0,0,2,0,0,0\n").find("line 1: qw..qz: quaternion norm 2"), std::string::npos);
  EXPECT_NE(LoadError(dir, "0,0,0,0,1,0,0\n").find("line 1: 7 columns, expected 8"), std::string::npos);
  EXPECT_NE(LoadError(dir, "time_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,zero,0,1,0,0,0\n")
                .find("line 2: y_m: 'zero' is not a finite number"),
            std::string::npos);
  EXPECT_NE(LoadError(dir, "# nothing\n").find("holds no poses"), std::string::npos);
  // A header in another order (w last, as ROS writes quaternions) is refused, not read w-first.
  EXPECT_NE(LoadError(dir, "time_s,x_m,y_m,z_m,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n")
                .find("line 1: header 'time_s,x_m,y_m,z_m,qx,qy,qz,qw' is not 'time_s,x_m,y_m,z_m,qw,qx,qy,qz'"),
            std::string::npos);
  EXPECT_NE(LoadError(dir, "0,0,0,nan,1,0,0,0\n").find("z_m: 'nan' is not a finite number"), std::string::npos);
}

TEST(PoseLogSource, SetsHandAndCameraPosesAndFlagsFramesOutsideTheLog) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 5, 3);  // times i / 30
  std::vector<TimedPose> poses = SamplePoses();                                  // 0 .. 0.25 s
  PoseLogSourceOptions options;
  options.time_offset_s = 0.13;  // frames at 0.13 .. 0.263 s on the log's clock: the last is outside
  options.T_H_C = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.1));
  options.T_W_B = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(1, 0, 0));
  PoseLogSource source(std::make_unique<FrameDirectorySource>(dir.path()), PoseLog(poses), options);
  EXPECT_NE(source.Describe().find("poses from a log of 6 entries"), std::string::npos);
  Frame f;
  std::string error;
  for (int i = 0; i < 4; ++i) {
    ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk) << error;
    ASSERT_TRUE(f.T_B_H.has_value());
    const Pose expected = *ReferenceAt(poses, i / 30.0 + 0.13);
    EXPECT_TRUE(testing::PosesNear(*f.T_B_H, expected, kSameOpsAngleRad, kSameOpsTranslationM));
    EXPECT_TRUE(testing::PosesNear(*f.T_W_C, options.T_W_B * expected * *options.T_H_C, 1e-12, 1e-15));
  }
  EXPECT_EQ(source.Next(&f, &error), FrameStatus::kBadFrame);
  EXPECT_NE(error.find("frame 4 at 0.263333 s lies outside the pose log [0, 0.25] s"), std::string::npos) << error;
  EXPECT_FALSE(f.depth_m.empty());  // the images are still there
  EXPECT_EQ(source.Next(&f, &error), FrameStatus::kEndOfStream);
  EXPECT_EQ(source.stats().frames, 4);
  EXPECT_EQ(source.stats().outside_log, 1);
}

}  // namespace
}  // namespace romunect::openni2
