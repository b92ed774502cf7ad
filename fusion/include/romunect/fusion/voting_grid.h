// The occupancy voting grid of the fusion (paper, section 3.3): a dense voxel grid over an
// axis-aligned box in the world (frame G = W shifted to the box's minimum corner, metres), one
// signed vote per voxel. A ray from the camera centre to a measured point gives every voxel it
// crosses inside the box a miss (-1) and the voxel that holds the point a hit (+1). The fused
// depth map keeps, per (x, y) column, the voxel centre with the highest positive vote.
//
// Traversal semantics (shared by the fast path and the plain reference in tests/fusion; both
// evaluate these exact double expressions, so their votes are bit-identical):
//   grid units g = (p_W - min_W) / voxel_m, component by component; voxel (i, j, k) is
//   [i, i+1) x [j, j+1) x [k, k+1). For pixel (u, v) with depth d > 0 (finite):
//   ray_C = camera.Ray(u, v); dir_W[a] = R(a,0) ray_C[0] + R(a,1) ray_C[1] + R(a,2) ray_C[2];
//   p_W = o_W + d dir_W (o_W = T_W_C translation); seg(t) = o_g + t (p_g - o_g), t in [0, 1];
//   inv[a] = 1 / (p_g[a] - o_g[a]); plane crossings t = (P - o_g[a]) * inv[a].
//   The segment is clipped to the box (slab test, t_enter = max(0, ...), t_exit = min(1, ...));
//   the start voxel is clamp(floor(o_g + t_enter d_g)); the walk steps the axis whose next
//   crossing is smallest (ties: x, then y, then z) while that crossing is < t_exit. Every voxel
//   visited gets a miss, except the last one, which gets a hit when p_g lies inside the grid.
//
// Votes are int16 and saturate at +-32767: int8 would saturate after ~127 rays (a surface voxel
// at 0.25 mm sees ~7 rays per frame at 200 mm, so 20-30 frames), and saturated ties would bias
// heights upward; int16 needs 300+ such frames. Saturating (not wrapping) keeps the sign.
//
// Order within a frame: every voxel gets all of the frame's misses, then its hits, each
// saturating: v <- max(v - m, -32767), then v <- min(v + h, 32767). Misses commute with misses and
// hits with hits (each saturates at one end only), so the votes do not depend on the order in
// which the frame's rays are cast, on threads or on kernels: the fast path may interleave rays.
// (Casting ray after ray would differ only where a voxel saturates within the frame.)
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/height_map.h"

namespace romunect::fusion {

using Vote = int16_t;

struct GridOptions {
  // The box in W, metres. Default: the paper's 150 x 80 mm region, 64 mm tall, around a bin
  // standing on z = 0.
  Eigen::Vector3d min_W{-0.075, -0.040, -0.004};
  Eigen::Vector3d max_W{0.075, 0.040, 0.060};
  double voxel_m = 0.25e-3;
  // Refuse grids above this many bytes (and above the machine's physical memory).
  size_t max_memory_bytes = size_t{16} << 30;
  // Page all of the votes in at construction (zeroing them takes ~0.3 s for 100 MB here), so a
  // real-time loop never waits for first touches; otherwise pages come as rays reach them and
  // parts no ray reaches cost no memory.
  bool prefault = false;

  // Why the options are unusable, or "" when valid (names the field, value and rule).
  std::string Problem() const;
  // Voxels per axis: ceil(extent / voxel - 1e-6); the grid covers [min, min + n voxel).
  Eigen::Vector3i Dims() const;
  // Bytes the grid needs (votes plus per-column bookkeeping).
  size_t RequiredBytes() const;
};

// Where the cells of the extracted height map lie (sensor/height_map.h: one layout for fusion,
// the simulator's ground truth and the pick).
using HeightMapGeometry = ::romunect::HeightMapGeometry;

class VotingGrid {
 public:
  // Validates the options and allocates zeroed memory (paged in now with `prefault`, else as
  // rays reach it). Throws InputError (source "fusion grid") naming the field on invalid
  // options, and with the bytes needed when the grid does not fit.
  explicit VotingGrid(const GridOptions& options);
  ~VotingGrid();
  VotingGrid(const VotingGrid&) = delete;
  VotingGrid& operator=(const VotingGrid&) = delete;

  const GridOptions& options() const { return options_; }
  int nx() const { return nx_; }
  int ny() const { return ny_; }
  int nz() const { return nz_; }
  double voxel_m() const { return options_.voxel_m; }
  HeightMapGeometry geometry() const;
  size_t memory_bytes() const;

  // Layout: z fastest, then x, then y: a column (ix, iy) is nz contiguous votes.
  size_t ColumnIndex(int ix, int iy) const { return static_cast<size_t>(iy) * nx_ + ix; }
  Vote vote(int ix, int iy, int iz) const { return votes_[ColumnIndex(ix, iy) * nz_ + iz]; }
  const Vote* column(int ix, int iy) const { return votes_ + ColumnIndex(ix, iy) * nz_; }
  Vote* mutable_column(size_t column_index) { return votes_ + column_index * nz_; }

  // Lowest and highest z index that ever got a hit in a column (lo > hi: none). Only those can
  // hold a positive vote, so extraction reads nothing else.
  uint16_t hit_lo(size_t column_index) const { return hit_lo_[column_index]; }
  uint16_t hit_hi(size_t column_index) const { return hit_hi_[column_index]; }
  uint16_t* mutable_hit_lo() { return hit_lo_; }
  uint16_t* mutable_hit_hi() { return hit_hi_; }

  // Resets every vote to 0.
  void Clear();

 private:
  GridOptions options_;
  int nx_ = 0, ny_ = 0, nz_ = 0;
  Vote* votes_ = nullptr;       // nx*ny*nz, mapped: untouched pages cost no memory
  uint16_t* hit_lo_ = nullptr;  // nx*ny
  uint16_t* hit_hi_ = nullptr;  // nx*ny
};

// The fused height map: CV_32F, ny rows x nx columns, world z (m) of the winning voxel centre,
// NaN where no voxel of the column has a positive vote. Winner: highest vote, ties the higher z.
// Callable at any time between insertions. `isa` (cpu_features.h): the instruction set of the
// search in each column, the same map with every one (tests compare them with the reference);
// kAuto takes 16 lanes (AVX2) where the CPU has them, else 8 (SSE2), else scalar. There is no
// AVX-512 search (the latency of the grid's memory, not the search, bounds extraction): asking
// for it, or for an instruction set the CPU lacks, throws InputError. `threads` (>= 1) extract
// bands of rows at once: the same map at any count (each column is read one after the other, so
// the memory's latency bounds one thread).
cv::Mat ExtractHeightMap(const VotingGrid& grid, Isa isa = Isa::kAuto, int threads = 1);

// The completeness of the height map (the share of its cells with a value) frame after frame,
// without extracting it: after each insertion, Update(FrameInserter::changed_columns()) looks
// again only at the columns that frame could change, and only at whether each holds a positive
// vote (searched from its highest hit down). The grid must outlive the tracker and start empty.
class CompletenessTracker {
 public:
  explicit CompletenessTracker(const VotingGrid& grid);
  // `changed_columns` (x = ix, y = iy) within the grid; returns the completeness now.
  double Update(const cv::Rect& changed_columns);

 private:
  const VotingGrid& grid_;
  std::vector<uint8_t> filled_;  // per column: has a positive vote
  size_t filled_count_ = 0;
};

}  // namespace romunect::fusion
