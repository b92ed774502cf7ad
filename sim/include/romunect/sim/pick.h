// The pick: a grasp point chosen from a fused height map alone (never from ground truth) --
// the highest patch flat enough for the suction cup -- then the arm approaches along the
// patch's normal, grips on contact (the cup's weld), lifts the object above the bin's rim and
// reports whether it came out. Frames: W world; heights are world z (m); SI units.
#pragma once

#include <optional>
#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sim/ik.h"
#include "romunect/sim/scanner.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

struct PickOptions {
  double cup_radius_m = 0.008;       // the patch the cup needs (its lip, 9 mm, minus a margin)
  double candidate_step_m = 1e-3;    // grasp candidates on this grid
  double min_valid_fraction = 0.9;   // of the patch's cells that must hold a height
  double max_rms_m = 0.4e-3;         // plane-fit residual over the patch
  double max_tilt_rad = 0.5;         // patch normal from vertical
  double pre_grasp_m = 0.04;         // approach starts this far out along the normal
  double approach_speed_m_s = 0.05;  // along the normal, until the cup touches
  double overtravel_m = 0.01;        // past the surface without contact: give up
  double lift_above_rim_m = 0.06;    // the cup rises to this height above the bin's rim
  double move_speed_m_s = 0.2;       // Cartesian moves other than the approach

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
};

struct GraspPoint {
  Eigen::Vector3d p_W = Eigen::Vector3d::Zero();        // patch centre on the fitted plane
  Eigen::Vector3d normal_W = Eigen::Vector3d::UnitZ();  // fitted plane normal, pointing up
  double rms_m = 0.0;                                   // plane-fit residual
  int row = 0, col = 0;                                 // height-map cell of the centre
};

// The highest patch of the height map (CV_32F world z, NaN = empty, laid out as `geometry`)
// that is complete, flat and level enough for the cup; nullopt when there is none.
std::optional<GraspPoint> ChooseGraspPoint(const cv::Mat& height_m, const HeightMapGeometry& geometry,
                                           const PickOptions& options = {});

struct PickResult {
  bool grasp_found = false;
  GraspPoint grasp;
  bool contact = false;     // the cup touched an object
  int object = -1;          // the object gripped (index in the world), -1 when none
  std::string object_kind;  // its kind (objects.h ToString), "" when none
  bool success = false;     // the gripped object ended above the bin's rim, held by the cup
  double simulated_s = 0.0;
  double wall_s = 0.0;
  std::string failure;  // why not, when success is false
  std::string BriefReport() const;
};

// Chooses the grasp from the height map and executes it in the world (physics on: the pile
// is unfrozen). Never throws for a pick that fails; the result says why.
PickResult Pick(World* world, const cv::Mat& height_m, const HeightMapGeometry& geometry,
                const PickOptions& options = {}, const IkOptions& ik = {});

}  // namespace romunect::sim
