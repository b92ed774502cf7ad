// The insertion kernels (private to fusion/src): the column walk of frame_inserter.h, one
// translation unit per instruction set, insert_kernel_{scalar,sse2,avx2,avx512}.cc, each compiled
// under `#pragma GCC target` where it needs more than the x86-64 baseline and called only where the
// CPU reports it (frame_inserter.cc lists them in its dispatch table). The walk's own code is
// ray_walk.inc, included by every unit into its anonymous namespace after that unit's vote-block
// operations.
//
// This header holds what frame_inserter.cc and the kernels share: plain structs, constants and
// declarations. Every unit includes it before its pragma, so its few inline functions are
// baseline code in all of them (no inline function is shared between units compiled for different
// instruction sets). docs/design.md, "SIMD kernels".
#pragma once

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include <opencv2/core.hpp>

#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/voting_grid.h"

namespace romunect::fusion::insert_internal {

inline constexpr Vote kVoteMax = std::numeric_limits<Vote>::max();
inline constexpr Vote kVoteMin = -kVoteMax;  // symmetric saturation

// The side of the square pixel tiles in which a frame's rays are cast: neighbouring rays cross
// the same columns, so a tile's columns stay in cache (pixel-row order revisits a column only
// 640 rays later). Not part of the semantics (voting_grid.h: the order of rays does not matter).
inline constexpr int kInsertionTilePx = 32;

// Votes per block of each walk: a column shorter than a kernel's block takes a narrower one.
inline constexpr int kSse2BlockVotes = 8;
inline constexpr int kAvx2BlockVotes = 16;
inline constexpr int kAvx512BlockVotes = 32;

// One cast ray of the kernels without a lane setup: set up once per frame (phase 1) and walked
// by every slab owner (phase 2); also the scalar fallbacks' form of a lane's ray.
struct RaySetup {
  double p_g[3];           // measured point, grid units
  double t_enter, t_exit;  // the segment's part inside the box
  int32_t iy_lo, iy_hi;    // rows the walk may visit (conservative, for slab skipping)
  bool ends_inside;        // the point is in the grid: the last voxel gets a hit
};

// A ray's hit, kept until the frame's misses are applied (voting_grid.h): the column's index and
// the voxel's z.
struct HitRecord {
  uint32_t column;
  uint16_t z;
};
static_assert(sizeof(HitRecord) == 8, "the AVX-512 walk stores hits as column | z << 32");

// Slots past a thread's hits that the AVX-512 walk may write and then overwrite: it stores eight
// compressed hits at once. A compress straight into memory takes ~15 ns on Zen 4 even with an
// empty mask, one into a register and a plain store ~1.4 ns.
inline constexpr size_t kHitSlack = 8;

// One thread's walk: the frame's camera centre, the grid, the rows it owns and where its hits go.
struct WalkContext {
  double ox, oy, oz;  // camera centre, grid units
  int nx, ny, nz;
  int ya, yb;  // this thread's rows [ya, yb)
  Vote* votes;
  HitRecord* hits;  // this thread's hits (in its rows): room for one per pixel, plus kHitSlack
  size_t hit_count;
  size_t misses;
};

// A frame's constants: the camera's pose and per-pixel rays, the grid. The setup of
// frame_inserter.cc and the lane setup of the AVX-512 kernel evaluate the same expressions on them.
struct SetupFrame {
  double R[3][3], o_W[3], min_W[3], o_g[3], voxel;
  int n[3];
  const double* ray_C;  // x, y per pixel (z = 1)
  int width;
};

// The (x, y) range, in grid units, of the segments a thread set up in a frame: the columns whose
// votes the frame may change lie within it (FrameInserter::changed_columns()).
struct SegmentBounds {
  double x_lo = std::numeric_limits<double>::infinity(), x_hi = -std::numeric_limits<double>::infinity();
  double y_lo = std::numeric_limits<double>::infinity(), y_hi = -std::numeric_limits<double>::infinity();
  void Add(double xa, double xb, double ya, double yb) {
    x_lo = std::min({x_lo, xa, xb});
    x_hi = std::max({x_hi, xa, xb});
    y_lo = std::min({y_lo, ya, yb});
    y_hi = std::max({y_hi, ya, yb});
  }
  // The union with another range, which may be empty (lo > hi).
  void Merge(const SegmentBounds& o) {
    x_lo = std::min(x_lo, o.x_lo);
    x_hi = std::max(x_hi, o.x_hi);
    y_lo = std::min(y_lo, o.y_lo);
    y_hi = std::max(y_hi, o.y_hi);
  }
};

// The start voxel on one axis: clamp(floor(x)) into [0, n).
inline int StartIndex(double x, int n) { return static_cast<int>(std::clamp(std::floor(x), 0.0, n - 1.0)); }

// The start of a ray's column walk, the same expressions for every kernel: the segment's
// direction (dz) and inverse per axis, the start voxel, the step signs, and per axis in (x, y)
// the first crossing plane (voxel index + 1 going up) and its time (inf without motion).
struct WalkStart {
  double dz, inv_x, inv_y, inv_z, tx, ty;
  int ix0, iy0, iz0, sx, sy, plane_x, plane_y;
};
inline WalkStart StartWalk(const RaySetup& ray, double ox, double oy, double oz, int nx, int ny, int nz) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  WalkStart w;
  const double dx = ray.p_g[0] - ox, dy = ray.p_g[1] - oy;
  w.dz = ray.p_g[2] - oz;
  w.inv_x = 1.0 / dx;
  w.inv_y = 1.0 / dy;
  w.inv_z = 1.0 / w.dz;
  w.ix0 = StartIndex(ox + ray.t_enter * dx, nx);
  w.iy0 = StartIndex(oy + ray.t_enter * dy, ny);
  w.iz0 = StartIndex(oz + ray.t_enter * w.dz, nz);
  w.sx = dx > 0.0 ? 1 : (dx < 0.0 ? -1 : 0);
  w.sy = dy > 0.0 ? 1 : (dy < 0.0 ? -1 : 0);
  w.plane_x = w.ix0 + (dx > 0.0);
  w.plane_y = w.iy0 + (dy > 0.0);
  w.tx = w.sx != 0 ? (static_cast<double>(w.plane_x) - ox) * w.inv_x : kInf;
  w.ty = w.sy != 0 ? (static_cast<double>(w.plane_y) - oy) * w.inv_y : kInf;
  return w;
}

