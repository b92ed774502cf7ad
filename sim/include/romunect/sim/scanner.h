// The twin's loop and the main job's engine: a Scanner loads the scene, drops and settles the
// pile, freezes it, plans the approach, moves the arm to its start, mirrors the MuJoCo world
// into the Embree renderer (static parts once, the frozen pile among them, so moving a pile
// object through world() afterwards does not show in renders; the arm's geoms as instances),
// and is then a FrameSource: each Next() advances the physics to the next 30 Hz sensor frame,
// updates the instances' poses, renders, and images the frame (IR synthesis and depth engine
// through a FrameImager; without one, depth_m is the ideal ground truth), all on the caller's
// thread. The same steps are exposed as stages (Render, SynthesizeIr, ComputeDepth) for a
// FramePipeline that runs them on threads of their own (AddScanStages). Frames carry the
// EXECUTED T_W_C and T_B_H, and gt_depth_m. Frames: W world, B base, H hand, C camera; SI units.
#pragma once

#include <cstdint>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/frame_pipeline.h"
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
// poses, index and time are already set). `seed` differs per frame. A scan pipeline runs the two
// stages at once on different frames (AddScanStages), so an imager keeps the stages' state apart.
// Image runs both.
class FrameImager {
 public:
  virtual ~FrameImager() = default;
  virtual void SynthesizeIr(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) = 0;
  virtual void ComputeDepth(const Rig& rig, Frame* frame) = 0;
  // A frame whose images the imager already holds (a resumed run's, read back): sets ir, raw,
  // depth_m and gt_depth_m and returns true, and the scanner neither renders nor images it (only
  // its physics and poses run). Called in Render, in frame order. Default: none.
  virtual bool Replay(const Rig& rig, Frame* frame) { return false; }
  void Image(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) {
    SynthesizeIr(rig, geometry, seed, frame);
    ComputeDepth(rig, frame);
  }
};

// The depths (along the camera axis, m) where the rig measures: the depth engine searches the
// shifts [min_shift_px, min_shift_px + search_range_px) against the chip's reference, and the
// shift at the centre pixel is affine in 1/Z (zero on the projector's pre-warp plane, or on the
// chip's reference plane for the stock device). Only usable_fraction of the search window, about
// its centre, counts: best matches at its border are clamped, not found. A window that reaches
// zero disparity ends at 10 x the focus distance. The romunect rig: about 191-210 mm (the
// paper's ~2 cm focused range); kinect-v1: about 0.48-3.0 m.
struct DepthRange {
  double near_m = 0.0, far_m = 0.0;
};
DepthRange MeasurableDepthRange(const Rig& rig, double usable_fraction = 0.8);

struct ScanOptions {
  std::filesystem::path scene_file;       // MJCF with the arm and a bin; empty: the default scene
  std::filesystem::path saved_scene;      // a SaveSettledScene() file: its pile, no settling
  PileOptions pile;                       // the random pile (ignored with saved_scene)
  std::vector<ObjectSpec> extra_objects;  // added to the pile (user meshes)
  Rig rig = RigPreset("romunect");
  std::optional<Pose> T_H_C;  // hand-eye; default: the scene's camera site
  ApproachOptions approach;
  // Fill approach.focused_near_m/far_m from MeasurableDepthRange(rig) when they are 0, so the
  // passes run at stand-off levels where the rig measures.
  bool levels_from_rig = true;
  IkOptions ik;
  int samples_per_pixel = 1;  // renderer: 1 (pinhole) or 4 (thin lens, defocus)
  int threads = 2;            // renderer threads
  uint64_t seed = 1;          // per-frame imaging seeds derive from it
  // When set, each frame also carries this colour camera's image (frame.color, color_camera.h),
  // rendered beside the IR camera and shaded for a surface at the rig's focus distance.
  std::optional<ColorCamera> color_camera;

  std::string Problem() const;  // "" when valid; otherwise "field = value: rule"
};

struct ScanStats {
  SettleSummary settle;
  TrackingStats tracking;
  int frames = 0;
  double setup_s = 0.0;          // wall: loading, planning, scene building (settle excluded)
  double move_to_start_s = 0.0;  // simulated time of the joint-space move
  double physics_s = 0.0;        // wall, per stage, summed over the frames delivered
  double render_s = 0.0;
  double imaging_s = 0.0;    // IR synthesis + depth engine (the FrameImager)
  double simulated_s = 0.0;  // approach time of the last frame
  std::string BriefReport() const;
};

