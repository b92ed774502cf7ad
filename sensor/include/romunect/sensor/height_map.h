// Where a height map's cells lie: a 2.5D map over the world's x-y plane (frame W, z up,
// metres), as fusion extracts it from its voting grid and the simulator traces its ground
// truth. A height map is a CV_32F image of ny rows x nx columns holding world z (m), NaN where
// empty; cell (row j, column i) has its centre at (min_x + (i + 0.5) voxel, min_y + (j + 0.5)
// voxel), row 0 is the smallest y. The z fields describe the grid the map came from (fusion's
// voxel layers; 0 where there is none).
#pragma once

#include <Eigen/Core>

namespace romunect {

struct HeightMapGeometry {
  double min_x_m = 0.0, min_y_m = 0.0, min_z_m = 0.0;  // the box's minimum corner in W
  double voxel_m = 0.0;                                // cell (and voxel) edge
  int nx = 0, ny = 0, nz = 0;                          // columns, rows, z layers

  double CellCentreX_m(int i) const { return min_x_m + (i + 0.5) * voxel_m; }
  double CellCentreY_m(int j) const { return min_y_m + (j + 0.5) * voxel_m; }
  double LayerCentreZ_m(int k) const { return min_z_m + (k + 0.5) * voxel_m; }
  // The centre of cell (row j, column i) in W's x-y plane.
  Eigen::Vector2d CellCentre_W(int i, int j) const { return {CellCentreX_m(i), CellCentreY_m(j)}; }
  double size_x_m() const { return nx * voxel_m; }
  double size_y_m() const { return ny * voxel_m; }
};

}  // namespace romunect
