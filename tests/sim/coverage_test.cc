#include "romunect/sim/coverage.h"

#include <cmath>
#include <vector>

#include <gtest/gtest.h>
#include <Eigen/Geometry>

#include "romunect/sensor/rig.h"
#include "romunect/sim/scanner.h"

namespace romunect::sim {
namespace {

// Heights compared in metres: planning arithmetic only, no physics.
constexpr double kPlanToleranceM = 1e-9;
// The servos track within a few mm; the planned poses are exact, so 1 mm is generous.
constexpr double kLevelToleranceM = 1e-3;

ApproachOptions RangeOptions(const std::string& rig_name) {
  const DepthRange range = MeasurableDepthRange(RigPreset(rig_name));
  ApproachOptions options;
  options.focused_near_m = range.near_m;
  options.focused_far_m = range.far_m;
  return options;
}

// The romunect rig's options with its frame period, on which the descent is timed.
ApproachOptions TimedOptions() {
  ApproachOptions options = RangeOptions("romunect");
  options.frame_period_s = 1.0 / RigPreset("romunect").frame_rate_hz;
  return options;
}

// The camera's position in the bin frame at each frame of a plan (frame k at k frame periods).
std::vector<Eigen::Vector3d> FramePositions(const World& world, const ApproachPlan& plan, double period_s) {
  const Pose T_Bin_W = world.T_W_Bin().inverse();
  std::vector<Eigen::Vector3d> positions;
  for (int k = 0; k <= static_cast<int>(plan.duration_s() / period_s); ++k) {
    const size_t i = static_cast<size_t>(std::lround(k * period_s / plan.timestep_s));
    positions.push_back((T_Bin_W * plan.T_W_C[std::min(i, plan.T_W_C.size() - 1)]).translation());
  }
  return positions;
}

// Every band is measurable from its level, the bands stack without gaps (the last may overlap)
// from the table to the measured top, and the rim lies in a band: no planned level leaves a surface of the measured
// pile out of range, for the focused romunect rig and the stock Kinect alike.
TEST(CoverageTest, EveryLevelHoldsItsBandInTheMeasurableRange) {
  const double rim_m = 0.035;
  for (const std::string rig : {"romunect", "kinect-v1"}) {
    const ApproachOptions o = RangeOptions(rig);
    for (const double top_m : {0.0, 0.012, 0.05, 0.104}) {
      const std::vector<CoverageLevel> levels = CoverageLevels(o, top_m, rim_m);
      ASSERT_FALSE(levels.empty());
      EXPECT_NEAR(levels.front().low_m, o.surface_low_m, kPlanToleranceM) << rig;
      bool rim_seen = false;
      for (size_t i = 0; i < levels.size(); ++i) {
        const CoverageLevel& l = levels[i];
        EXPECT_GE(l.camera_height_m - l.high_m, o.focused_near_m - kPlanToleranceM) << rig << " top " << top_m;
        EXPECT_LE(l.camera_height_m - l.low_m, o.focused_far_m + kPlanToleranceM) << rig << " top " << top_m;
        rim_seen |= l.low_m <= rim_m && rim_m <= l.high_m;
        if (i > 0 && levels[i - 1].high_m >= top_m) continue;  // the rim's own band may float above
        if (i > 0) {
          EXPECT_LE(l.low_m, levels[i - 1].high_m + kPlanToleranceM) << rig;  // no gap
        }
      }
      EXPECT_TRUE(rim_seen) << rig << " top " << top_m;
      double covered_to = levels.front().high_m;
      for (const CoverageLevel& l : levels) covered_to = std::max(covered_to, l.high_m);
      EXPECT_GE(covered_to, top_m - kPlanToleranceM) << rig;
    }
    // The stock range holds the whole one-layer bin from one level, from under a metre.
    const std::vector<CoverageLevel> stock = CoverageLevels(RangeOptions("kinect-v1"), 0.02, rim_m);
    EXPECT_EQ(stock.size(), 1u);
    EXPECT_LT(stock.front().camera_height_m, 1.0);
  }
}

// The planned approach over the default bin: the descent ends with the table in range, every sample
// of the coverage leg lies between the lowest and the highest level, and the leg ends at one of
// the levels.
TEST(CoverageTest, PlannedFramesStayAtTheMeasuredPilesLevels) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  const ApproachOptions o = RangeOptions("romunect");
  const double top_m = 0.012;
  const ApproachPlan descent = PlanDescent(world, rig.camera, o);
  const ApproachPlan leg = PlanCoverage(world, rig.camera, o, top_m, descent);
  const std::vector<CoverageLevel> levels = CoverageLevels(o, top_m, world.bin_inner_size_m().z());
  ASSERT_EQ(leg.levels_m.size(), levels.size());
  const Pose T_Bin_W = world.T_W_Bin().inverse();
  // the descent stops after the rim's pass, with the rim in range (before the pile is known)
  const double rim_m = world.bin_inner_size_m().z();
  const double z_end = (T_Bin_W * descent.T_W_C.back()).translation().z();
  EXPECT_LE(z_end - rim_m, o.focused_far_m + kLevelToleranceM);
  EXPECT_GE(z_end - rim_m, o.focused_near_m - kLevelToleranceM);
  for (const Pose& T_W_C : leg.T_W_C) {
    const double z = (T_Bin_W * T_W_C).translation().z();
    ASSERT_GE(z, std::min(z_end, levels.front().camera_height_m) - kLevelToleranceM);
    ASSERT_LE(z, levels.back().camera_height_m + kLevelToleranceM);
  }
  const double z_last = (T_Bin_W * leg.T_W_C.back()).translation().z();
  bool at_a_level = false;
  for (const CoverageLevel& l : levels) at_a_level |= std::abs(z_last - l.camera_height_m) < kLevelToleranceM;
  EXPECT_TRUE(at_a_level) << z_last;
  // The hand turns for the second passes: the camera's x points along the bin's +x then.
  bool turned = false;
  for (const Pose& T_W_C : leg.T_W_C) turned |= (T_Bin_W * T_W_C).linear().col(0).x() > 0.9;
  EXPECT_TRUE(turned);
}

// A plane 12 mm above the bin floor seen from 200 mm: the meter's top is the plane's height.
TEST(CoverageTest, PileHeightMeterMeasuresThePlanesHeight) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  const double plane_m = 0.012, camera_m = 0.2;
  Frame frame;
  frame.depth_m = cv::Mat(rig.camera.height, rig.camera.width, CV_32F, cv::Scalar(camera_m - plane_m));
  Eigen::Matrix3d R_Bin_C;
  R_Bin_C << -1, 0, 0, 0, 1, 0, 0, 0, -1;
  frame.T_W_C = world.T_W_Bin() * MakePose(R_Bin_C, Eigen::Vector3d(0, 0, camera_m));
  PileHeightMeter meter(world.T_W_Bin(), world.bin_inner_size_m());
  EXPECT_FALSE(meter.TopM().has_value());  // nothing measured yet
  // a frame with 100 stray points and nothing else (far above the range) adds nothing
  Frame stray = frame;
  stray.depth_m = cv::Mat(rig.camera.height, rig.camera.width, CV_32F, cv::Scalar(0.0f));
  stray.depth_m(cv::Rect(300, 200, 40, 40)).setTo(camera_m - 0.15);
  meter.Add(stray, rig.camera);
  EXPECT_EQ(meter.samples(), 0);
  meter.Add(frame, rig.camera);
  ASSERT_TRUE(meter.TopM().has_value());
  EXPECT_NEAR(*meter.TopM(), plane_m, 1e-5);  // float depth: micrometres
  // 30 stray points 40 mm higher (every 4th pixel of a 20 x 24 block) do not raise the top...
  const double tall_m = 0.052;
  frame.depth_m(cv::Rect(300, 200, 20, 24)).setTo(camera_m - tall_m);
  meter.Add(frame, rig.camera);
  EXPECT_NEAR(*meter.TopM(), plane_m, 1e-5);
  // ... a small object's top does, even among two frames of the plane (100 points of ~38000)
  frame.depth_m(cv::Rect(300, 200, 40, 40)).setTo(camera_m - tall_m);
  meter.Add(frame, rig.camera);
  EXPECT_NEAR(*meter.TopM(), tall_m, 1e-5);
}

