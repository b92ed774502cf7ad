#include "romunect/sim/coverage.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

#include "path.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect::sim {
namespace {

// A wide measurable range (the stock Kinect's 0.48-3.0 m) is used near its near end, where depth
// noise (growing with Z^2) is lowest, with this much room for taller surfaces.
constexpr double kWideRangeRoomM = 0.25;
// Points this close to a wall are left out of the pile's height (the walls are the bin, not the pile).
constexpr double kWallMarginM = 0.003;
// The descent starts at least this far above the first level, so the pile's top comes into range
// on the way down.
constexpr double kDescentRoomM = 0.05;
// The hand's turn for the second passes: short of 180 deg, as the last wrist joint stops at
// +-3.14 rad; the baseline's shadows fall on the other side all the same.
constexpr double kTurnRad = 170.0 * M_PI / 180.0;
// The pile's top is the height with this many measured points (every 4th pixel: about 5 mm^2 at
// 200 mm) or this share of them above it: a few stray matches do not raise it.
constexpr size_t kTopRank = 50;
constexpr double kTopShare = 0.001;
// A frame adds its points when at least this share of its sampled pixels measured a point over
// the inner floor (a pill box's top is about 5 % of the footprint).
constexpr double kMinFrameShare = 0.01;
// The lowest band's outer rows lie this far beyond the bin's inner side walls.
constexpr double kRunBeyondWallM = 0.006;
// The bin's walls are no wider than this (the default bin's are 5 mm): the rim's passes cover them.
constexpr double kWallM = 0.006;

// The camera's distance to the surfaces of a band of `span_m`: the middle of a narrow range, near
// the near end of a wide one, clamped so the whole band stays in [near, far].
double PreferredDistance(const ApproachOptions& o, double span_m) {
  const double mid = 0.5 * (o.focused_near_m + o.focused_far_m);
  const double preferred = std::min(mid, o.focused_near_m + kWideRangeRoomM);
  return std::clamp(preferred, o.focused_near_m + 0.5 * span_m, o.focused_far_m - 0.5 * span_m);
}

CoverageLevel LevelFor(const ApproachOptions& o, double low_m, double high_m) {
  CoverageLevel level;
  level.low_m = low_m;
  level.high_m = high_m;
  level.camera_height_m = 0.5 * (low_m + high_m) + PreferredDistance(o, high_m - low_m);
  return level;
}

// The row centres of a pass over a region (bin frame, centred) at one level: the footprint at the
// band's far end tiles it, centres evenly from edge to edge, symmetric about the region's centre
// (xs along a row, ys across the rows). The outer rows and row ends lie at least over the walls
// (`min_end_m`, x and y): from further in, a wall hides the table beside it. A pass over an
// area leaves an edge strip narrower than a sixth of the footprint to the walls' shadow; a pass
// over an outline (`outline`) leaves nothing, the edges being what it is for.
struct Rows {
  std::vector<double> xs, ys;
};
Rows PassRows(const CameraModel& camera, const Eigen::Vector2d& region_m, double distance_m,
              const Eigen::Vector2d& min_end_m = Eigen::Vector2d::Zero(), bool outline = false) {
  const Eigen::Vector2d foot(distance_m * camera.width / camera.fx, distance_m * camera.height / camera.fy);
  auto centres = [outline](double region, double foot_m, double end_m) {
    std::vector<double> c;
    const double travel = std::max(region - foot_m, 2 * end_m);
    if (travel <= (outline ? 0.0 : foot_m / 3)) return std::vector<double>{0.0};
    const int n = static_cast<int>(std::ceil(travel / foot_m - 1e-9)) + 1;
    for (int i = 0; i < n; ++i) c.push_back(-0.5 * travel + travel * i / (n - 1));
    return c;
  };
  return {centres(region_m.x(), foot.x(), min_end_m.x()), centres(region_m.y(), foot.y(), min_end_m.y())};
}

// A serpentine over the rows, a row sweeping from one x end to the other (its end centres are
// enough), starting at the corner nearest to `at`.
std::vector<Eigen::Vector2d> Serpentine(const Rows& rows, const Eigen::Vector2d& at) {
  const double sx = at.x() > 0 ? -1.0 : 1.0, sy = at.y() > 0 ? -1.0 : 1.0;  // mirrored towards `at`
  std::vector<Eigen::Vector2d> points;
  for (size_t j = 0; j < rows.ys.size(); ++j) {
    const bool forward = j % 2 == 0;
    points.emplace_back(sx * (forward ? rows.xs.front() : rows.xs.back()), sy * rows.ys[j]);
    if (rows.xs.size() > 1) points.emplace_back(sx * (forward ? rows.xs.back() : rows.xs.front()), sy * rows.ys[j]);
  }
  return points;
}

// The descent's first pass, its first point where the descent turns into it. With three rows:
// out along the middle row to one end, then round the outer rows; the middle row's other half is
// seen by the frame on the turn and from the far end on the way between the outer rows, a row's
// length shorter than the serpentine (which would first have to reach a corner). The turn is off
// the middle by what lets the frame there (`drift_m` on into the pass) and the far end's frames
// meet with `foot_m` (the footprint along x at the band's near end); otherwise the serpentine,
// from the middle.
std::vector<Eigen::Vector2d> FirstPass(const Rows& rows, double foot_m, double drift_m) {
  if (rows.ys.size() != 3 || rows.xs.size() < 2) {
    std::vector<Eigen::Vector2d> points = Serpentine(rows, Eigen::Vector2d::Zero());
    points.insert(points.begin(), Eigen::Vector2d::Zero());
    return points;
  }
  const double x = rows.xs.back(), y = rows.ys.back();
  const double turn_x = std::clamp(x - foot_m + drift_m, 0.0, x);
  return {{turn_x, 0.0}, {-x, 0.0}, {-x, -y}, {x, -y}, {x, y}, {-x, y}};
}

// Times a path of corners, rounds them and solves it for the arm's joints into `plan`.
void Execute(const World& world, const std::vector<PathPoint>& polyline, double speed_m_s, double acceleration_m_s2,
             double smoothing_s, const World::ArmVector& q_seed, const IkOptions& ik, ApproachPlan* plan) {
  for (size_t i = 1; i < polyline.size(); ++i) plan->length_m += (polyline[i] - polyline[i - 1]).norm();
  std::vector<PathPoint> p_Bin = TimeParameterize(polyline, speed_m_s, acceleration_m_s2, plan->timestep_s);
  p_Bin = Smooth(p_Bin, 2 * static_cast<int>(std::lround(smoothing_s / plan->timestep_s / 2)) + 1);
  std::vector<Pose> T_Bin_C;
  for (const PathPoint& p : p_Bin) T_Bin_C.push_back(CameraPoseInBin(p));
  SolvePath(world, T_Bin_C, q_seed, ik, plan);
}

}  // namespace

