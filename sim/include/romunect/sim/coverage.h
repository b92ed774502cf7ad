// The approach planned for coverage, as a real cell plans it: from what the cell knows (the
// bin's pose and inner size, the region of interest, the rig's measurable depth range, the
// camera's field of view) and from what the sensor measures on the way down (the first frames
// in range tell how high the pile stands), never from the simulator's ground truth.
//
// The approach has two legs. The descent (PlanDescent) comes straight down over the bin's
// middle to the lowest stand-off level, the one whose measurable band holds the table, the bin
// floor and a one-layer pile, and runs on at it through that band's first pass over the whole
// region, its outer rows over the side walls and its row ends at the end walls; then, when the
// rim lies above that band, a pass over the bin's outline at the rim's level (none of this
// depends on the pile). On the way, a PileHeightMeter collects the heights of the measured
// points over the bin's inner floor. The coverage leg (PlanCoverage) then starts where the descent stopped:
// measurable bands stacked from the table up to the measured top, one more for the bin's rim
// when it lies above them (the descent has seen it), a serpentine per band whose rows tile the
// band's area with the footprint at the band's far end (every frame adds new area): the bands
// above the lowest over the bin's inside, the rim's over its outline, the hand turning 170 deg
// on the way; the lowest band again, turned, over the whole region, so the strips the
// projector's baseline shadows on one side of every edge are seen from the other. Frames: W
// world, C camera, Bin (the bin's inner floor centre, z up); SI units; heights are above the bin
// floor.
#pragma once

#include <optional>
#include <vector>

#include <Eigen/Core>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/pose.h"
#include "romunect/sim/approach.h"
#include "romunect/sim/ik.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

// One stand-off level of the coverage leg: the camera's height above the bin floor and the
// band of surface heights it measures, [low_m, high_m].
struct CoverageLevel {
  double camera_height_m = 0.0;
  double low_m = 0.0, high_m = 0.0;
  bool rim_only = false;  // the rim's own band, above the bands of the pile
};

// The stand-off levels for surfaces from options.surface_low_m (the table) up to top_m, plus the
// rim (rim_m) when no band holds it. Bands are (focused_far_m - focused_near_m) wide; within a
// band the surfaces sit at the preferred distance (the middle of a narrow range; near the near
// end of a wide one, where depth noise is lowest), clamped so the band stays measurable.
// Lowest band first. Needs options.focused_far_m > 0.
std::vector<CoverageLevel> CoverageLevels(const ApproachOptions& options, double top_m, double rim_m);

// Collects the heights above the bin floor of measured points over the bin's inner floor (walls
// left out), every `stride_px` pixel of each frame's depth_m at its T_W_C; a frame where fewer
// than 1 % of them measured a point over the floor adds nothing (far above the measurable range,
// the blurred pattern gives a few stray matches). Not thread safe.
class PileHeightMeter {
 public:
  PileHeightMeter(const Pose& T_W_Bin, const Eigen::Vector3d& bin_inner_size_m, int stride_px = 4);
  void Add(const Frame& frame, const CameraModel& camera);  // frames without depth or pose add nothing
  // The pile's top: the height with 50 measured points or 0.1 % of them above it, whichever is
  // more (a few stray matches do not raise it);
  // nothing when fewer than min_samples points were measured.
  std::optional<double> TopM(int min_samples = 200) const;
  int samples() const { return static_cast<int>(heights_m_.size()); }

 private:
  Pose T_Bin_W_;
  Eigen::Vector2d half_inner_m_;
  int stride_px_;
  std::vector<float> heights_m_;
};

// The descent: from options.start_distance_m (raised to the first level plus 5 cm when lower)
// straight down, just off the bin's middle, to the lowest coverage level at coverage_speed_m_s,
// then the lowest band's first pass at that level, then, when the rim lies above that band, up to the
// rim's band and a pass over the bin's outline (the rim's height is the bin's: no pile needed),
// stopping at its end. With options.frame_period_s
// the start is raised so that a frame falls on the turn into the pass, where its band starts at
// the bin floor (the frame before it a full period's travel higher, above a one-layer pile).
ApproachPlan PlanDescent(const World& world, const CameraModel& camera, const ApproachOptions& options,
                         const IkOptions& ik = {});

// The coverage leg from the end of `descent` for a pile whose measured top is top_m (the bin
// floor when nothing was measured): levels from CoverageLevels, serpentines at
// coverage_speed_m_s, the turned passes; levels_m holds the levels' camera heights, highest
// first. Its first sample is the descent's last. Throws
// InputError("approach", ...) when a pose is outside the arm's workspace.
ApproachPlan PlanCoverage(const World& world, const CameraModel& camera, const ApproachOptions& options, double top_m,
                          const ApproachPlan& descent, const IkOptions& ik = {});

}  // namespace romunect::sim
