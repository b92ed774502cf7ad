// The analytic bin workload (fusion issue): a bin 120 x 55 x 35 mm (3 mm walls and floor) on a
// table at z = 0, with boxes, spheres and cylinders inside, in a 150 x 80 mm region; a camera
// descending from 400 to 200 mm above the table with lateral motion and a few degrees of tilt,
// field of view 60 x 45 mm at 200 mm (for any image size); 30-80 % invalid pixels per frame in
// random blobs; Gaussian depth noise. Everything is exact analytic ray casting (no MuJoCo, no
// Embree) and deterministic from the seed: same options, same bytes.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/frame.h"
#include "romunect/sensor/pose.h"

namespace romunect::testing {

struct AnalyticBinOptions {
  int width = 640, height = 480;  // image size; intrinsics scale so the FOV stays 60 x 45 mm
  int frames = 50;
  uint32_t seed = 1;
  double noise_m = 1e-4;                            // depth noise, standard deviation along the optical axis
  double min_invalid = 0.3, max_invalid = 0.8;      // invalid share per frame, drawn uniformly
  double start_height_m = 0.4, end_height_m = 0.2;  // camera z in W, first and last frame
  std::array<double, 5> distortion{};               // k1, k2, p1, p2, k3 of the camera
};

class AnalyticBin {
 public:
  explicit AnalyticBin(const AnalyticBinOptions& options);

  // The region of the paper (150 x 80 mm) and a 64 mm z range covering table and bin, in W.
  static Eigen::Vector3d RegionMin() { return {-0.075, -0.040, -0.004}; }
  static Eigen::Vector3d RegionMax() { return {0.075, 0.040, 0.060}; }

  const AnalyticBinOptions& options() const { return options_; }
  const CameraModel& camera() const { return camera_; }
  int frames() const { return options_.frames; }
  const Pose& T_W_C(int i) const { return poses_.at(i); }

  // The smallest t > 0 with origin_W + t dir_W on a surface; +inf when the ray hits nothing.
  double Intersect(const Eigen::Vector3d& origin_W, const Eigen::Vector3d& dir_W) const;
  // The top surface's z (m) at (x, y): what a ray straight down first hits.
  double HeightAt(double x_m, double y_m) const;

  // Frame i: depth_m (noisy, with invalid blobs), gt_depth_m (exact), T_W_C, index, time_s.
  Frame RenderFrame(int i) const;

  // The exact height map at cell centres (min + (i + 0.5) voxel), CV_32F ny x nx, row 0 =
  // smallest y (the fused map's layout).
  cv::Mat GroundTruthHeightMap(const Eigen::Vector3d& min_W, double voxel_m, int nx, int ny) const;

  struct Solid {
    enum Kind { kBox, kSphere, kCylinder } kind;
    Eigen::Vector3d centre_W;
    Eigen::Matrix3d R_W_L;      // local axes (the cylinder's axis is local z)
    Eigen::Vector3d half_size;  // box: half extents; sphere: (r, r, r); cylinder: (r, r, half length)
  };
  const std::vector<Solid>& solids() const { return solids_; }

 private:
  AnalyticBinOptions options_;
  CameraModel camera_;
  std::vector<Pose> poses_;
  std::vector<Solid> solids_;
};

}  // namespace romunect::testing