// With the sensor's frame period known, a frame of the descent falls on its turn just above the
// first level, where its band holds the bin floor and a one-layer pile, and the frame before it is a full frame
// period's travel higher: the first frame with a one-layer pile in range sees the whole
// footprint. The frames after it run on at that level through the lowest band's first pass,
// whose rows reach the walls on every side, then climb to the rim's level for its pass, where
// the descent stops.
TEST(CoverageTest, DescentPutsAFrameOnItsTurnAtTheFirstLevel) {
  World world(WorldOptions{});
  const ApproachOptions o = TimedOptions();
  const ApproachPlan descent = PlanDescent(world, RigPreset("romunect").camera, o);
  const std::vector<Eigen::Vector3d> frame = FramePositions(world, descent, o.frame_period_s);
  auto at = [&](int k) { return frame.at(k); };
  const int frames = static_cast<int>(frame.size()) - 1;
  ASSERT_EQ(descent.levels_m.size(), 2u);  // the rim (35 mm) lies above the lowest band (19 mm wide)
  const double level_m = descent.levels_m.back(), rim_level_m = descent.levels_m.front();
  int turn = -1;
  for (int k = 0; k <= frames && turn < 0; ++k) {
    if (at(k).z() < level_m + 0.5 * (o.focused_far_m - o.focused_near_m)) turn = k;
  }
  ASSERT_GT(turn, 0);
  // The turn's frame: the band from the bin floor to one range width above it in range (the
  // turn is planned where the corner filter's lift puts it: 0.5 mm for that lift's estimate).
  const Eigen::Vector3d p = at(turn);
  EXPECT_NEAR(p.z(), o.focused_far_m, 0.0005);
  EXPECT_LT(p.head<2>().norm(), 0.01);  // over the bin's middle
  // the frame before: at full speed, 30 mm higher (the ramp's planning: 0.1 mm)
  EXPECT_NEAR(at(turn - 1).z() - p.z(), o.coverage_speed_m_s * o.frame_period_s, 0.004);
  // the frames after run at the level (the corner filter: within 7.5 mm) through the first pass
  Eigen::Vector2d low = Eigen::Vector2d::Zero(), high = Eigen::Vector2d::Zero();
  int k = turn + 1;
  for (; k <= frames && std::abs(at(k).z() - level_m) < 0.0075; ++k) {
    low = low.cwiseMin(at(k).head<2>());
    high = high.cwiseMax(at(k).head<2>());
  }
  // ... over the whole region: frames at the walls (the corner filter pulls the ends in by a
  // few mm), at both ends and both sides
  const Eigen::Vector2d walls = 0.5 * world.bin_inner_size_m().head<2>() - Eigen::Vector2d::Constant(0.004);
  EXPECT_TRUE((-low.array() > walls.array()).all()) << low.transpose();
  EXPECT_TRUE((high.array() > walls.array()).all()) << high.transpose();
  // then at most two frames on the way up, and the rim's pass at its level to the end
  const int first_pass_end = k;
  while (k <= frames && std::abs(at(k).z() - rim_level_m) >= 0.0075) ++k;
  EXPECT_LE(k - first_pass_end, 2);
  int rim_frames = 0;
  for (; k <= frames; ++k) {
    EXPECT_NEAR(at(k).z(), rim_level_m, 0.0075) << k;
    ++rim_frames;
  }
  EXPECT_GE(rim_frames, 4);  // two rows over the bin's outline at 30 mm per frame
}

