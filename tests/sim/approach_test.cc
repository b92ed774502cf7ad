#include "romunect/sim/approach.h"

#include <cmath>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/scanner.h"

namespace romunect::sim {
namespace {

// The plan's own poses are exact up to IK's convergence tolerance (1e-6 m).
constexpr double kPlanToleranceM = 1e-5;
// A DLS-driven position servo tracks with a peak error of about 3 mm; we
// allow 5 mm at 0.3 m/s with lateral passes.
constexpr double kMaxTrackingErrorM = 5e-3;
// After the hold at the end, the servo has converged: below the sensor's 0.1 mm accuracy.
constexpr double kSettledErrorM = 1e-4;

TEST(ApproachTest, PlanDescendsFromStartToWorkingDistanceWithPassesCoveringTheRegion) {
  World world(WorldOptions{});
  const CameraModel camera = RigPreset("romunect").camera;
  ApproachOptions options;
  const ApproachPlan plan = PlanApproach(world, camera, options);
  const Pose T_W_Bin = world.T_W_Bin();
  const Eigen::Vector3d start = T_W_Bin.inverse() * plan.T_W_C.front().translation();
  const Eigen::Vector3d end = T_W_Bin.inverse() * plan.T_W_C.back().translation();
  EXPECT_NEAR(start.z(), 0.40, kPlanToleranceM);
  EXPECT_NEAR(end.z(), 0.20, kPlanToleranceM);
  // The footprint at 200 mm (about 6 x 4.5 cm) needs 3 x 2 passes over 150 x 80 mm.
  const double foot_x = 0.2 * camera.width / camera.fx, foot_y = 0.2 * camera.height / camera.fy;
  EXPECT_EQ(plan.passes_x, static_cast<int>(std::ceil(0.15 / (0.9 * foot_x))));
  EXPECT_EQ(plan.passes_y, static_cast<int>(std::ceil(0.08 / (0.9 * foot_y))));
  EXPECT_GT(plan.passes_x * plan.passes_y, 1);
  // About a second at 0.3 m/s: the duration is the length at speed plus the two ramps.
  EXPECT_GT(plan.duration_s(), plan.length_m / options.speed_m_s);
  EXPECT_LT(plan.duration_s(), plan.length_m / options.speed_m_s + 2 * options.speed_m_s / options.acceleration_m_s2);
  for (size_t k = 0; k < plan.q.size(); k += 50) {
    const PoseError e = ComparePoses(world.ForwardKinematics(plan.q[k], ArmSite::kCamera), plan.T_W_C[k]);
    EXPECT_LT(e.translation_m, kPlanToleranceM);
  }
}

// The default options with the rig's focused range, as the Scanner fills them.
ApproachOptions FocusedOptions(const DepthRange& range) {
  ApproachOptions options;
  options.focused_near_m = range.near_m;
  options.focused_far_m = range.far_m;
  return options;
}

// The stand-off levels from the rig's focused range: every height from the table around the
// bin to above the rim (piles stand above it) lies inside some level's range, both ends
// mid-range. With Sweep::kLevels the passes run at the levels (flat serpentine legs).
TEST(ApproachTest, StandOffLevelsCoverTableToAboveTheRimWithTheFocusedRange) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  const DepthRange range = MeasurableDepthRange(rig);
  ApproachOptions options = FocusedOptions(range);
  options.sweep = ApproachOptions::Sweep::kLevels;
  const ApproachPlan plan = PlanApproach(world, rig.camera, options);
  const double top = world.bin_inner_size_m().z() + options.above_rim_m, low = options.surface_low_m;
  const double mid = 0.5 * (range.near_m + range.far_m);
  ASSERT_GE(plan.levels_m.size(), 3u);  // 55 mm of heights vs a ~2 cm range
  EXPECT_NEAR(plan.levels_m.front(), top + mid, 1e-9);
  EXPECT_NEAR(plan.levels_m.back(), low + mid, 1e-9);
  for (double h = low; h <= top; h += 0.5e-3) {
    bool seen = false;
    for (double level : plan.levels_m) seen |= level - h >= range.near_m && level - h <= range.far_m;
    EXPECT_TRUE(seen) << "height " << h;
  }
  const Pose T_Bin_W = world.T_W_Bin().inverse();
  int at_levels = 0;
  for (const Pose& T_W_C : plan.T_W_C) {
    const double z = (T_Bin_W * T_W_C.translation()).z();
    EXPECT_GT(z, plan.levels_m.back() - kPlanToleranceM);
    EXPECT_LT(z, options.start_distance_m + kPlanToleranceM);
    for (double level : plan.levels_m) at_levels += std::abs(z - level) < 1e-4;
  }
  EXPECT_GT(at_levels, static_cast<int>(plan.T_W_C.size()) / 2);  // most time is spent measuring
}

// The kColumns sweep: at every pass centre the camera passes through all levels (the
// highest and the lowest reached there), the outer centres lie over the bin's walls, the
// approach ends at the lowest level, and the default scan takes 3-6 s at 30 Hz (the paper's 50
// frames and more).
TEST(ApproachTest, ColumnsSweepEveryLevelAtEveryCentreFromWallToWall) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  ApproachOptions options = FocusedOptions(MeasurableDepthRange(rig));
  options.sweep = ApproachOptions::Sweep::kColumns;
  const ApproachPlan plan = PlanApproach(world, rig.camera, options);
  const Eigen::Vector3d inner = world.bin_inner_size_m();
  ASSERT_GE(plan.passes_x, 2);
  ASSERT_GE(plan.passes_y, 2);
  const Pose T_Bin_W = world.T_W_Bin().inverse();
  // Corner smoothing (a 0.1 s box filter, 30 mm of path at 0.3 m/s) cuts the corners at the
  // column ends: the path stays within a few mm of the centre there, and up to 15 mm of the
  // end level (half the filter), still well inside the ~20 mm range of that level.
  constexpr double kNearCentreM = 4e-3, kCornerM = 15e-3;
  for (int j = 0; j < plan.passes_y; ++j) {
    for (int i = 0; i < plan.passes_x; ++i) {
      const Eigen::Vector2d c(inner.x() * (static_cast<double>(i) / (plan.passes_x - 1) - 0.5),
                              inner.y() * (static_cast<double>(j) / (plan.passes_y - 1) - 0.5));
      double z_min = 1e9, z_max = -1e9;
      for (const Pose& T_W_C : plan.T_W_C) {
        const Eigen::Vector3d p = T_Bin_W * T_W_C.translation();
        if ((p.head<2>() - c).norm() > kNearCentreM) continue;
        z_min = std::min(z_min, p.z());
        z_max = std::max(z_max, p.z());
      }
      EXPECT_LT(z_min, plan.levels_m.back() + kCornerM) << "centre " << c.transpose();
      EXPECT_GT(z_max, plan.levels_m.front() - kCornerM) << "centre " << c.transpose();
    }
  }
  EXPECT_NEAR((T_Bin_W * plan.T_W_C.back().translation()).z(), plan.levels_m.back(), kPlanToleranceM);
  const double frames = std::floor(plan.duration_s() * rig.frame_rate_hz) + 1;
  EXPECT_GE(frames, 50);
  EXPECT_GE(plan.duration_s(), 3.0);
  EXPECT_LE(plan.duration_s(), 6.0);
}

