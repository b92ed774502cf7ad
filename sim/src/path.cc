#include "path.h"

#include <algorithm>
#include <cmath>
#include <string>

#include <Eigen/Geometry>

#include "romunect/sensor/errors.h"

namespace romunect::sim {

// Positions at constant speed with acceleration ramps along a polyline, one per time step.
std::vector<PathPoint> TimeParameterize(const std::vector<PathPoint>& polyline, double speed, double accel, double dt) {
  std::vector<double> s_at{0.0};
  for (size_t i = 1; i < polyline.size(); ++i) s_at.push_back(s_at.back() + (polyline[i] - polyline[i - 1]).norm());
  const double length = s_at.back();
  // Trapezoid (or triangle, for short paths) in arc length.
  const double t_ramp_full = speed / accel, s_ramp_full = 0.5 * accel * t_ramp_full * t_ramp_full;
  double v_peak = speed, t_ramp = t_ramp_full, t_cruise = 0.0;
  if (2 * s_ramp_full >= length) {
    v_peak = std::sqrt(accel * length);
    t_ramp = v_peak / accel;
  } else {
    t_cruise = (length - 2 * s_ramp_full) / speed;
  }
  const double total = 2 * t_ramp + t_cruise;
  const int steps = std::max(1, static_cast<int>(std::ceil(total / dt)));
  std::vector<PathPoint> out;
  size_t seg = 1;
  for (int k = 0; k <= steps; ++k) {
    const double t = std::min(total, k * dt);
    double s;
    if (t < t_ramp) {
      s = 0.5 * accel * t * t;
    } else if (t < t_ramp + t_cruise) {
      s = 0.5 * accel * t_ramp * t_ramp + v_peak * (t - t_ramp);
    } else {
      const double tr = total - t;
      s = length - 0.5 * accel * tr * tr;
    }
    s = std::clamp(s, 0.0, length);
    while (seg + 1 < s_at.size() && s_at[seg] < s) ++seg;
    const double span = s_at[seg] - s_at[seg - 1];
    const double a = span > 0 ? (s - s_at[seg - 1]) / span : 0.0;
    out.push_back(polyline[seg - 1] + a * (polyline[seg] - polyline[seg - 1]));
  }
  return out;
}

// A centred moving average of `window` samples that narrows towards the ends, so the first
// and last positions stay exact (rounds the corners).
std::vector<PathPoint> Smooth(const std::vector<PathPoint>& p, int window) {
  if (window <= 1) return p;
  const int n = static_cast<int>(p.size());
  std::vector<PathPoint> out(p.size());
  for (int i = 0; i < n; ++i) {
    const int h = std::min({window / 2, i, n - 1 - i});
    PathPoint sum = PathPoint::Zero();
    for (int k = -h; k <= h; ++k) sum += p[i + k];
    out[i] = sum / (2 * h + 1);
  }
  return out;
}

Eigen::Matrix3d R_Bin_C(double turn_rad) {
  Eigen::Matrix3d R;
  R.col(0) = -Eigen::Vector3d::UnitX();
  R.col(1) = Eigen::Vector3d::UnitY();
  R.col(2) = -Eigen::Vector3d::UnitZ();
  return Eigen::AngleAxisd(turn_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix() * R;
}

Pose CameraPoseInBin(const PathPoint& p) { return MakePose(R_Bin_C(p[3] / kTurnRadiusM), p.head<3>()); }

World::ArmVector ScanPostureSeed(const World& world) {
  const Eigen::Vector3d bin_W = world.T_W_Bin().translation();
  World::ArmVector q;
  q << std::atan2(bin_W.y(), bin_W.x()), 0.3, 0.9, 0.0, 0.37, 0.0;
  return q;
}

void SolvePath(const World& world, const std::vector<Pose>& T_Bin_C, const World::ArmVector& q_seed,
               const IkOptions& ik, ApproachPlan* plan) {
  auto num = [](double v) { return std::to_string(v); };
  const Pose T_W_Bin = world.T_W_Bin();
  World::ArmVector q = q_seed;
  for (size_t k = 0; k < T_Bin_C.size(); ++k) {
    const Pose T_W_C = T_W_Bin * T_Bin_C[k];
    const IkResult r = SolveIk(world, ArmSite::kCamera, T_W_C, q, ik);
    if (!r.converged) {
      throw InputError("approach", "T_W_C at t = " + num((plan->T_W_C.size()) * plan->timestep_s) + " s",
                       "outside the arm's workspace: camera at (" + num(T_W_C.translation().x()) + ", " +
                           num(T_W_C.translation().y()) + ", " + num(T_W_C.translation().z()) +
                           ") m in W is missed by " + num(r.position_error_m) + " m, " + num(r.angle_error_rad) +
                           " rad");
    }
    q = r.q;
    plan->T_W_C.push_back(T_W_C);
    plan->q.push_back(q);
  }
}

}  // namespace romunect::sim
