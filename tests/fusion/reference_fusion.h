// The plain reference of the fusion's semantics (voting_grid.h): a dense vote array, one ray at a
// time, a textbook 3D Amanatides-Woo walk, one voxel per step, and a full-column extraction.
// Slow and obvious on purpose: the fast path must match it vote for vote.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::fusion::reference {

struct ReferenceGrid {
  Eigen::Vector3d min_W;
  double voxel_m = 0.0;
  int n[3] = {0, 0, 0};
  std::vector<int16_t> votes;  // (iy * nx + ix) * nz + iz

  ReferenceGrid(const Eigen::Vector3d& min, double voxel, int nx, int ny, int nz);
  int16_t& at(int ix, int iy, int iz) { return votes[(static_cast<size_t>(iy) * n[0] + ix) * n[2] + iz]; }
  int16_t at(int ix, int iy, int iz) const { return votes[(static_cast<size_t>(iy) * n[0] + ix) * n[2] + iz]; }
};

struct ReferenceCounts {
  size_t rays = 0, hits = 0, misses = 0, rays_missing_box = 0, points_outside_box = 0, invalid = 0;
};

// Casts every pixel of depth_m in pixel-row order, the frame's hits after all of its misses
// (voting_grid.h).
void ReferenceInsert(const CameraModel& camera, const cv::Mat& depth_m, const Pose& T_W_C, ReferenceGrid* grid,
                     ReferenceCounts* counts);

// Per column: the voxel with the highest positive vote (ties: higher z); NaN when none.
cv::Mat ReferenceExtract(const ReferenceGrid& grid);

}  // namespace romunect::fusion::reference