std::vector<CoverageLevel> CoverageLevels(const ApproachOptions& o, double top_m, double rim_m) {
  ROMUNECT_CHECK(o.focused_far_m > o.focused_near_m && o.focused_near_m > 0);
  const double width = o.focused_far_m - o.focused_near_m;
  const double low = o.surface_low_m;
  // a range wide enough for the table and the rim at once measures both from one level
  const double top = std::max(rim_m - low <= width ? std::max(top_m, rim_m) : top_m, low + 1e-3);
  // bands from the table up to the top, each as wide as the range (the lowest, where most
  // surfaces lie, holds as many as it can), evenly spaced, the last ending at the top
  const int n = std::max(1, static_cast<int>(std::ceil((top - low) / width - 1e-9)));
  std::vector<CoverageLevel> levels;
  if (n == 1) levels.push_back(LevelFor(o, low, top));
  for (int i = 0; n > 1 && i < n; ++i) {
    const double band_low = low + (top - width - low) * i / (n - 1);
    levels.push_back(LevelFor(o, band_low, band_low + width));
  }
  // the rim, when the bands stop below it: a band of its own centred on it
  if (rim_m > top) {
    levels.push_back(LevelFor(o, rim_m - 0.25 * width, rim_m + 0.25 * width));
    levels.back().rim_only = true;
  }
  return levels;
}