// The descent's pass over the rim, planned from the bin alone: at frames a frame period apart, the
// footprints of the frames with the rim in range cover the wall tops (the bin's outline less its
// inside), though the frames fall anywhere along the rows.
TEST(CoverageTest, DescentSeesTheWholeRim) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  const ApproachOptions o = TimedOptions();
  const ApproachPlan descent = PlanDescent(world, rig.camera, o);
  const double rim_m = world.bin_inner_size_m().z();
  std::vector<Eigen::Vector3d> in_range;  // the frames' camera positions with the rim in range
  for (const Eigen::Vector3d& p : FramePositions(world, descent, o.frame_period_s)) {
    if (p.z() - rim_m >= o.focused_near_m && p.z() - rim_m <= o.focused_far_m) in_range.push_back(p);
  }
  const Eigen::Vector2d inner = 0.5 * world.bin_inner_size_m().head<2>();
  const double wall_m = 0.005;  // the default bin's walls
  int seen = 0, points = 0;
  for (double x = -inner.x() - wall_m; x <= inner.x() + wall_m; x += 0.001) {
    for (double y = -inner.y() - wall_m; y <= inner.y() + wall_m; y += 0.001) {
      if (std::abs(x) < inner.x() && std::abs(y) < inner.y()) continue;  // inside the bin
      ++points;
      for (const Eigen::Vector3d& p : in_range) {
        const double d = p.z() - rim_m;
        if (std::abs(x - p.x()) < 0.5 * d * rig.camera.width / rig.camera.fx &&
            std::abs(y - p.y()) < 0.5 * d * rig.camera.height / rig.camera.fy) {
          ++seen;
          break;
        }
      }
    }
  }
  // the corner filter rounds the rows' corners: a few points at the outline's corners are left
  EXPECT_GT(seen, 0.97 * points) << seen << " of " << points;
}

