// The scan's motion: a joint-space move to above the bin, then a Cartesian approach of the
// camera from start_distance_m down to end_distance_m above the bin floor at speed_m_s, with
// lateral passes where the field of view at the end distance does not cover the region of
// interest. The camera looks straight down (C's z = -z of the bin frame, C's x = the bin's x).
// The plan is checked for reachability by IK at every physics step before anything moves; the
// executor then tracks it with the position servos, and the executed poses (not the planned
// ones) are what the frames report. Frames: W world, C camera, bin frame; SI units.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

struct ApproachOptions {
  double start_distance_m = 0.40;             // camera height above the bin floor at the start
  double end_distance_m = 0.20;               // ... at the end (the working distance)
  double speed_m_s = 0.3;                     // along the path
  double acceleration_m_s2 = 1.5;             // speed ramps at both ends
  Eigen::Vector2d region_size_m{0.15, 0.08};  // region of interest (bin x, y), centred on the bin
  double pass_overlap = 0.1;                  // fraction of the footprint shared by neighbouring passes
  double corner_smoothing_s = 0.1;            // box filter over the path's corners (0: sharp corners)
  double joint_speed_rad_s = 1.0;             // peak joint speed of the move to the start
  double hold_before_s = 0.3;                 // still time at the start, for the servos to settle
  // Stand-off levels (used when focused_far_m > 0): the sensor measures only depths (along
  // its axis) in [focused_near_m, focused_far_m] (see MeasurableDepthRange). The levels put
  // the middle of the focused range evenly from the highest surface (bin floor +
  // surface_height_m; 0: the rim plus above_rim_m, as piles stand above the rim) down to the
  // lowest (bin floor + surface_low_m: the table the bin stands on), with one level more than
  // the range widths that span needs, so both ends lie mid-range, where the rig matches best.
  // The sweep then visits them (end_distance_m is unused):
  //  - kColumns: at each pass centre the camera sweeps the levels from the highest to the
  //    lowest or back (alternating), moving laterally at the lowest or highest level: every
  //    footprint sees every height early, in the shortest path, ending at the lowest level
  //    (the default);
  //  - kLevels: straight down to the highest level, the serpentine over the region there, then
  //    at each lower level (back and forth);
  //  - kCoverage: planned for coverage from the measured pile (coverage.h: a descent, then the
  //    levels the measured pile needs; PlanApproach returns the descent, the Scanner plans the
  //    rest when the descent's frames are measured). The default; without focused_far_m, the
  //    single-level descent as for the others.
  enum class Sweep { kCoverage, kColumns, kLevels };
  Sweep sweep = Sweep::kCoverage;
  // kCoverage: speed and acceleration along the path. Faster than the paper's 0.3 m/s: a frame
  // then moves by about half the footprint (the twin models no motion blur; a real sensor would
  // need a short exposure).
  double coverage_speed_m_s = 0.9;
  double coverage_acceleration_m_s2 = 8.0;
  // kCoverage: box filter over the coverage path's corners. One frame period: a wider filter
  // pulls the serpentine's row ends and outer rows inwards (0.1 s at 0.9 m/s averages 90 mm of
  // path), off the walls they were placed over; the arm's servos round what is left.
  double coverage_corner_smoothing_s = 1.0 / 30;
  // kCoverage: the sensor's frame period (the Scanner sets it from the rig; 0: unknown). The
  // descent is then timed so that a frame falls on its turn at the first level (coverage.h,
  // PlanDescent).
  double frame_period_s = 0.0;
  bool turned_passes = true;  // kCoverage: the bands again with the hand turned 180 deg
  double focused_near_m = 0.0;
  double focused_far_m = 0.0;
  double surface_height_m = 0.0;
  double above_rim_m = 0.015;
  double surface_low_m = -0.005;  // the default bin's 5 mm floor stands on the table

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
};

struct ApproachPlan {
  double timestep_s = 0.0;          // one sample per physics step
  std::vector<Pose> T_W_C;          // planned camera poses, one per step
  std::vector<World::ArmVector> q;  // joint angles that reach them (IK)
  int passes_x = 1, passes_y = 1;   // lateral passes over the region (per level)
  std::vector<double> levels_m;     // camera heights above the bin floor of the passes
  double length_m = 0.0;            // path length
  double duration_s() const { return T_W_C.empty() ? 0.0 : (T_W_C.size() - 1) * timestep_s; }
  // Continues this plan with `leg`, whose first sample is this plan's last (coverage.h's
  // PlanCoverage from a descent): the path grows, the levels become the leg's.
  void Append(const ApproachPlan& leg);
};

// The box the scan measures, in W (axes of the bin frame): the region of interest centred on
// the bin, from 4 mm below the lowest planned surface (the table) to 10 mm above the highest
// (rim plus above_rim_m, or surface_height_m): the fusion grid's box.
struct ScanBox {
  Eigen::Vector3d min_W = Eigen::Vector3d::Zero(), max_W = Eigen::Vector3d::Zero();
};
ScanBox ScanRegionBox(const World& world, const ApproachOptions& options);

// Plans the approach over the world's bin for `camera`. Throws InputError("approach", field,
// ...) when a pose along the way is outside the arm's workspace (IK does not converge).
// With Sweep::kCoverage the plan is coverage.h's descent (the first leg).
ApproachPlan PlanApproach(const World& world, const CameraModel& camera, const ApproachOptions& options,
                          const IkOptions& ik = {});

struct TrackingStats {
  double max_position_error_m = 0.0;  // executed vs planned camera position, over the approach
  double rms_position_error_m = 0.0;
  double max_angle_error_rad = 0.0;
  int steps = 0;
};

// Drives the world along a plan: MoveToStart() (joint space, min-jerk, then a hold), then
// AdvanceTo(t) steps the physics until the approach's time t.
class ApproachExecutor {
 public:
  ApproachExecutor(World* world, const ApproachPlan& plan, const ApproachOptions& options);

  // Moves from the current joint angles to plan.q[0]; returns the simulated time it took.
  double MoveToStart();
  // Steps until the approach clock reaches t_s (clamped to the plan's end, holding there).
  void AdvanceTo(double t_s);
  double time_s() const { return step_ * plan_.timestep_s; }
  bool finished() const { return step_ + 1 >= static_cast<int>(plan_.q.size()); }
  const TrackingStats& tracking() const { return tracking_; }

 private:
  World* world_;
  const ApproachPlan& plan_;
  ApproachOptions options_;
  int step_ = 0;
  double sum_sq_error_ = 0.0;
  TrackingStats tracking_;
};

}  // namespace romunect::sim