namespace {

// The levels the descent visits, before the pile is measured: the lowest band, from the table up
// by one range width (a one-layer pile lies in it), and the rim's own band when the rim is above it.
std::vector<CoverageLevel> DescentLevels(const ApproachOptions& o, double rim_m) {
  const double one_layer_m = o.surface_low_m + (o.focused_far_m - o.focused_near_m);
  return CoverageLevels(o, std::min(one_layer_m, rim_m), rim_m);
}

// How far out the lowest band's passes reach (bin frame, both signs). The outer rows lie over the
// side walls: from further in, a wall hides the table beside it. The row ends reach the end
// walls' inner faces: the footprint, longer along x, then reaches past the wall (which hides about
// a millimetre of the table beyond it), and a frame further out would see mostly what lies
// beyond the region.
Eigen::Vector2d LowestPassEnds(const World& world) {
  const Eigen::Vector2d inner = world.bin_inner_size_m().head<2>();
  return {0.5 * inner.x(), 0.5 * inner.y() + kRunBeyondWallM};
}

// The bin's outline seen from above: its inner size and a wall's width on every side.
Eigen::Vector2d Outline(const World& world) {
  return world.bin_inner_size_m().head<2>() + Eigen::Vector2d::Constant(2 * kWallM);
}

}  // namespace

PileHeightMeter::PileHeightMeter(const Pose& T_W_Bin, const Eigen::Vector3d& bin_inner_size_m, int stride_px)
    : T_Bin_W_(T_W_Bin.inverse()),
      half_inner_m_(0.5 * bin_inner_size_m.head<2>() - Eigen::Vector2d::Constant(kWallMarginM)),
      stride_px_(stride_px) {
  ROMUNECT_CHECK(stride_px >= 1);
}

void PileHeightMeter::Add(const Frame& frame, const CameraModel& camera) {
  if (frame.depth_m.empty() || !frame.T_W_C) return;
  const Pose T_Bin_C = T_Bin_W_ * *frame.T_W_C;
  std::vector<float> heights_m;
  for (int v = 0; v < frame.depth_m.rows; v += stride_px_) {
    const float* row = frame.depth_m.ptr<float>(v);
    for (int u = 0; u < frame.depth_m.cols; u += stride_px_) {
      if (!(row[u] > 0)) continue;
      const Eigen::Vector3d p_Bin = T_Bin_C * camera.Unproject(Eigen::Vector2d(u, v), row[u]);
      if (std::abs(p_Bin.x()) > half_inner_m_.x() || std::abs(p_Bin.y()) > half_inner_m_.y()) continue;
      heights_m.push_back(static_cast<float>(p_Bin.z()));
    }
  }
  // a frame far above the measurable range holds only stray matches of the blurred pattern
  const size_t samples = static_cast<size_t>(frame.depth_m.rows / stride_px_) * (frame.depth_m.cols / stride_px_);
  if (heights_m.size() < kMinFrameShare * samples) return;
  heights_m_.insert(heights_m_.end(), heights_m.begin(), heights_m.end());
}

std::optional<double> PileHeightMeter::TopM(int min_samples) const {
  if (samples() < std::max(1, min_samples)) return std::nullopt;
  std::vector<float> h = heights_m_;
  // a count, not a share: the descent's frames at the lowest level add many low points, and a
  // tall object's top is in range for one frame only
  const size_t from_top = std::max<size_t>(kTopRank, static_cast<size_t>(kTopShare * (h.size() - 1)));
  const size_t k = h.size() - 1 - std::min(from_top, h.size() - 1);
  std::nth_element(h.begin(), h.begin() + k, h.end());
  return h[k];
}

