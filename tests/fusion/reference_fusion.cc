#include "reference_fusion.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

namespace romunect::fusion::reference {
namespace {

void AddVote(int16_t* v, int delta) { *v = static_cast<int16_t>(std::clamp(*v + delta, -32767, 32767)); }

}  // namespace

ReferenceGrid::ReferenceGrid(const Eigen::Vector3d& min, double voxel, int nx, int ny, int nz)
    : min_W(min), voxel_m(voxel), n{nx, ny, nz}, votes(static_cast<size_t>(nx) * ny * nz, 0) {}

void ReferenceInsert(const CameraModel& camera, const cv::Mat& depth_m, const Pose& T_W_C, ReferenceGrid* grid,
                     ReferenceCounts* counts) {
  const Eigen::Matrix3d R = T_W_C.linear();
  const Eigen::Vector3d o_W = T_W_C.translation();
  const int* n = grid->n;
  std::vector<int16_t*> hits;  // applied after every miss of the frame (voting_grid.h)
  for (int v = 0; v < depth_m.rows; ++v) {
    for (int u = 0; u < depth_m.cols; ++u) {
      const float depth = depth_m.at<float>(v, u);
      if (depth == 0.0f) continue;
      if (!(depth > 0.0f) || !std::isfinite(depth)) {
        ++counts->invalid;
        continue;
      }
      ++counts->rays;
      const Eigen::Vector3d ray_C = camera.Ray(Eigen::Vector2d(u, v));
      double o[3], p[3], d[3], inv[3];
      bool inside = true;
      for (int a = 0; a < 3; ++a) {
        const double dir = R(a, 0) * ray_C[0] + R(a, 1) * ray_C[1] + R(a, 2) * ray_C[2];
        const double p_W = o_W[a] + static_cast<double>(depth) * dir;
        o[a] = (o_W[a] - grid->min_W[a]) / grid->voxel_m;
        p[a] = (p_W - grid->min_W[a]) / grid->voxel_m;
        d[a] = p[a] - o[a];
        inv[a] = 1.0 / d[a];
        inside = inside && p[a] >= 0.0 && p[a] < n[a];
      }
      if (!inside) ++counts->points_outside_box;
      // Clip the segment to the box.
      double t_enter = 0.0, t_exit = 1.0;
      for (int a = 0; a < 3; ++a) {
        if (d[a] != 0.0) {
          double ta = (0.0 - o[a]) * inv[a], tb = (static_cast<double>(n[a]) - o[a]) * inv[a];
          if (ta > tb) std::swap(ta, tb);
          t_enter = std::max(t_enter, ta);
          t_exit = std::min(t_exit, tb);
        } else if (!(o[a] >= 0.0 && o[a] < n[a])) {
          t_enter = 1.0;
          t_exit = 0.0;
        }
      }
      if (!(t_enter < t_exit)) {
        ++counts->rays_missing_box;
        continue;
      }
      // Walk voxel by voxel.
      int idx[3], step[3];
      double t_next[3];
      for (int a = 0; a < 3; ++a) {
        idx[a] = static_cast<int>(std::clamp(std::floor(o[a] + t_enter * d[a]), 0.0, n[a] - 1.0));
        step[a] = d[a] > 0.0 ? 1 : (d[a] < 0.0 ? -1 : 0);
        t_next[a] = step[a] == 0 ? std::numeric_limits<double>::infinity()
                                 : (static_cast<double>(step[a] > 0 ? idx[a] + 1 : idx[a]) - o[a]) * inv[a];
      }
      for (;;) {
        int a = 0;
        if (t_next[1] < t_next[a]) a = 1;
        if (t_next[2] < t_next[a]) a = 2;
        int16_t* vote = &grid->at(idx[0], idx[1], idx[2]);
        if (!(t_next[a] < t_exit)) {  // the last voxel of the segment
          if (inside) {
            hits.push_back(vote);
            ++counts->hits;
          } else {
            AddVote(vote, -1);
            ++counts->misses;
          }
          break;
        }
        AddVote(vote, -1);
        ++counts->misses;
        idx[a] += step[a];
        if (idx[a] < 0 || idx[a] >= n[a]) break;
        t_next[a] = (static_cast<double>(step[a] > 0 ? idx[a] + 1 : idx[a]) - o[a]) * inv[a];
      }
    }
  }
  for (int16_t* vote : hits) AddVote(vote, +1);
}

cv::Mat ReferenceExtract(const ReferenceGrid& grid) {
  cv::Mat height(grid.n[1], grid.n[0], CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN()));
  for (int iy = 0; iy < grid.n[1]; ++iy) {
    for (int ix = 0; ix < grid.n[0]; ++ix) {
      int best_k = -1, best = 0;
      for (int k = 0; k < grid.n[2]; ++k) {
        const int vote = grid.at(ix, iy, k);
        if (vote > 0 && vote >= best) {  // ties: the higher z wins
          best = vote;
          best_k = k;
        }
      }
      if (best_k >= 0) {
        height.at<float>(iy, ix) = static_cast<float>(grid.min_W.z() + (best_k + 0.5) * grid.voxel_m);
      }
    }
  }
  return height;
}

}  // namespace romunect::fusion::reference
