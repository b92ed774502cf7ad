#include "romunect/sim/ik.h"

#include <random>

#include <gtest/gtest.h>

#include "romunect/testing/test_support.h"

namespace romunect::sim {
namespace {

// IK must reach goals within 0.1 mm and 0.05 degrees.
constexpr double kIkToleranceM = 1e-4;
constexpr double kIkToleranceRad = 0.05 * 3.14159265358979323846 / 180.0;

// A configuration with the camera over the bin, looking down (the scan's neighbourhood).
World::ArmVector ScanSeed() {
  World::ArmVector q;
  q << 0.0, 0.3, 0.9, 0.0, 0.37, 0.0;
  return q;
}

TEST(IkTest, ReachesSampledPosesWithinTenthOfMillimetreAndTwentiethOfDegree) {
  World world(WorldOptions{});
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> joint(-0.35, 0.35);
  for (int trial = 0; trial < 20; ++trial) {
    World::ArmVector q_goal = ScanSeed();
    for (int j = 0; j < World::kArmDof; ++j) q_goal[j] += joint(rng);
    const Pose T_W_goal = world.ForwardKinematics(q_goal, ArmSite::kCamera);
    const IkResult ik = SolveIk(world, ArmSite::kCamera, T_W_goal, ScanSeed());
    ASSERT_TRUE(ik.converged) << "trial " << trial << ": " << ik.position_error_m << " m, " << ik.angle_error_rad
                              << " rad";
    // Checked independently of the solver's own error: forward kinematics of its answer.
    EXPECT_TRUE(
        testing::PosesNear(world.ForwardKinematics(ik.q, ArmSite::kCamera), T_W_goal, kIkToleranceRad, kIkToleranceM))
        << "trial " << trial;
  }
}

TEST(IkTest, UnreachableGoalIsReportedNotConverged) {
  World world(WorldOptions{});
  Pose T_W_goal = world.ForwardKinematics(ScanSeed(), ArmSite::kCamera);
  T_W_goal.translation() = Eigen::Vector3d(2.0, 0.0, 0.3);  // twice the arm's reach
  const IkResult ik = SolveIk(world, ArmSite::kCamera, T_W_goal, ScanSeed());
  EXPECT_FALSE(ik.converged);
  EXPECT_GT(ik.position_error_m, 0.5);
}

TEST(IkTest, DoesNotTouchTheSimulationState) {
  World world(WorldOptions{});
  world.SetArmQ(ScanSeed());
  const Pose before = world.T_W_C();
  Pose goal = before;
  goal.translation().z() -= 0.1;
  ASSERT_TRUE(SolveIk(world, ArmSite::kCamera, goal, ScanSeed()).converged);
  EXPECT_TRUE(before.matrix() == world.T_W_C().matrix());  // bit for bit
}

}  // namespace
}  // namespace romunect::sim