ApproachPlan PlanDescent(const World& world, const CameraModel& camera, const ApproachOptions& o, const IkOptions& ik) {
  ApproachPlan plan;
  plan.timestep_s = world.timestep_s();
  // the lowest level does not depend on the pile: its band starts at the table
  const double rim_m = world.bin_inner_size_m().z();
  const std::vector<CoverageLevel> levels = DescentLevels(o, rim_m);
  const CoverageLevel& first = levels.front();
  plan.levels_m = {first.camera_height_m};
  const double v = o.coverage_speed_m_s, a = o.coverage_acceleration_m_s2;
  // Frame 1 is the first frame with the pile in range: it holds the whole footprint when the
  // frame before it was still above the pile. The descent therefore comes down at full speed
  // (a frame period apart: 30 mm at 0.9 m/s and 30 Hz) and turns at the first level into the
  // lowest band's first pass without braking: a frame falls on the turn (its band holds the
  // floor and a one-layer pile), and the frames after it add new area instead of braking on
  // one spot. The start is raised so that a whole number of frame periods brings
  // the camera to the turn: on the cruise, s(t) = v t - v^2 / (2 a).
  const double T = o.frame_period_s;
  const double brake_m = 0.5 * v * v / a;
  const Eigen::Vector2d corner = LowestPassEnds(world);
  // The turn's band starts at the bin floor (frame 1 over the bin's middle sees no table): a
  // one-layer pile as high as the band is wide is in range there. The corner filter lifts the
  // frame on the turn by an eighth of its window's travel (the mean over the window).
  const double lift_m = v * o.coverage_corner_smoothing_s / 8;
  const double turn_m = first.camera_height_m - std::min(first.low_m, 0.0) - lift_m;
  double start = std::max(o.start_distance_m, turn_m + kDescentRoomM);
  const bool timed = T > 0 && start - turn_m > brake_m;
  if (timed) {
    const int periods = static_cast<int>(std::ceil((start - turn_m + brake_m) / (v * T) - 1e-9));
    start = turn_m + periods * v * T - brake_m;
  }
  // the lowest band's first pass does not depend on the pile: the descent runs it
  const double first_far_m = first.camera_height_m - first.low_m;
  const double foot_near_m = (first.camera_height_m - first.high_m) * camera.width / camera.fx;
  const std::vector<Eigen::Vector2d> pass =
      FirstPass(PassRows(camera, o.region_size_m, first_far_m, corner), foot_near_m, lift_m);
  std::vector<PathPoint> polyline = {PathPoint(pass[0].x(), pass[0].y(), start, 0)};
  polyline.emplace_back(pass[0].x(), pass[0].y(), turn_m, 0);
  for (size_t i = 1; i < pass.size(); ++i) polyline.emplace_back(pass[i].x(), pass[i].y(), first.camera_height_m, 0);
  // The rim above the lowest band: its pass follows at once (the wall tops are a sixth of the
  // default region, and the rim's height is the bin's), from the corner nearer to the camera. Its
  // footprint is the one at the rim, and its rows run half a frame's travel past the outline's
  // ends, so that a frame falls over each end wherever the frames fall along a row.
  if (levels.back().rim_only) {
    const CoverageLevel& rim = levels.back();
    const Eigen::Vector2d past_ends(T > 0 ? v * T : 0.0, 0.0);
    const Rows rows = PassRows(camera, Outline(world) + past_ends, rim.camera_height_m - rim_m, {0, 0}, true);
    for (const Eigen::Vector2d& p : Serpentine(rows, polyline.back().head<2>())) {
      polyline.emplace_back(p.x(), p.y(), rim.camera_height_m, 0);
    }
    plan.levels_m.insert(plan.levels_m.begin(), rim.camera_height_m);
  }
  Execute(world, polyline, v, a, o.coverage_corner_smoothing_s, ScanPostureSeed(world), ik, &plan);
  return plan;
}

