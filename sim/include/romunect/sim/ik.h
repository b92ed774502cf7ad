// Inverse kinematics of the arm by damped least squares on MuJoCo's site Jacobians:
//   dq = J^T (J J^T + lambda^2 I)^-1 e,   e = [p_goal - p; log(R_goal R^T)] in W,
// a 6 x 6 Cholesky per iteration, steps clamped, joints kept within their limits.
#pragma once

#include <string>

#include "romunect/sensor/pose.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

struct IkOptions {
  int max_iterations = 200;
  double damping = 0.01;      // lambda, in the units of e (m and rad); > 0
  double max_step_rad = 0.2;  // largest change of any joint per iteration
  double tolerance_m = 1e-6;  // converged when both errors are below these
  double tolerance_rad = 1e-6;

  std::string Problem() const;  // "" when valid; otherwise names the field, value and rule
};

struct IkResult {
  bool converged = false;
  World::ArmVector q = World::ArmVector::Zero();
  int iterations = 0;
  double position_error_m = 0.0;
  double angle_error_rad = 0.0;
};

// Joint angles that put `site` at T_W_goal, starting from q_seed. Uses only the world's
// kinematics (its simulation state is untouched). Never throws: an unreachable goal comes back
// with converged = false and the remaining error.
IkResult SolveIk(const World& world, ArmSite site, const Pose& T_W_goal, const World::ArmVector& q_seed,
                 const IkOptions& options = {});

}  // namespace romunect::sim
