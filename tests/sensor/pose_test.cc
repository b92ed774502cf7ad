#include "romunect/sensor/pose.h"

#include <numbers>
#include <random>

#include <gtest/gtest.h>

#include "romunect/sensor/frames.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

constexpr double kTolerance = 1e-12;  // compositions of a few rotations: round-off only

Pose RandomPose(std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, 1.0);
  const Eigen::Quaterniond q = Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized();
  return MakePose(q.toRotationMatrix(), Eigen::Vector3d(n(rng), n(rng), n(rng)));
}

TEST(Pose, CompositionCancelsInnerFrames) {
  // T_W_C = T_W_B * T_B_H * T_H_C maps a point in C the same as applying each in turn.
  std::mt19937 rng(7);
  const Pose T_W_B = RandomPose(rng), T_B_H = RandomPose(rng), T_H_C = RandomPose(rng);
  const Pose T_W_C = T_W_B * T_B_H * T_H_C;
  const Eigen::Vector3d p_C(0.01, -0.02, 0.2);
  const Eigen::Vector3d p_W = T_W_B * (T_B_H * (T_H_C * p_C));
  EXPECT_LT((T_W_C * p_C - p_W).norm(), kTolerance);
}

TEST(Pose, InverseSwapsFrames) {
  std::mt19937 rng(8);
  const Pose T_a_b = RandomPose(rng);
  const Pose T_b_a = T_a_b.inverse();
  const Eigen::Vector3d p_b(0.3, 0.1, -0.2);
  EXPECT_LT((T_b_a * (T_a_b * p_b) - p_b).norm(), kTolerance);
  EXPECT_TRUE(testing::PosesNear(T_a_b * T_b_a, Pose::Identity(), kTolerance, kTolerance));
}

TEST(Pose, TranslationIsOriginOfChildInParent) {
  // T_W_C.translation() is the camera centre in the world.
  const Pose T_W_C = MakePose(Eigen::AngleAxisd(std::numbers::pi, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                              Eigen::Vector3d(0.1, 0.0, 0.4));
  EXPECT_LT((T_W_C * Eigen::Vector3d::Zero() - Eigen::Vector3d(0.1, 0.0, 0.4)).norm(), kTolerance);
  // A camera looking down (z_C = -z_W) sees a point 0.4 m below it at depth 0.4.
  EXPECT_NEAR((T_W_C.inverse() * Eigen::Vector3d(0.1, 0.0, 0.0)).z(), 0.4, kTolerance);
}

TEST(Pose, WFirstQuaternionsConvertByName) {
  // 90 degrees about z: w = cos(45), z = sin(45), stored w-first as MuJoCo does.
  const double h = std::sqrt(0.5);
  const Eigen::Quaterniond q = QuaternionFromWxyz({h, 0.0, 0.0, h});
  EXPECT_LT((q * Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitY()).norm(), kTolerance);
  const auto wxyz = QuaternionToWxyz(q);
  EXPECT_NEAR(wxyz[0], h, kTolerance);
  EXPECT_NEAR(wxyz[3], h, kTolerance);
  const Pose T = MakePoseWxyz({h, 0.0, 0.0, h}, Eigen::Vector3d(1, 2, 3));
  EXPECT_LT((T * Eigen::Vector3d::UnitX() - Eigen::Vector3d(1, 3, 3)).norm(), kTolerance);
}

TEST(Pose, RowMajorRoundTripIsExact) {
  std::mt19937 rng(9);
  const Pose T = RandomPose(rng);
  const Pose back = PoseFromRowMajor(PoseToRowMajor(T));
  EXPECT_EQ(T.matrix(), back.matrix());
  const auto rows = PoseToRowMajor(T);
  EXPECT_EQ(rows[3], T.translation().x());  // row-major: element (0, 3) is t_x
  EXPECT_EQ(rows[12], 0.0);
  EXPECT_EQ(rows[15], 1.0);
}

TEST(Pose, RigidityProblemFindsEachDefect) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  EXPECT_EQ(RigidityProblem(m), "");
  m(0, 0) = 2.0;
  EXPECT_NE(RigidityProblem(m).find("orthonormal"), std::string::npos);
  m = Eigen::Matrix4d::Identity();
  m(0, 0) = -1.0;
  EXPECT_NE(RigidityProblem(m).find("reflection"), std::string::npos);
  m = Eigen::Matrix4d::Identity();
  m(3, 0) = 0.5;
  EXPECT_NE(RigidityProblem(m).find("last row"), std::string::npos);
  m = Eigen::Matrix4d::Identity();
  m(1, 3) = std::numeric_limits<double>::infinity();
  EXPECT_NE(RigidityProblem(m).find("finite"), std::string::npos);
}

TEST(Pose, InterpolationEndsAndMiddle) {
  const Pose A = Pose::Identity();
  const Pose B = MakePose(Eigen::AngleAxisd(0.4, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
                          Eigen::Vector3d(0.2, 0, 0));
  EXPECT_TRUE(testing::PosesNear(InterpolatePose(A, B, 0.0), A, kTolerance, kTolerance));
  EXPECT_TRUE(testing::PosesNear(InterpolatePose(A, B, 1.0), B, kTolerance, kTolerance));
  const Pose mid = InterpolatePose(A, B, 0.5);
  EXPECT_NEAR(RotationAngleRad(mid), 0.2, kTolerance);
  EXPECT_NEAR(mid.translation().x(), 0.1, kTolerance);
}

}  // namespace
}  // namespace romunect
