#include "romunect/sim/pick.h"

#include <cmath>
#include <cstdio>
#include <functional>

#include <Eigen/Dense>

#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"

namespace romunect::sim {
namespace {

std::string Num(double v) { return std::to_string(v); }

// The hand orientation that points the cup (the flange's z) along -normal, keeping the hand's
// x as close as possible to its current x (the least wrist rotation).
Eigen::Matrix3d CupRotation(const Eigen::Vector3d& normal_W, const Eigen::Matrix3d& R_W_now) {
  const Eigen::Vector3d z = -normal_W.normalized();
  Eigen::Vector3d x = R_W_now.col(0) - R_W_now.col(0).dot(z) * z;
  if (x.norm() < 1e-6) x = Eigen::Vector3d::UnitX() - z.x() * z;
  x.normalize();
  Eigen::Matrix3d R;
  R << x, z.cross(x), z;
  return R;
}

// Moves the suction tip in a straight line (slerped orientation) at `speed`, one IK per step,
// until `stop` says so. Returns false (with *why) when IK fails on the way.
bool MoveTip(World* world, const Pose& to, double speed, const IkOptions& ik, const std::function<bool()>& stop,
             std::string* why) {
  const Pose from = world->SitePose_W(ArmSite::kSuctionTip);
  const double dt = world->timestep_s();
  const double length = (to.translation() - from.translation()).norm();
  const int steps = std::max(1, static_cast<int>(std::ceil(length / speed / dt)));
  World::ArmVector q = world->arm_q(), q_prev = q;
  for (int k = 1; k <= steps; ++k) {
    const Pose goal = InterpolatePose(from, to, static_cast<double>(k) / steps);
    const IkResult r = SolveIk(*world, ArmSite::kSuctionTip, goal, q, ik);
    if (!r.converged) {
      *why = "the suction tip cannot reach (" + Num(goal.translation().x()) + ", " + Num(goal.translation().y()) +
             ", " + Num(goal.translation().z()) + ") m in W";
      return false;
    }
    q_prev = q;
    q = r.q;
    world->SetArmTarget(q, (q - q_prev) / dt);
    world->Step();
    if (stop && stop()) return true;
  }
  world->SetArmTarget(q, World::ArmVector::Zero());
  return true;
}

}  // namespace

std::string PickOptions::Problem() const {
  if (!(cup_radius_m > 0)) return "cup_radius_m = " + Num(cup_radius_m) + ": must be > 0";
  if (!(candidate_step_m > 0)) return "candidate_step_m = " + Num(candidate_step_m) + ": must be > 0";
  if (!(min_valid_fraction > 0 && min_valid_fraction <= 1))
    return "min_valid_fraction = " + Num(min_valid_fraction) + ": must be in (0, 1]";
  if (!(max_rms_m > 0)) return "max_rms_m = " + Num(max_rms_m) + ": must be > 0";
  if (!(max_tilt_rad >= 0 && max_tilt_rad < 1.5))
    return "max_tilt_rad = " + Num(max_tilt_rad) + ": must be in [0, 1.5)";
  if (!(pre_grasp_m > 0)) return "pre_grasp_m = " + Num(pre_grasp_m) + ": must be > 0";
  if (!(approach_speed_m_s > 0) || !(move_speed_m_s > 0)) return "approach_speed_m_s and move_speed_m_s must be > 0";
  if (!(overtravel_m >= 0)) return "overtravel_m = " + Num(overtravel_m) + ": must be >= 0";
  if (!(lift_above_rim_m > 0)) return "lift_above_rim_m = " + Num(lift_above_rim_m) + ": must be > 0";
  return "";
}

std::optional<GraspPoint> ChooseGraspPoint(const cv::Mat& height_m, const HeightMapGeometry& geometry,
                                           const PickOptions& options) {
  ROMUNECT_CHECK(height_m.type() == CV_32F && height_m.rows == geometry.ny && height_m.cols == geometry.nx);
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  const int stride = std::max(1, static_cast<int>(std::lround(options.candidate_step_m / geometry.voxel_m)));
  const int r_cells = static_cast<int>(std::ceil(options.cup_radius_m / geometry.voxel_m));
  // Patch samples: every `sample` cells inside the cup's disc (about 15 x 15 samples).
  const int sample = std::max(1, r_cells / 7);
  std::optional<GraspPoint> best;
  for (int j = r_cells; j + r_cells < geometry.ny; j += stride) {
    for (int i = r_cells; i + r_cells < geometry.nx; i += stride) {
      const float centre = height_m.at<float>(j, i);
      if (std::isnan(centre) || (best && centre <= best->p_W.z())) continue;
      // Least-squares plane z = a dx + b dy + c over the patch, in metres about the centre.
      Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
      Eigen::Vector3d Atz = Eigen::Vector3d::Zero();
      int total = 0, valid = 0;
      for (int dj = -r_cells; dj <= r_cells; dj += sample) {
        for (int di = -r_cells; di <= r_cells; di += sample) {
          if (di * di + dj * dj > r_cells * r_cells) continue;
          ++total;
          const float z = height_m.at<float>(j + dj, i + di);
          if (std::isnan(z)) continue;
          ++valid;
          const Eigen::Vector3d row(di * geometry.voxel_m, dj * geometry.voxel_m, 1.0);
          AtA += row * row.transpose();
          Atz += row * z;
        }
      }
      if (valid < 3 || valid < options.min_valid_fraction * total) continue;
      const Eigen::Vector3d abc = AtA.ldlt().solve(Atz);
      double sum_sq = 0.0;
      for (int dj = -r_cells; dj <= r_cells; dj += sample) {
        for (int di = -r_cells; di <= r_cells; di += sample) {
          if (di * di + dj * dj > r_cells * r_cells) continue;
          const float z = height_m.at<float>(j + dj, i + di);
          if (std::isnan(z)) continue;
          const double e = z - (abc[0] * di * geometry.voxel_m + abc[1] * dj * geometry.voxel_m + abc[2]);
          sum_sq += e * e;
        }
      }
      const double rms = std::sqrt(sum_sq / valid);
      const Eigen::Vector3d normal = Eigen::Vector3d(-abc[0], -abc[1], 1.0).normalized();
      if (rms > options.max_rms_m || std::acos(std::min(1.0, normal.z())) > options.max_tilt_rad) continue;
      GraspPoint g;
      g.p_W = Eigen::Vector3d(geometry.CellCentreX_m(i), geometry.CellCentreY_m(j), abc[2]);
      g.normal_W = normal;
      g.rms_m = rms;
      g.row = j;
      g.col = i;
      if (!best || g.p_W.z() > best->p_W.z()) best = g;
    }
  }
  return best;
}

std::string PickResult::BriefReport() const {
  char s[300];
  if (!grasp_found) return "pick: no grasp point (no patch flat and complete enough for the cup)";
  std::snprintf(s, sizeof s,
                "pick %s: grasp at (%.1f, %.1f, %.1f) mm, tilt %.1f deg, object %d (%s); %.2f s simulated%s%s",
                success ? "succeeded" : "FAILED", 1e3 * grasp.p_W.x(), 1e3 * grasp.p_W.y(), 1e3 * grasp.p_W.z(),
                std::acos(std::min(1.0, grasp.normal_W.z())) * 180 / M_PI, object,
                object_kind.empty() ? "none" : object_kind.c_str(), simulated_s, failure.empty() ? "" : ": ",
                failure.c_str());
  return s;
}

PickResult Pick(World* world, const cv::Mat& height_m, const HeightMapGeometry& geometry, const PickOptions& options,
                const IkOptions& ik) {
  ROMUNECT_CHECK(world != nullptr);
  const Stopwatch wall;
  const double t0 = world->time_s();
  PickResult result;
  auto finish = [&]() {
    result.simulated_s = world->time_s() - t0;
    result.wall_s = wall.seconds();
    return result;
  };
  const std::optional<GraspPoint> grasp = ChooseGraspPoint(height_m, geometry, options);
  if (!grasp) {
    result.failure = "no grasp point";
    return finish();
  }
  result.grasp_found = true;
  result.grasp = *grasp;
  world->SetPileFrozen(false);  // the pick needs physics
  world->Release();

  const Eigen::Matrix3d R = CupRotation(grasp->normal_W, world->SitePose_W(ArmSite::kSuctionTip).rotation());
  const Pose pre = MakePose(R, grasp->p_W + options.pre_grasp_m * grasp->normal_W);
  const Pose past = MakePose(R, grasp->p_W - options.overtravel_m * grasp->normal_W);
  const double rim_z = (world->T_W_Bin() * Eigen::Vector3d(0, 0, world->bin_inner_size_m().z())).z();
  // Above the pre-grasp first, then down to it: the hand never sweeps through the pile.
  Pose above = pre;
  above.translation().z() = std::max(pre.translation().z(), rim_z + options.lift_above_rim_m);
  if (!MoveTip(world, above, options.move_speed_m_s, ik, nullptr, &result.failure) ||
      !MoveTip(world, pre, options.move_speed_m_s, ik, nullptr, &result.failure)) {
    return finish();
  }
  std::optional<int> touched;
  if (!MoveTip(
          world, past, options.approach_speed_m_s, ik,
          [&]() { return (touched = world->SuctionContact()).has_value(); }, &result.failure)) {
    return finish();
  }
  if (!touched) {
    result.failure = "the cup reached " + Num(1e3 * options.overtravel_m) + " mm past the surface without touching";
    return finish();
  }
  result.contact = true;
  result.object = *touched;
  result.object_kind = ToString(world->options().objects[*touched].kind);
  world->Grip(*touched);
  world->SetArmTarget(world->arm_q(), World::ArmVector::Zero());
  world->Step(50);  // let the weld take hold
  Pose lifted = world->SitePose_W(ArmSite::kSuctionTip);
  lifted.translation() += (above.translation().z() - lifted.translation().z()) * Eigen::Vector3d::UnitZ();
  if (!MoveTip(world, lifted, options.move_speed_m_s, ik, nullptr, &result.failure)) return finish();
  world->Step(250);  // hold for 0.5 s: a weak grip would drop it now
  // Out of the bin: the object's lowest point... its origin, at least 1 cm above the rim.
  const double object_z = world->T_W_O(*touched).translation().z();
  result.success = world->gripped() == touched && object_z > rim_z + 0.01;
  if (!result.success) result.failure = "the object is not above the rim after the lift (z " + Num(object_z) + " m)";
  return finish();
}

}  // namespace romunect::sim
