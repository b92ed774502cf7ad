// IR image synthesis: from what each camera ray hit (GeometryBuffer, frame C) to the camera's
// 10-bit IR image (CV_16U), following rig.h's optics and radiometry. Per hit: projector pixel
// through T_C_P and the projector model; the pattern there, blurred by the projector's circle
// of confusion at that distance and by the camera pixel's footprint; the lit mask (shadows);
// the BRDF (IrMaterial: Lambert + Phong lobe); inverse-square fall-off; ambient IR. Then camera
// defocus (a per-pixel blur by the circle of confusion with one sample per pixel; with lens-
// sampled layers the average over the layers is the defocus), exposure and gain, shot and read
// noise (seeded, counter based: the same bytes at any thread count), full well, quantization.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/rig.h"

namespace romunect {

struct IrSynthesisOptions {
  bool noise = true;           // shot and read noise (off: the expected image, rounded)
  bool camera_defocus = true;  // blur by the camera's circle of confusion
  int threads = 1;

  std::string Problem() const;
};

struct IrSynthesisStats {
  int pixels_hit = 0;        // rays that hit a surface (layer 0)
  int pixels_lit = 0;        // ... and whose hit the projector sees
  int pixels_saturated = 0;  // output at the top of the range
  double mean_dn = 0.0;
  double seconds = 0.0;
  std::string BriefReport() const;
};

// Owns the per-rig pattern stack and per-frame buffers, reused from frame to frame.
class IrSynthesizer {
 public:
  explicit IrSynthesizer(const IrSynthesisOptions& options = {});

  // Builds the rig's blurred pattern levels now rather than in the first Synthesize: for a
  // 1280 x 720 projector ~0.2 s of CPU, setup that a scan's first frame should not wait for.
  // Nothing to do when they are built for this rig's pattern, prewarp and projector.
  void Prepare(const Rig& rig);

  // Writes the IR image (CV_16U, camera size, values in [0, 2^bits - 1]) into *ir. The
  // geometry must match rig.camera's size. stats may be null.
  void Synthesize(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, cv::Mat* ir, IrSynthesisStats* stats);

  // Expected electrons per pixel of the last frame, before noise and clipping (CV_32F).
  const cv::Mat& expected_electrons() const { return blurred_; }

  // The instruction set of the code that shades and finishes the pixels: ResolveIsa() of the
  // one set (kAuto unless set). set_isa needs kAuto or one the synthesizer implements (scalar,
  // AVX2, AVX-512) and the CPU supports; every one gives the same bytes (tests/sensor compare them).
  Isa isa() const { return isa_; }
  void set_isa(Isa isa);

  // Shot and read noise on or off from the next frame (the pattern levels are kept).
  bool noise() const { return options_.noise; }
  void set_noise(bool noise) { options_.noise = noise; }

 private:
  // Blur levels (sigmas increasing) and where to start looking for a sigma's pair of levels
  // (the kernels' FindLevel gives the level k and weight w of (1 - w) level[k] + w level[k + 1]).
  struct LevelTable {
    LevelTable() = default;
    explicit LevelTable(std::vector<float> level_sigmas);
    static constexpr float kLutPerPx = 16.f;  // start indices per pixel of sigma
    std::vector<float> sigmas;
    std::vector<int> start;  // by sigma bin
  };

  // Writes the layer's radiance (electrons) into *electrons or, given layer 0 as `base` with
  // its radiance, adds it to *electrons, reusing base's value where the hit is the same.
  // material_table_ holds `materials`.
  void ShadeLayer(const Rig& rig, const GeometryLayer& layer, const std::vector<IrMaterial>& materials,
                  const GeometryLayer* base, const cv::Mat* base_electrons, cv::Mat* electrons) const;
  // Synthesize's steps, in order. The radiance of every layer, averaged into electrons_; returns
  // whether the layers sampled the lens aperture.
  bool ShadeLayers(const Rig& rig, const GeometryBuffer& geometry);
  // The camera blur sigma per pixel (sigma_map_) from layer 0's depths, its range per row
  // (row_sigma_min_, row_sigma_max_); returns the largest.
  float DefocusSigmas(const Rig& rig, const GeometryLayer& layer0);
  // The blur levels of the camera (camera_table_), each blurred over the rows that read it.
  void BlurCameraLevels(float psf_sigma, float max_sigma, bool defocus);
  // The blend of the levels, noise, full well, gain and quantization into *ir.
  void FinishImage(const Rig& rig, uint64_t seed, cv::Mat* ir);

  IrSynthesisOptions options_;
  Isa isa_;  // resolved
  // Cached per rig: the displayed image blurred at increasing sigmas (projector pixels), each
  // with a zero border of one pixel, stacked level after level in one CV_32F image.
  PatternSpec cached_pattern_;
  Eigen::Matrix3d cached_H_ = Eigen::Matrix3d::Zero();
  ProjectorModel cached_projector_;
  cv::Mat pattern_stack_;
  LevelTable pattern_table_;
  // Per-frame workspace, reused: the materials' albedos, speculars and shininesses, each padded
  // to internal::kTableSize (ir_synthesis_kernel.h), and the camera blur levels stacked like the
  // pattern's (camera_levels_ views them).
  std::vector<float> material_table_;
  cv::Mat electrons_, layer0_electrons_, blurred_, sigma_map_, camera_stack_;
  std::vector<float> row_sigma_min_, row_sigma_max_;  // per row, with defocus
  std::vector<cv::Mat> camera_levels_;
  LevelTable camera_table_;
};

// A fronto-parallel plane at depth_m filling the whole view, lit everywhere, one material:
// the chip's reference scene, and a quick test scene.
GeometryBuffer FrontoParallelPlane(const CameraModel& camera, double depth_m, const IrMaterial& material);

}  // namespace romunect
