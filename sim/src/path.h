// Shared by the approach planners (approach.cc, coverage.cc): a polyline of camera positions
// and hand turns in the bin frame, timed at constant speed with ramps, rounded at its corners,
// and solved for the arm's joints at every physics step.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/pose.h"
#include "romunect/sim/approach.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

// A path point: the camera's position in the bin frame (m) and, last, its turn about the bin's
// z axis as an arc length: kTurnRadiusM * angle (rad), so turning the hand takes path time.
using PathPoint = Eigen::Vector4d;
inline constexpr double kTurnRadiusM = 0.05;

// Positions at constant speed with acceleration ramps along a polyline, one per time step.
std::vector<PathPoint> TimeParameterize(const std::vector<PathPoint>& polyline, double speed, double accel, double dt);
// A centred moving average of `window` samples that narrows towards the ends, so the first
// and last positions stay exact (rounds the corners).
std::vector<PathPoint> Smooth(const std::vector<PathPoint>& p, int window);

// The camera looking down the bin's -z, its x along the bin's -x (the scan posture: the arm
// reaches out along +x with the flange turned down), turned by `turn_rad` about the bin's z.
Eigen::Matrix3d R_Bin_C(double turn_rad);
Pose CameraPoseInBin(const PathPoint& p);

// The joint seed of the scan posture over the world's bin: elbow up, the flange pointing down.
World::ArmVector ScanPostureSeed(const World& world);

// IK at every sample of T_Bin_C (one per physics step), warm-started from `q_seed` and then from
// the previous sample; appends the poses and joints to plan->T_W_C and plan->q. Throws
// InputError("approach", ...) when a pose is outside the arm's workspace.
void SolvePath(const World& world, const std::vector<Pose>& T_Bin_C, const World::ArmVector& q_seed,
               const IkOptions& ik, ApproachPlan* plan);

}  // namespace romunect::sim
