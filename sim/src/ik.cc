#include "romunect/sim/ik.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Cholesky>

#include "romunect/sensor/check.h"

namespace romunect::sim {
namespace {

Eigen::Matrix<double, 6, 1> PoseErrorVector(const Pose& T_W_goal, const Pose& T_W_now) {
  Eigen::Matrix<double, 6, 1> e;
  e.head<3>() = T_W_goal.translation() - T_W_now.translation();
  const Eigen::AngleAxisd aa(T_W_goal.rotation() * T_W_now.rotation().transpose());
  e.tail<3>() = aa.angle() * aa.axis();
  return e;
}

}  // namespace

std::string IkOptions::Problem() const {
  if (max_iterations < 1) return "max_iterations = " + std::to_string(max_iterations) + ": must be >= 1";
  if (!(damping > 0.0)) return "damping = " + std::to_string(damping) + ": must be > 0";
  if (!(max_step_rad > 0.0)) return "max_step_rad = " + std::to_string(max_step_rad) + ": must be > 0";
  if (!(tolerance_m > 0.0) || !(tolerance_rad > 0.0)) return "tolerance_m and tolerance_rad must be > 0";
  return "";
}

IkResult SolveIk(const World& world, ArmSite site, const Pose& T_W_goal, const World::ArmVector& q_seed,
                 const IkOptions& options) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  const World::ArmVector lo = world.arm_lower_rad(), hi = world.arm_upper_rad();
  IkResult result;
  result.q = q_seed.cwiseMax(lo).cwiseMin(hi);
  const double lambda2 = options.damping * options.damping;
  for (int it = 0;; ++it) {
    const Eigen::Matrix<double, 6, 1> e = PoseErrorVector(T_W_goal, world.ForwardKinematics(result.q, site));
    result.position_error_m = e.head<3>().norm();
    result.angle_error_rad = e.tail<3>().norm();
    result.iterations = it;
    if (result.position_error_m < options.tolerance_m && result.angle_error_rad < options.tolerance_rad) {
      result.converged = true;
      return result;
    }
    if (it == options.max_iterations) return result;
    const World::Jacobian J = world.SiteJacobian(result.q, site);
    Eigen::Matrix<double, 6, 6> A = J * J.transpose();
    A.diagonal().array() += lambda2;
    World::ArmVector dq = J.transpose() * A.llt().solve(e);
    const double largest = dq.cwiseAbs().maxCoeff();
    if (largest > options.max_step_rad) dq *= options.max_step_rad / largest;
    result.q = (result.q + dq).cwiseMax(lo).cwiseMin(hi);
  }
}

}  // namespace romunect::sim