// Lane masks for runs of misses: loading a block at mask + kLanes - a gives -1 in lanes >= a, at
// mask + 2 kLanes - b gives -1 in lanes < b; their AND selects the lanes [a, b) of a block, the
// second alone the first b lanes, and a load at b the last b lanes.
template <int kLanes>
struct LaneMaskTable {
  int16_t mask[3 * kLanes];
  constexpr LaneMaskTable() : mask() {
    for (int i = kLanes; i < 2 * kLanes; ++i) mask[i] = -1;
  }
};

// Rays per group of the AVX-512 lane setup (eight double lanes).
inline constexpr int kLaneGroup = 8;

// The AVX-512 kernel's buffer for one tile (one per thread): the rays of the tile that enter the
// box going down, set up eight at a time, as structure of arrays: each ray's StartWalk, its
// t_exit and column.
struct alignas(64) TileRays {
  static constexpr int kSlots = kInsertionTilePx * kInsertionTilePx + kLaneGroup;
  // The tile's valid pixels (index into the ray table) and depths, padded; the kernel stores
  // them 16 at a time from before the last one kept, so within the tile's pixels.
  int32_t pixel[kSlots];
  float depth[kSlots];
  double tx[kSlots], ty[kSlots], px[kSlots], py[kSlots], sx[kSlots], sy[kSlots], inv_x[kSlots], inv_y[kSlots],
      dz[kSlots], t_exit[kSlots], iz[kSlots], inv_z[kSlots];
  int64_t column[kSlots], ends_inside[kSlots];
};

// Walks rays [0, count), those that may touch the context's rows, applying their misses and
// keeping their hits. Needs nz of at least the kernel's block.
using WalkRaysFn = void (*)(const RaySetup* rays, size_t count, WalkContext* c);
void WalkRaysScalar(const RaySetup* rays, size_t count, WalkContext* c);
void WalkRaysSse2(const RaySetup* rays, size_t count, WalkContext* c);
void WalkRaysAvx2(const RaySetup* rays, size_t count, WalkContext* c);  // four rays at once in lanes

// One thread's part of a frame with the lane setup: every tile of depth_m set up in lanes and
// walked where it may touch the context's rows, tile after tile. Counts into *counts, widens
// *bounds, counts rays per row into `weight` (ny counters; may be null). Needs nz >= 32.
using InsertSlabFn = void (*)(const SetupFrame& f, const cv::Mat& depth_m, TileRays* tile, WalkContext* c,
                              InsertStats* counts, SegmentBounds* bounds, uint32_t* weight);
void InsertSlabAvx512(const SetupFrame& f, const cv::Mat& depth_m, TileRays* tile, WalkContext* c, InsertStats* counts,
                      SegmentBounds* bounds, uint32_t* weight);

// One entry of the inserter's dispatch table (frame_inserter.cc, ResolveKernel): the walk of set-up
// rays, the slab insertion with a lane setup (null: none), and the shortest column, in votes, that
// both need (one block). A shorter column takes the widest narrower entry whose block fits.
struct Kernel {
  Isa isa;
  WalkRaysFn walk_rays;
  InsertSlabFn insert_slab;
  int min_nz;
};

}  // namespace romunect::fusion::insert_internal

#if defined(__SSE2__)
#define ROMUNECT_FUSION_KERNEL_SSE2 1
#endif
// AVX2 and AVX-512 code is compiled under `#pragma GCC target` and runs only where the CPU
// reports the instruction set.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROMUNECT_FUSION_KERNEL_AVX2 1
#define ROMUNECT_FUSION_KERNEL_AVX512 1
#endif
