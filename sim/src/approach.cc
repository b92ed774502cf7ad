#include "romunect/sim/approach.h"

#include <algorithm>
#include <cmath>

#include "path.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sim/coverage.h"

namespace romunect::sim {
namespace {

std::string Num(double v) { return std::to_string(v); }

}  // namespace

std::string ApproachOptions::Problem() const {
  if (!(start_distance_m > 0)) return "start_distance_m = " + Num(start_distance_m) + ": must be > 0";
  if (!(end_distance_m > 0) || !(end_distance_m <= start_distance_m)) {
    return "end_distance_m = " + Num(end_distance_m) + ": must be in (0, start_distance_m]";
  }
  if (!(speed_m_s > 0) || speed_m_s > 2.0) return "speed_m_s = " + Num(speed_m_s) + ": must be in (0, 2]";
  if (!(acceleration_m_s2 > 0)) return "acceleration_m_s2 = " + Num(acceleration_m_s2) + ": must be > 0";
  if (!(region_size_m.x() > 0) || !(region_size_m.y() > 0)) return "region_size_m: both sizes must be > 0";
  if (!(pass_overlap >= 0 && pass_overlap < 0.9))
    return "pass_overlap = " + Num(pass_overlap) + ": must be in [0, 0.9)";
  if (!(corner_smoothing_s >= 0)) return "corner_smoothing_s = " + Num(corner_smoothing_s) + ": must be >= 0";
  if (!(joint_speed_rad_s > 0)) return "joint_speed_rad_s = " + Num(joint_speed_rad_s) + ": must be > 0";
  if (!(hold_before_s >= 0)) return "hold_before_s = " + Num(hold_before_s) + ": must be >= 0";
  if (!(focused_far_m >= 0)) return "focused_far_m = " + Num(focused_far_m) + ": must be >= 0 (0: one level)";
  if (focused_far_m > 0 && !(focused_near_m > 0 && focused_near_m < focused_far_m)) {
    return "focused_near_m = " + Num(focused_near_m) + ": must be in (0, focused_far_m = " + Num(focused_far_m) + ")";
  }
  if (!(surface_height_m >= 0)) return "surface_height_m = " + Num(surface_height_m) + ": must be >= 0";
  if (!(above_rim_m >= 0)) return "above_rim_m = " + Num(above_rim_m) + ": must be >= 0";
  if (!(coverage_corner_smoothing_s >= 0))
    return "coverage_corner_smoothing_s = " + Num(coverage_corner_smoothing_s) + ": must be >= 0";
  if (!(frame_period_s >= 0) || frame_period_s > 1.0) return "frame_period_s = " + Num(frame_period_s) + ": must be in [0, 1]";
  if (!(coverage_speed_m_s > 0) || coverage_speed_m_s > 2.0)
    return "coverage_speed_m_s = " + Num(coverage_speed_m_s) + ": must be in (0, 2]";
  if (!(coverage_acceleration_m_s2 > 0))
    return "coverage_acceleration_m_s2 = " + Num(coverage_acceleration_m_s2) + ": must be > 0";
  if (!(surface_low_m <= 0)) return "surface_low_m = " + Num(surface_low_m) + ": must be <= 0 (below the bin floor)";
  return "";
}

namespace {

// The highest surface the plan measures, above the bin floor (m).
double TopSurface(const World& world, const ApproachOptions& options) {
  return options.surface_height_m > 0 ? options.surface_height_m : world.bin_inner_size_m().z() + options.above_rim_m;
}

}  // namespace

void ApproachPlan::Append(const ApproachPlan& leg) {
  T_W_C.insert(T_W_C.end(), leg.T_W_C.begin() + 1, leg.T_W_C.end());
  q.insert(q.end(), leg.q.begin() + 1, leg.q.end());
  levels_m = leg.levels_m;
  length_m += leg.length_m;
}

ScanBox ScanRegionBox(const World& world, const ApproachOptions& options) {
  const Eigen::Vector3d floor_W = world.T_W_Bin().translation();
  const Eigen::Vector2d half = options.region_size_m / 2;
  ScanBox box;
  box.min_W = floor_W + Eigen::Vector3d(-half.x(), -half.y(), options.surface_low_m - 0.004);
  box.max_W = floor_W + Eigen::Vector3d(half.x(), half.y(), TopSurface(world, options) + 0.010);
  return box;
}

ApproachPlan PlanApproach(const World& world, const CameraModel& camera, const ApproachOptions& options,
                          const IkOptions& ik) {
  if (!options.Problem().empty()) throw InputError("approach", "options", options.Problem());
  if (options.sweep == ApproachOptions::Sweep::kCoverage && options.focused_far_m > 0)
    return PlanDescent(world, camera, options, ik);
  ApproachPlan plan;
  plan.timestep_s = world.timestep_s();

  // Stand-off levels (camera heights above the bin floor), highest first.
  if (options.focused_far_m > 0) {
    const double top = TopSurface(world, options);
    const double low = options.surface_low_m, span = top - low;
    // Range centres evenly from the top down to the lowest surface, one level more than the
    // range widths the span needs: both ends lie mid-range, where matching is best.
    const double width = options.focused_far_m - options.focused_near_m;
    const double mid = 0.5 * (options.focused_near_m + options.focused_far_m);
    const int n = static_cast<int>(std::ceil(span / width - 1e-9)) + 1;
    for (int i = 0; i < n; ++i) plan.levels_m.push_back(mid + low + span * (n - 1 - i) / (n - 1));
  } else {
    plan.levels_m = {options.end_distance_m};
  }

  // Passes: the footprint on the lowest surface seen from the lowest level, with overlap,
  // tiles the region. With stand-off levels the outer centres lie over the bin's walls (one
  // more pass per axis): seen from straight above, a wall hides and shadows little of the
  // floor inside it and of the table outside it, while views from further in or out lose a
  // band beside it on one side.
  const bool levels = options.focused_far_m > 0;
  const double low = plan.levels_m.back() - (levels ? options.surface_low_m : 0.0);
  const double foot_x = low * camera.width / camera.fx * (1.0 - options.pass_overlap);
  const double foot_y = low * camera.height / camera.fy * (1.0 - options.pass_overlap);
  const Eigen::Vector2d span = levels ? Eigen::Vector2d(world.bin_inner_size_m().head<2>()) : options.region_size_m;
  const int edge = levels ? 1 : 0;
  plan.passes_x = std::max(1, static_cast<int>(std::ceil(span.x() / foot_x - 1e-9)) + edge);
  plan.passes_y = std::max(1, static_cast<int>(std::ceil(span.y() / foot_y - 1e-9)) + edge);
  auto centre = [&](int i, int n, double size) {
    if (edge && n > 1) return size * (static_cast<double>(i) / (n - 1) - 0.5);
    return size * ((i + 0.5) / n - 0.5);
  };
  std::vector<Eigen::Vector2d> centres;
  for (int j = 0; j < plan.passes_y; ++j) {
    for (int i = 0; i < plan.passes_x; ++i) {
      const int ii = (j % 2 == 0) ? i : plan.passes_x - 1 - i;  // serpentine
      centres.emplace_back(centre(ii, plan.passes_x, span.x()), centre(j, plan.passes_y, span.y()));
    }
  }
  std::vector<Eigen::Vector3d> polyline;
  const double start_m = std::max(options.start_distance_m, plan.levels_m.front());
  if (options.focused_far_m > 0 && options.sweep == ApproachOptions::Sweep::kColumns) {
    // Down to the highest level, then through the levels at each centre, alternating
    // downwards and upwards, moving to the next centre at the level reached.
    polyline.emplace_back(centres[0].x(), centres[0].y(), start_m);
    for (size_t i = 0; i < centres.size(); ++i) {
      const bool down = i % 2 == 0;
      polyline.emplace_back(centres[i].x(), centres[i].y(), down ? plan.levels_m.front() : plan.levels_m.back());
      polyline.emplace_back(centres[i].x(), centres[i].y(), down ? plan.levels_m.back() : plan.levels_m.front());
    }
    // The approach ends at the working distance, ready to pick.
    if (centres.size() % 2 == 0) polyline.emplace_back(centres.back().x(), centres.back().y(), plan.levels_m.back());
  } else if (options.focused_far_m > 0) {
    // Straight down to the first level, then the serpentine at each level, back and forth.
    polyline.emplace_back(centres[0].x(), centres[0].y(), start_m);
    for (size_t l = 0; l < plan.levels_m.size(); ++l) {
      for (size_t i = 0; i < centres.size(); ++i) {
        const Eigen::Vector2d& c = centres[l % 2 == 0 ? i : centres.size() - 1 - i];
        polyline.emplace_back(c.x(), c.y(), plan.levels_m[l]);
      }
    }
  } else {
    // Descend linearly in the lateral path length (straight down when there is one pass).
    std::vector<double> lateral{0.0};
    for (size_t i = 1; i < centres.size(); ++i)
      lateral.push_back(lateral.back() + (centres[i] - centres[i - 1]).norm());
    for (size_t i = 0; i < centres.size(); ++i) {
      const double a = lateral.back() > 0 ? lateral[i] / lateral.back() : 0.0;
      polyline.emplace_back(centres[i].x(), centres[i].y(),
                            options.start_distance_m + a * (options.end_distance_m - options.start_distance_m));
    }
    if (centres.size() == 1) {
      polyline.push_back(polyline[0]);
      polyline.back().z() = options.end_distance_m;
    }
  }
  for (size_t i = 1; i < polyline.size(); ++i) plan.length_m += (polyline[i] - polyline[i - 1]).norm();
  std::vector<PathPoint> path;
  for (const Eigen::Vector3d& p : polyline) path.emplace_back(p.x(), p.y(), p.z(), 0.0);
  std::vector<PathPoint> p_Bin = TimeParameterize(path, options.speed_m_s, options.acceleration_m_s2, plan.timestep_s);
  p_Bin = Smooth(p_Bin, 2 * static_cast<int>(std::lround(options.corner_smoothing_s / plan.timestep_s / 2)) + 1);

  // Reachability: IK at every step (the first from the scan posture's seed).
  std::vector<Pose> T_Bin_C;
  for (const PathPoint& p : p_Bin) T_Bin_C.push_back(CameraPoseInBin(p));
  SolvePath(world, T_Bin_C, ScanPostureSeed(world), ik, &plan);
  return plan;
}

ApproachExecutor::ApproachExecutor(World* world, const ApproachPlan& plan, const ApproachOptions& options)
    : world_(world), plan_(plan), options_(options) {
  ROMUNECT_CHECK(world != nullptr && !plan.q.empty());
  ROMUNECT_CHECK(std::abs(plan.timestep_s - world->timestep_s()) < 1e-12);
}

double ApproachExecutor::MoveToStart() {
  const World::ArmVector q0 = world_->arm_q(), q1 = plan_.q.front();
  const double dt = world_->timestep_s();
  // Minimum-jerk profile: peak joint speed 1.875 * distance / duration.
  const double duration = std::max(0.1, 1.875 * (q1 - q0).cwiseAbs().maxCoeff() / options_.joint_speed_rad_s);
  const int steps = static_cast<int>(std::ceil(duration / dt));
  for (int k = 1; k <= steps; ++k) {
    const double s = static_cast<double>(k) / steps;
    const double blend = s * s * s * (10 - 15 * s + 6 * s * s);
    const double rate = 30 * s * s * (1 - s) * (1 - s) / duration;
    world_->SetArmTarget(q0 + blend * (q1 - q0), rate * (q1 - q0));
    world_->Step();
  }
  const int hold = static_cast<int>(std::lround(options_.hold_before_s / dt));
  world_->SetArmTarget(q1, World::ArmVector::Zero());
  world_->Step(hold);
  step_ = 0;
  return (steps + hold) * dt;
}

void ApproachExecutor::AdvanceTo(double t_s) {
  const int last = static_cast<int>(plan_.q.size()) - 1;
  const int target = std::clamp(static_cast<int>(std::lround(t_s / plan_.timestep_s)), 0, last);
  const double dt = plan_.timestep_s;
  while (step_ < target) {
    const int k = step_ + 1;
    if (k == last) {
      world_->SetArmTarget(plan_.q[k], World::ArmVector::Zero());  // hold
    } else {
      const World::ArmVector qdot = (plan_.q[k + 1] - plan_.q[k - 1]) / (2 * dt);
      const World::ArmVector qddot = (plan_.q[k + 1] - 2 * plan_.q[k] + plan_.q[k - 1]) / (dt * dt);
      world_->SetArmTarget(plan_.q[k], qdot, qddot);
    }
    world_->Step();
    step_ = k;
    const PoseError e = ComparePoses(world_->T_W_C(), plan_.T_W_C[k]);
    tracking_.max_position_error_m = std::max(tracking_.max_position_error_m, e.translation_m);
    tracking_.max_angle_error_rad = std::max(tracking_.max_angle_error_rad, e.angle_rad);
    sum_sq_error_ += e.translation_m * e.translation_m;
    ++tracking_.steps;
    tracking_.rms_position_error_m = std::sqrt(sum_sq_error_ / tracking_.steps);
  }
}

}  // namespace romunect::sim