TEST(ApproachTest, ExecutedApproachTracksThePlanAtThirtyCentimetresPerSecond) {
  World world(WorldOptions{});
  const ApproachOptions options;
  const ApproachPlan plan = PlanApproach(world, RigPreset("romunect").camera, options);
  ApproachExecutor executor(&world, plan, options);
  executor.MoveToStart();
  EXPECT_LT(ComparePoses(world.T_W_C(), plan.T_W_C.front()).translation_m, kSettledErrorM);
  // Sample at 30 Hz like the sensor: the executed speed stays near the commanded one.
  Eigen::Vector3d last = world.T_W_C().translation();
  double max_speed = 0.0;
  for (int frame = 1; !executor.finished(); ++frame) {
    executor.AdvanceTo(frame / 30.0);
    max_speed = std::max(max_speed, (world.T_W_C().translation() - last).norm() * 30.0);
    last = world.T_W_C().translation();
  }
  EXPECT_LT(executor.tracking().max_position_error_m, kMaxTrackingErrorM);
  EXPECT_LT(max_speed, 1.1 * options.speed_m_s);  // no overshoot beyond 10 %
  EXPECT_GT(max_speed, 0.8 * options.speed_m_s);
  // Holding the last pose: no oscillation, converged below 0.1 mm within 0.3 s.
  world.Step(150);
  EXPECT_LT(ComparePoses(world.T_W_C(), plan.T_W_C.back()).translation_m, kSettledErrorM);
  EXPECT_LT(world.arm_qdot().norm(), 1e-3);
}

TEST(ApproachTest, UnreachableApproachIsAClearError) {
  World world(WorldOptions{});
  ApproachOptions options;
  options.start_distance_m = 1.5;  // far above the arm's reach
  try {
    PlanApproach(world, RigPreset("romunect").camera, options);
    FAIL() << "no exception";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("workspace"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace romunect::sim

namespace romunect::sim {
namespace {

TEST(ApproachTest, OptionsProblemNamesFieldValueAndRule) {
  EXPECT_EQ(ApproachOptions{}.Problem(), "");
  ApproachOptions bad;
  bad.end_distance_m = 0.5;  // above the start
  EXPECT_NE(bad.Problem().find("end_distance_m"), std::string::npos) << bad.Problem();
  bad = ApproachOptions{};
  bad.speed_m_s = -1;
  EXPECT_NE(bad.Problem().find("speed_m_s"), std::string::npos) << bad.Problem();
  World world(WorldOptions{});
  EXPECT_THROW(PlanApproach(world, RigPreset("romunect").camera, bad), InputError);
}

}  // namespace
}  // namespace romunect::sim