// One frame of the scan between the Scanner's stages: the frame and, from Render until
// SynthesizeIr, the geometry buffer it was rendered into (the scanner's, lent for that time).
// The frame's images are its own (new for every frame): a consumer may keep them.
struct ScanWork {
  Frame frame;
  uint64_t seed = 0;  // the frame's imaging seed
  bool replayed = false;  // FrameImager::Replay gave its images: not rendered, not imaged
  std::shared_ptr<GeometryBuffer> geometry;
  double ir_s = 0.0;  // wall time of SynthesizeIr (added to ScanStats::imaging_s by ComputeDepth)
};

class Scanner : public FrameSource {
 public:
  // Does everything up to the first frame. Throws InputError for bad input: an invalid scene,
  // a rig that does not fit, a pile that does not settle (naming the scene and the energy),
  // an approach outside the workspace.
  explicit Scanner(const ScanOptions& options);
  ~Scanner() override;

  // Replaces the imaging stage (IR synthesis, depth engine, depth correction). Not while a
  // pipeline runs the stages.
  void SetImager(std::unique_ptr<FrameImager> imager);

  const CameraModel& camera() const override;
  std::string Describe() const override;
  // Render, SynthesizeIr and ComputeDepth of the next frame, in line.
  FrameStatus Next(Frame* frame, std::string* error) override;

  // The stages of Next(), for a pipeline. Each is called in frame order from one thread at a
  // time; the three may run at once on different frames (frame k renders while k - 1 has its IR
  // synthesized and k - 2 its depth computed): a frame's bytes are the same either way.
  // Render: advances the physics to the next frame and renders it into *work (a fresh ScanWork);
  // false when the approach has ended. Without an imager it also sets the ideal depth.
  bool Render(ScanWork* work);
  void SynthesizeIr(ScanWork* work);  // with an imager: frame.ir; gives the geometry buffer back
  void ComputeDepth(ScanWork* work);  // with an imager: frame.raw and frame.depth_m

  // Frames the approach will deliver. With Sweep::kCoverage, the descent's until the frame after
  // it plans the coverage leg (Render: it waits until ComputeDepth has measured every descent
  // frame, so the plan is the same whatever the threads' timing), then all of them.
  int frame_count() const;
  int descent_frames() const;  // kCoverage: frames before the coverage leg is planned; else 0
  // kCoverage: the pile's top above the bin floor as the descent measured it (PileHeightMeter),
  // once the coverage leg is planned; nothing before, or when too little was measured.
  std::optional<double> measured_pile_top_m() const;
  // The options in use; approach.focused_*_m from the rig, approach.surface_height_m from the
  // measured pile once the coverage leg is planned (ScanRegionBox then gives the fusion box).
  const ScanOptions& options() const;
  const ScanStats& stats() const;  // between frames, or after a pipeline's run
  const ApproachPlan& plan() const;
  World& world();
  const World& world() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Sets `pipeline`'s source to scanner->Render and adds the imaging stages ("ir", "depth", with
// queues of `queue_depth`); the caller adds its consumers (fusion, writing) after them. The
// scanner must outlive the pipeline's run, and nothing else may drive it meanwhile.
void AddScanStages(Scanner* scanner, FramePipeline<ScanWork>* pipeline, int queue_depth = 1);

// The ground-truth height map of the world as it is now (world z of the highest surface in
// each cell's centre column, m; NaN where nothing is hit), ray traced from above. The arm is
// left out (it is above the bin while scanning). CV_32F, ny x nx of `geometry` (height_map.h;
// its z fields are unused).
cv::Mat GroundTruthHeightMap(const World& world, const HeightMapGeometry& geometry);

// A picture of the arm over the bin for people: the MuJoCo geoms ray traced with simple
// shading from an oblique viewpoint that frames the arm and the bin. CV_8UC3 (BGR).
cv::Mat OverviewPicture(const World& world, int width_px = 960, int height_px = 720);

}  // namespace romunect::sim
