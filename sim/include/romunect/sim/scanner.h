// The twin's loop and the main job's engine: a Scanner loads the scene, drops and settles the
// pile, freezes it, plans the approach, moves the arm to its start, mirrors the MuJoCo world
// into the Embree renderer (static parts once, the frozen pile among them, so moving a pile
// object through world() afterwards does not show in renders; the arm's geoms as instances),
// and is then a FrameSource: each Next() advances the physics to the next 30 Hz sensor frame,
// updates the instances' poses, renders, and images the frame (IR synthesis and depth engine
// through a FrameImager; without one, depth_m is the ideal ground truth). Frames carry the
// EXECUTED T_W_C and T_B_H, and gt_depth_m. Frames: W world, B base, H hand, C camera; SI units.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/height_map.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/approach.h"
#include "romunect/sim/pile.h"
#include "romunect/sim/world.h"

namespace romunect::sim {

// Turns a rendered frame's geometry into the sensor's images in two stages: SynthesizeIr sets
// frame->ir from the geometry, then ComputeDepth sets raw and depth_m from the ir (gt_depth_m,
// poses, index and time are already set). `seed` differs per frame. The scanner may run the two
// stages at once on consecutive frames (ScanOptions::imaging_thread), so an imager keeps the
// stages' state apart. Image runs both.
class FrameImager {
 public:
  virtual ~FrameImager() = default;
  virtual void SynthesizeIr(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) = 0;
  virtual void ComputeDepth(const Rig& rig, Frame* frame) = 0;
  void Image(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) {
    SynthesizeIr(rig, geometry, seed, frame);
    ComputeDepth(rig, frame);
  }
};

// The depths (along the camera axis, m) where the rig measures: the depth engine searches
// search_range_px shifts centred on the zero-shift plane (the projector's pre-warp plane, the
// camera's focus distance), and a shift of s px is 1/Z - 1/Z_focus = s / (fx * baseline). Only
// usable_fraction of the search window counts: best matches at its border are clamped, not
// found. For the romunect rig about 191-210 mm (the paper's ~2 cm focused range).
struct DepthRange {
  double near_m = 0.0, far_m = 0.0;
};
DepthRange MeasurableDepthRange(const Rig& rig, double usable_fraction = 0.8);

struct ScanOptions {
  std::filesystem::path scene_file;   // MJCF with the arm and a bin; empty: the default scene
  std::filesystem::path saved_scene;  // a SaveSettledScene() file: its pile, no settling
  PileOptions pile;                   // the random pile (ignored with saved_scene)
  std::vector<ObjectSpec> extra_objects;  // added to the pile (user meshes)
  Rig rig = RigPreset("romunect");
  std::optional<Pose> T_H_C;          // hand-eye; default: the scene's camera site
  ApproachOptions approach;
  // Fill approach.focused_near_m/far_m from MeasurableDepthRange(rig) when they are 0, so the
  // passes run at stand-off levels where the rig measures.
  bool levels_from_rig = true;
  IkOptions ik;
  int samples_per_pixel = 1;          // renderer: 1 (pinhole) or 4 (thin lens, defocus)
  int threads = 2;                    // renderer threads
  // With an imager: while frame k renders, frame k - 1's IR synthesis and frame k - 2's depth
  // engine run on a thread each (the same frames, each delivered two renders later). The
  // imager's own threads add to them.
  bool imaging_thread = true;
  uint64_t seed = 1;                  // per-frame imaging seeds derive from it

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
};

struct ScanStats {
  SettleSummary settle;
  TrackingStats tracking;
  int frames = 0;
  double setup_s = 0.0;        // wall: loading, planning, scene building (settle excluded)
  double move_to_start_s = 0.0;  // simulated time of the joint-space move
  double physics_s = 0.0;      // wall, per stage, summed over the frames delivered
  double render_s = 0.0;
  double imaging_s = 0.0;      // IR synthesis + depth engine (the FrameImager)
  double simulated_s = 0.0;    // approach time of the last frame
  std::string BriefReport() const;
};

class Scanner : public FrameSource {
 public:
  // Does everything up to the first frame. Throws InputError for bad input: an invalid scene,
  // a rig that does not fit, a pile that does not settle (naming the scene and the energy),
  // an approach outside the workspace.
  explicit Scanner(const ScanOptions& options);
  ~Scanner() override;

  // Replaces the imaging stage (IR synthesis, depth engine, depth correction). Before the first
  // Next(), or after the stream ended: with ScanOptions::imaging_thread a frame may be in it.
  void SetImager(std::unique_ptr<FrameImager> imager);

  const CameraModel& camera() const override;
  std::string Describe() const override;
  FrameStatus Next(Frame* frame, std::string* error) override;

  int frame_count() const;  // frames the approach will deliver
  const ScanOptions& options() const;
  const ScanStats& stats() const;
  const ApproachPlan& plan() const;
  World& world();
  const World& world() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// The ground-truth height map of the world as it is now (world z of the highest surface in
// each cell's centre column, m; NaN where nothing is hit), ray traced from above. The arm is
// left out (it is above the bin while scanning). CV_32F, ny x nx of `geometry` (height_map.h;
// its z fields are unused).
cv::Mat GroundTruthHeightMap(const World& world, const HeightMapGeometry& geometry);

// A picture of the arm over the bin for people: the MuJoCo geoms ray traced with simple
// shading from an oblique viewpoint that frames the arm and the bin. CV_8UC3 (BGR).
cv::Mat OverviewPicture(const World& world, int width_px = 960, int height_px = 720);

}  // namespace romunect::sim