namespace {

ApproachPlan PlanCoverageTurning(const World& world, const CameraModel& camera, const ApproachOptions& o, double top_m,
                                 const ApproachPlan& descent, const IkOptions& ik, double turn_rad) {
  ROMUNECT_CHECK(!descent.T_W_C.empty());
  ApproachPlan plan;
  plan.timestep_s = world.timestep_s();
  const double rim = world.bin_inner_size_m().z();
  const std::vector<CoverageLevel> levels = CoverageLevels(o, std::max(top_m, 0.0), rim);
  const Eigen::Vector3d start_Bin = (world.T_W_Bin().inverse() * descent.T_W_C.back()).translation();
  std::vector<PathPoint> polyline = {PathPoint(start_Bin.x(), start_Bin.y(), start_Bin.z(), 0.0)};
  // The lowest band (table, floor, a one-layer pile) covers the whole region, the bands above it
  // the bin's inside, the rim's the bin's outline.
  const Eigen::Vector2d inside = world.bin_inner_size_m().head<2>();
  const Eigen::Vector2d outline = Outline(world);
  // the rim's own band, when the descent swept it (it then visited two levels), is passed on the
  // way up (the hand turns on the way instead) and swept again on the way back, with the turned passes
  const bool rim_swept = descent.levels_m.size() > 1;
  // a serpentine at level i with the hand's turn going from turn0 to turn1 along it
  auto sweep = [&](size_t i, double turn0_rad, double turn1_rad) {
    const CoverageLevel& level = levels[i];
    const bool rim_band = level.low_m <= rim && rim <= level.high_m;  // the band holding the rim
    const Eigen::Vector2d region = i == 0 ? o.region_size_m : rim_band ? outline : inside;
    const double distance = level.camera_height_m - level.low_m;  // the footprint at the band's far end
    const Eigen::Vector2d ends = i == 0 ? LowestPassEnds(world) : Eigen::Vector2d::Zero();
    const std::vector<Eigen::Vector2d> points =
        Serpentine(PassRows(camera, region, distance, ends, rim_band), polyline.back().head<2>());
    for (size_t k = 0; k < points.size(); ++k) {
      const double a = points.size() > 1 ? static_cast<double>(k) / (points.size() - 1) : 1.0;
      polyline.emplace_back(points[k].x(), points[k].y(), level.camera_height_m,
                            kTurnRadiusM * (turn0_rad + a * (turn1_rad - turn0_rad)));
    }
  };
  // The descent ran the lowest band's first pass (and the rim's, when it has a band of its own).
  // Then the bands above it, the hand turning on the way; then the lowest band again, turned, so
  // the baseline's shadows fall the other way; then the bands above it again, the hand turning back.
  const double turned = o.turned_passes ? turn_rad : 0.0;
  const size_t upper = levels.size() - 1;
  for (size_t i = 1; i < levels.size(); ++i) {
    if (!(levels[i].rim_only && rim_swept)) sweep(i, turned * (i - 1) / upper, turned * i / upper);
  }
  if (o.turned_passes) {
    sweep(0, turned, turned);
    // and back up through the bands above it, the hand turning back: their edges from both sides
    for (size_t i = 1; i < levels.size(); ++i) sweep(i, turned * (upper - i + 1) / upper, turned * (upper - i) / upper);
  }
  if (polyline.size() == 1) {  // nothing left to visit: the leg is the descent's last sample
    plan.T_W_C = {descent.T_W_C.back()};
    plan.q = {descent.q.back()};
    plan.levels_m = descent.levels_m;
    return plan;
  }
  plan.passes_x = plan.passes_y = 1;
  for (auto it = levels.rbegin(); it != levels.rend(); ++it) plan.levels_m.push_back(it->camera_height_m);
  Execute(world, polyline, o.coverage_speed_m_s, o.coverage_acceleration_m_s2, o.coverage_corner_smoothing_s,
          descent.q.back(), ik, &plan);
  return plan;
}

}  // namespace

ApproachPlan PlanCoverage(const World& world, const CameraModel& camera, const ApproachOptions& o, double top_m,
                          const ApproachPlan& descent, const IkOptions& ik) {
  // the wrist turns whichever way its joint limits allow
  try {
    return PlanCoverageTurning(world, camera, o, top_m, descent, ik, kTurnRad);
  } catch (const InputError&) {
    if (!o.turned_passes) throw;
    return PlanCoverageTurning(world, camera, o, top_m, descent, ik, -kTurnRad);
  }
}

}  // namespace romunect::sim
