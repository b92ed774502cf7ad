// Renders a RayScene into a GeometryBuffer (geometry_buffer.h): a camera ray per pixel through
// the camera model (distortion included, pixel centres at integer coordinates), traced as
// coherent 4 x 4 packets; for each hit a shadow ray towards the projector centre (the
// translation of T_C_P) gives the lit mask. Everything is in frame C: hit points p_C (m),
// unit normals facing the camera, material index and object id.
//
// Sampling: layers[0] is always the pinhole ray through the pixel centre (ground truth). The
// quality mode (samples_per_pixel = 4) adds three thin-lens samples with a fixed stratified
// pattern (QualitySamplePattern): sub-pixel offsets and points on the lens aperture, focused
// at focus_distance_m. Its fast variant (adaptive) traces layer 0 first and adds the three
// extra samples, through the pinhole at the same sub-pixel offsets, only in pixels at an edge of
// layer 0 (object, shadow or depth step: where depth or defocus changes within the pixel);
// elsewhere the extra layers repeat layer 0's sample and image synthesis applies the camera's
// defocus as in the 1-sample mode. The result does not depend on the number of threads, bit
// for bit.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/embree/ray_scene.h"
#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/pose.h"

namespace romunect::embree {

struct RenderOptions {
  int samples_per_pixel = 1;       // 1 (pinhole) or 4 (quality mode, thin lens)
  double focus_distance_m = 0.2;   // camera lens focus: depth (z in C) that is sharp, > 0
  double aperture_radius_m = 0.0;  // camera lens aperture radius, >= 0; 0 = pinhole
  int threads = 1;                 // render threads (tiles handed out in order), >= 1
  int tile_size_px = 32;           // square tiles, a multiple of 4 (the packet size)
  double shadow_bias_m = 2e-6;     // shadow rays leave this far off the surface (self-hits)
  bool adaptive = false;           // with 4 samples: extra samples only at edges (see above)
  // Adaptive: neighbouring depths further apart than this many pixel footprints (z / fx) mark
  // a depth edge; 4 = surfaces steeper than 76 degrees to the view count as edges.
  double edge_slope = 4.0;
  // The instruction set of the renderer's own per-ray work around the Embree calls (Embree picks
  // its own): kAuto, or one the renderer implements (sse2, avx2, avx512) and the CPU supports.
  // Every one gives the same bytes.
  Isa isa = Isa::kAuto;

  // Why the options are unusable, or "" (names the field, its value and the rule).
  std::string Problem() const;
};

struct RenderStats {
  int64_t camera_rays = 0;     // over all layers
  int64_t hits = 0;            // camera rays that hit something
  int64_t shadow_rays = 0;     // traced shadow rays (hits facing the projector)
  int64_t lit = 0;             // hits the projector centre sees
  int64_t refined_pixels = 0;  // adaptive: pixels that got the extra samples
  // Moving parts that no camera ray (no shadow ray) of the frame can reach, from their bounding
  // boxes against the view's bounds. When that is all of them, those rays skip the moving parts
  // (on a hand-held sensor the arm's links sit behind the camera); the image is the same.
  int64_t moving_out_of_view = 0;
  int64_t moving_out_of_shadows = 0;
  double seconds = 0.0;  // wall time of Render()
  std::string BriefReport() const;
};

// One sample of the quality pattern: sub-pixel offset (px) and point on the aperture (m).
struct LensSample {
  Eigen::Vector2f pixel_offset_px = Eigen::Vector2f::Zero();
  Eigen::Vector2f lens_offset_m = Eigen::Vector2f::Zero();
};

// The fixed pattern of samples_per_pixel samples; sample 0 is the pinhole centre ray. For 4:
// the centre stands for the inner quarter of pixel and aperture; the other three sit at 120
// degree steps, at 1/3 px from the centre and at 0.778 of the aperture radius (the centroid
// of a third of the outer ring), their lens angles turned 60 degrees from the pixel angles.
std::vector<LensSample> QualitySamplePattern(int samples_per_pixel, double aperture_radius_m);

class GeometryRenderer {
 public:
  GeometryRenderer();
  ~GeometryRenderer();
  GeometryRenderer(GeometryRenderer&&) noexcept;
  GeometryRenderer& operator=(GeometryRenderer&&) noexcept;

  // Renders the committed scene seen by `camera` at pose T_W_C with the projector at T_C_P
  // into *out (its Mats are reused when they already have the right size). Ray tables of a
  // camera are computed on first use and kept. Options must be valid (Problem() == "").
  RenderStats Render(const RayScene& scene, const CameraModel& camera, const Pose& T_W_C, const Pose& T_C_P,
                     const RenderOptions& options, GeometryBuffer* out);

 private:
  struct Cache;
  std::unique_ptr<Cache> cache_;
};

// Ground truth of a rendered frame, from layers[0]: depth along the optical axis (z in C, m;
// 0 where the ray missed), CV_32F.
cv::Mat GroundTruthDepth(const GeometryBuffer& buffer);

}  // namespace romunect::embree
