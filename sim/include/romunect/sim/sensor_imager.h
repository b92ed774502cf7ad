// The simulated sensor's imaging stage for the Scanner: IR synthesis from the rendered
// geometry, the Kinect-style depth engine, and the per-pixel depth correction that turns the
// chip's raw output into metric depth. Without a calibration the correction is the rig's
// ground truth, fitted here from fronto-parallel planes whose depth the simulator knows.
// Frames: C, the camera; depth in metres along the optical axis.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/scanner.h"

namespace romunect::sim {

struct SensorImagerOptions {
  int threads = 1;  // IR synthesis and depth engine threads
  // A correction from a calibration (the calibration file's depth model); nullopt: the rig's
  // ground truth from a plane sweep.
  std::optional<DepthCorrection> correction;
  std::string correction_source;  // what `correction` came from, for reports
  // Ground-truth plane sweep: planes from near to far; both 0: the rig's matchable range
  // (MeasurableDepthRange with sweep_fraction of the search window). Planes outside it give
  // no or false matches, which bent the fit and put gross outliers into the maps.
  double sweep_near_m = 0.0;
  double sweep_far_m = 0.0;
  double sweep_fraction = 0.9;
  int sweep_planes = 17;
  // Depths outside MeasurableDepthRange(rig, keep_fraction) are dropped (set to 0): matches at
  // the border of the shift search are clamped there, not found. 1: keep all.
  double keep_fraction = 0.95;
  std::string Problem() const;
};

class SensorImager : public FrameImager {
 public:
  // Builds the depth engine (the chip's reference image), the synthesizer's pattern levels and,
  // without a given correction, the ground-truth correction: the first frame waits for none.
  // Throws InputError("sensor imager", field, ...) on bad options or a correction of the wrong size.
  SensorImager(const Rig& rig, const SensorImagerOptions& options);

  void SynthesizeIr(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, Frame* frame) override;
  void ComputeDepth(const Rig& rig, Frame* frame) override;

  const DepthCorrection& correction() const { return correction_; }
  // Where the correction came from ("ground truth of the rig: ..." or the calibration file).
  const std::string& correction_source() const { return correction_source_; }
  const DepthEngineStats& last_stats() const { return output_.stats; }  // of the last ComputeDepth

 private:
  SensorImagerOptions options_;
  IrSynthesizer synthesizer_;  // SynthesizeIr's state
  DepthEngine engine_;         // ComputeDepth's (with output_)
  DepthCorrection correction_;
  std::string correction_source_;
  DepthRange keep_;           // depths kept (m)
  DepthEngineOutput output_;  // reused every frame
};

// The rig's ground-truth depth correction (1/Z affine in raw per pixel): fronto-parallel planes
// at known depths are imaged through the rig and the depth engine, and each pixel's model is
// fitted to the true depths. Noise-free imaging, so the fit shows the model, not the noise.
DepthCorrection GroundTruthDepthCorrection(const Rig& rig, const SensorImagerOptions& options);
// The depths the ground-truth sweep spans (the options' or the rig's matchable range).
DepthRange SweepRange(const Rig& rig, const SensorImagerOptions& options);

}  // namespace romunect::sim