// The descent runs at 0.9 m/s with corners a frame period wide; the arm's controller feeds
// forward the inertia its accelerations need, so the executed camera stays within 2.5 mm of the
// plan (position servos with gravity and damping feed-forward alone lag by about 10 mm there).
TEST(CoverageTest, DescentIsTrackedThroughItsCorners) {
  World world(WorldOptions{});
  const ApproachOptions o = TimedOptions();
  const ApproachPlan descent = PlanDescent(world, RigPreset("romunect").camera, o);
  ApproachExecutor executor(&world, descent, o);
  executor.MoveToStart();
  executor.AdvanceTo(descent.duration_s());
  EXPECT_LT(executor.tracking().max_position_error_m, 0.0025);
  EXPECT_LT(executor.tracking().rms_position_error_m, 0.0015);
}

// The rim is swept where a pass of its own is needed, and once: the stock Kinect's wide range
// holds the table and the rim from one level, so its descent has no rim pass; the focused rig's
// descent has one, so a one-layer pile's coverage leg only passes the rim's band on the way up,
// and without turned passes nothing is left to visit.
TEST(CoverageTest, TheRimIsSweptOnceForAOneLayerPile) {
  World world(WorldOptions{});
  EXPECT_EQ(PlanDescent(world, RigPreset("kinect-v1").camera, RangeOptions("kinect-v1")).levels_m.size(), 1u);
  const Rig rig = RigPreset("romunect");
  ApproachOptions o = RangeOptions("romunect");
  o.turned_passes = false;
  const ApproachPlan descent = PlanDescent(world, rig.camera, o);
  ASSERT_EQ(descent.levels_m.size(), 2u);
  const ApproachPlan leg = PlanCoverage(world, rig.camera, o, 0.012, descent);
  ASSERT_EQ(leg.T_W_C.size(), 1u);  // the descent's last sample
  EXPECT_LT(ComparePoses(leg.T_W_C.front(), descent.T_W_C.back()).translation_m, kPlanToleranceM);
}

// A pile above the rim: one of its bands holds the rim, and the coverage leg sweeps that band
// over the bin's outline, out to the walls on both sides, although the descent saw the rim.
TEST(CoverageTest, ATallPilesBandHoldingTheRimSweepsTheOutline) {
  World world(WorldOptions{});
  const Rig rig = RigPreset("romunect");
  const ApproachOptions o = RangeOptions("romunect");
  const double top_m = 0.06, rim_m = world.bin_inner_size_m().z();
  const std::vector<CoverageLevel> levels = CoverageLevels(o, top_m, rim_m);
  const CoverageLevel* rim_band = nullptr;
  for (const CoverageLevel& l : levels) {
    EXPECT_FALSE(l.rim_only);
    if (l.low_m <= rim_m && rim_m <= l.high_m) rim_band = &l;
  }
  ASSERT_NE(rim_band, nullptr);
  const ApproachPlan leg = PlanCoverage(world, rig.camera, o, top_m, PlanDescent(world, rig.camera, o));
  const Pose T_Bin_W = world.T_W_Bin().inverse();
  double y_low = 0.0, y_high = 0.0;
  for (const Pose& T_W_C : leg.T_W_C) {
    const Eigen::Vector3d p = (T_Bin_W * T_W_C).translation();
    if (std::abs(p.z() - rim_band->camera_height_m) > kLevelToleranceM) continue;
    y_low = std::min(y_low, p.y());
    y_high = std::max(y_high, p.y());
  }
  // the footprint (about 45 mm across) reaches the side walls' outer faces from its rows
  const double half_foot_m = 0.5 * (rim_band->camera_height_m - rim_m) * rig.camera.height / rig.camera.fy;
  const double walls_m = 0.5 * world.bin_inner_size_m().y() + 0.005;
  EXPECT_GE(y_high + half_foot_m, walls_m - 0.002) << y_high;  // the corner filter pulls rows in a little
  EXPECT_LE(y_low - half_foot_m, -walls_m + 0.002) << y_low;
}

}  // namespace
}  // namespace romunect::sim
