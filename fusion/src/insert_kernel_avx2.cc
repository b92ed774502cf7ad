// The insertion walk on AVX2: a block is 16 votes, one 32-byte register, and the rays that go
// down walk four at a time in double lanes. Compiled for AVX2 under a pragma, not a build flag,
// and called only where the CPU reports it (frame_inserter.cc). Standard headers and
// insert_kernel.h come before the pragma so that their inline functions stay baseline code.
//
// Why lanes: one ray's walk is a chain of dependent steps (the next crossing decides the axis,
// which decides the next crossing), about 20 cycles each; four independent rays fill the core.
// Each lane evaluates the exact double expressions of WalkRayT<-1, kAllRows> (ray_walk.inc:
// crossing times, the z at a column's exit, its floor and the near-plane test; no FMA, so every
// lane rounds as the scalar code does) and steps x or y by a blend instead of a branch. A lane
// whose ray ends takes the next ray at once. Votes are applied as they are found: a frame's misses
// commute (voting_grid.h), so interleaving rays changes nothing. Rare cases go to the scalar code:
// a lane near a z plane (SettleLastZ), a run that does not fit one block, a ray's last column.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "insert_kernel.h"

#if ROMUNECT_FUSION_KERNEL_AVX2
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2")

namespace romunect::fusion::insert_internal {
namespace {

// The block operations of ray_walk.inc (insert_kernel_sse2.cc), on 16 votes.
using Block = __m256i;
inline Block LoadBlock(const Vote* p) { return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)); }
inline void StoreBlock(Vote* p, Block v) { _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), v); }
inline Block AndBlocks(Block a, Block b) { return _mm256_and_si256(a, b); }
inline Block AddMiss(Block v, Block mask) {
  return _mm256_max_epi16(_mm256_add_epi16(v, mask), _mm256_set1_epi16(kVoteMin));
}
#include "ray_walk.inc"
static_assert(kLanes == kAvx2BlockVotes);

// Lane masks of the 16 subsets of four lanes (bit l: lane l).
struct LaneSubsets {
  alignas(32) int64_t mask[16][4];
  constexpr LaneSubsets() : mask() {
    for (int m = 0; m < 16; ++m) {
      for (int l = 0; l < 4; ++l) mask[m][l] = (m >> l & 1) ? -1 : 0;
    }
  }
};
constexpr LaneSubsets kLaneSubsets;

// The lanes' walk state, in memory while lanes are refilled (the loop keeps it in registers).
struct alignas(32) LaneState {
  double tx[4], ty[4], px[4], py[4], sx[4], sy[4], inv_x[4], inv_y[4], dz[4], t_exit[4], iz[4], x_stop[4], y_stop[4],
      by[4];
  int64_t col[4], step_x[4], step_y[4];
  double inv_z[4];
  int bx[4];
  const RaySetup* ray[4];
};

// Lane l takes ray `ray` (going down): the start of WalkRayT<-1, kAllRows>.
template <bool kAllRows>
inline void StartLane(const RaySetup& ray, const WalkContext& c, int l, LaneState* s) {
  const WalkStart w = StartWalk(ray, c.ox, c.oy, c.oz, c.nx, c.ny, c.nz);
  const int sx = w.sx, sy = w.sy, ix0 = w.ix0, iy0 = w.iy0;
  s->inv_x[l] = w.inv_x;
  s->inv_y[l] = w.inv_y;
  s->inv_z[l] = w.inv_z;
  s->dz[l] = w.dz;
  s->iz[l] = w.iz0;
  s->bx[l] = sx > 0;
  s->by[l] = sy > 0;
  s->px[l] = w.plane_x;
  s->py[l] = w.plane_y;
  s->sx[l] = sx;
  s->sy[l] = sy;
  s->tx[l] = w.tx;
  s->ty[l] = w.ty;
  s->t_exit[l] = ray.t_exit;
  s->x_stop[l] = sx > 0 ? c.nx + 1 : -1;
  s->y_stop[l] = sy > 0 ? (kAllRows ? c.ny : c.yb) + 1 : (kAllRows ? -1 : c.ya - 1);
  s->col[l] = (static_cast<int64_t>(iy0) * c.nx + ix0) * c.nz;
  s->step_x[l] = static_cast<int64_t>(sx) * c.nz;
  s->step_y[l] = static_cast<int64_t>(sy) * c.nx * c.nz;
  s->ray[l] = &ray;
}

// Lane l without a ray: it stays in its column forever (no crossing, no exit, no stop plane)
// and its votes are masked off.
inline void IdleLane(int l, LaneState* s) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  s->tx[l] = s->ty[l] = s->px[l] = s->py[l] = s->sx[l] = s->sy[l] = s->inv_x[l] = s->inv_y[l] = s->dz[l] = 0.0;
  s->iz[l] = 0.0;
  s->t_exit[l] = kInf;
  s->x_stop[l] = s->y_stop[l] = nan;
  s->by[l] = 0.0;
  s->col[l] = s->step_x[l] = s->step_y[l] = 0;
  s->ray[l] = nullptr;
}

// The rays the lanes take, in order, and the lanes that hold one (`active`, bit l: lane l).
template <bool kAllRows>
struct LaneFeed {
  const RaySetup* rays;
  size_t count;
  WalkContext* c;
  size_t next = 0;
  int active = 0;

  // Lane l takes the next ray that goes down (walking the others on the way); idle when none.
  void Refill(int l, LaneState* s) {
    while (next < count) {
      const RaySetup& ray = rays[next++];
      if (!kAllRows && !MayTouchRows(ray, *c)) continue;
      if (ray.p_g[2] < c->oz) {
        StartLane<kAllRows>(ray, *c, l, s);
        active |= 1 << l;
        return;
      }
      WalkRay<kAllRows>(ray, c);
    }
    IdleLane(l, s);
    active &= ~(1 << l);
  }
};

// The sum of the four lanes' counts (whole numbers held as doubles).
inline size_t SumLanes(__m256d counts) {
  alignas(32) double a[4];
  _mm256_store_pd(a, counts);
  size_t sum = 0;
  for (int l = 0; l < 4; ++l) sum += static_cast<size_t>(a[l]);
  return sum;
}

// Lane l at its segment's last column: the column's misses and the hit (ApplyLastColumn), where
// the column is in the thread's rows.
template <bool kAllRows>
inline void FinishLane(const LaneState& s, int l, WalkContext* c) {
  const double row = s.py[l] - s.by[l];
  if (!kAllRows && !(row >= c->ya && row < c->yb)) return;
  const size_t column = static_cast<size_t>(row) * c->nx + static_cast<size_t>(s.px[l] - s.bx[l]);
  ApplyLastColumn<-1>(*s.ray[l], column, static_cast<int>(s.iz[l]), c->oz, s.dz[l], s.inv_z[l], c);
}

// The last z voxel of the lanes `settle`, near a z plane, by SettleLastZ; the others keep `last`.
inline __m256d SettleLanes(int settle, __m256d last, __m256d t_column, __m256d iz, const LaneState& s,
                           const WalkContext& c) {
  alignas(32) double a_t[4], a_last[4], a_iz[4];
  _mm256_store_pd(a_t, t_column);
  _mm256_store_pd(a_last, last);
  _mm256_store_pd(a_iz, iz);
  for (int m = settle; m != 0; m &= m - 1) {
    const int l = __builtin_ctz(m);
    a_last[l] = SettleLastZ<-1>(static_cast<int>(a_last[l]), static_cast<int>(a_iz[l]), c.nz, c.oz, s.inv_z[l], a_t[l]);
  }
  return _mm256_load_pd(a_last);
}

// Misses [last, iz] of the lanes `long_runs`, whose runs do not fit one block, by ApplyMisses
// (col: each lane's column, as the index of its first vote).
inline void ApplyLongRuns(int long_runs, __m256d last, __m256d iz, __m256i col, WalkContext* c) {
  alignas(32) double a_last[4], a_iz[4];
  alignas(32) int64_t a_col[4];
  _mm256_store_pd(a_last, last);
  _mm256_store_pd(a_iz, iz);
  _mm256_store_si256(reinterpret_cast<__m256i*>(a_col), col);
  for (int m = long_runs; m != 0; m &= m - 1) {
    const int l = __builtin_ctz(m);
    ApplyMisses(c->votes + a_col[l], static_cast<int>(a_last[l]), static_cast<int>(a_iz[l]) + 1, c);
  }
}

// One block of misses per lane: the block's address and its offset in the lane mask table.
inline void ApplyMissBlocks(__m256i block, __m256i mask) {
  alignas(32) int64_t a_block[4], a_mask[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(a_block), block);
  _mm256_store_si256(reinterpret_cast<__m256i*>(a_mask), mask);
  for (int l = 0; l < 4; ++l) ApplyMissBlock(reinterpret_cast<Vote*>(a_block[l]), a_mask[l]);
}

// Walks rays [0, count) that may touch the thread's rows: those going down in lanes, the others
// with WalkRay. Requires nz >= kLanes.
template <bool kAllRows>
inline void WalkRaysInLanesT(const RaySetup* rays, size_t count, WalkContext* c) {
  const int nz = c->nz;
  alignas(32) Vote scratch[kLanes] = {};  // the block of lanes without a run: no lane changes
  LaneState s;
  LaneFeed<kAllRows> feed{rays, count, c};
  for (int l = 0; l < 4; ++l) feed.Refill(l, &s);

  const __m256d ox = _mm256_set1_pd(c->ox), oy = _mm256_set1_pd(c->oy), oz = _mm256_set1_pd(c->oz);
  const __m256d half = _mm256_set1_pd(0.5), near = _mm256_set1_pd(0.5 - kNearPlane);
  const __m256d sign_bit = _mm256_set1_pd(-0.0), zero = _mm256_setzero_pd(), one = _mm256_set1_pd(1.0);
  const __m256d lanes = _mm256_set1_pd(kLanes), first_lanes = _mm256_set1_pd(kFirstLanes);
  const __m256d top = _mm256_set1_pd(nz - kLanes);  // the last block start inside a column
  const __m256d row_a = _mm256_set1_pd(c->ya), row_b = _mm256_set1_pd(c->yb);
  const __m256i votes = _mm256_set1_epi64x(reinterpret_cast<int64_t>(c->votes));
  const __m256i no_block = _mm256_set1_epi64x(reinterpret_cast<int64_t>(scratch));
  const __m256i no_lanes = _mm256_set1_epi64x(kFirstLanes);
  __m256d sx, sy, inv_x, inv_y, dz, t_exit, x_stop, y_stop, by, tx, ty, px, py, iz, alive;
  __m256i step_x, step_y, col;
  auto load = [&] {
    sx = _mm256_load_pd(s.sx);
    sy = _mm256_load_pd(s.sy);
    inv_x = _mm256_load_pd(s.inv_x);
    inv_y = _mm256_load_pd(s.inv_y);
    dz = _mm256_load_pd(s.dz);
    t_exit = _mm256_load_pd(s.t_exit);
    x_stop = _mm256_load_pd(s.x_stop);
    y_stop = _mm256_load_pd(s.y_stop);
    by = _mm256_load_pd(s.by);
    tx = _mm256_load_pd(s.tx);
    ty = _mm256_load_pd(s.ty);
    px = _mm256_load_pd(s.px);
    py = _mm256_load_pd(s.py);
    iz = _mm256_load_pd(s.iz);
    step_x = _mm256_load_si256(reinterpret_cast<const __m256i*>(s.step_x));
    step_y = _mm256_load_si256(reinterpret_cast<const __m256i*>(s.step_y));
    col = _mm256_load_si256(reinterpret_cast<const __m256i*>(s.col));
    alive = _mm256_castsi256_pd(_mm256_load_si256(reinterpret_cast<const __m256i*>(kLaneSubsets.mask[feed.active])));
  };
  // The state the scalar code reads or changes (the rest is constant per ray).
  auto store = [&] {
    _mm256_store_pd(s.tx, tx);
    _mm256_store_pd(s.ty, ty);
    _mm256_store_pd(s.px, px);
    _mm256_store_pd(s.py, py);
    _mm256_store_pd(s.iz, iz);
    _mm256_store_si256(reinterpret_cast<__m256i*>(s.col), col);
  };
  load();
  __m256d run_misses = zero;
  while (feed.active != 0) {
    const __m256d t_column = _mm256_min_pd(tx, ty);
    const int stay = _mm256_movemask_pd(_mm256_cmp_pd(t_column, t_exit, _CMP_LT_OQ));
    if (stay != 0xF) [[unlikely]] {
      // Lanes at their segment's last column (idle lanes stay): finish them, take new rays.
      store();
      for (int done = ~stay & 0xF; done != 0; done &= done - 1) {
        const int l = __builtin_ctz(done);
        FinishLane<kAllRows>(s, l, c);
        feed.Refill(l, &s);
      }
      load();
      continue;
    }
    // The last z voxel of each lane's column (LastZ<-1>).
    const __m256d z = _mm256_add_pd(oz, _mm256_mul_pd(t_column, dz));
    const __m256d z_floor = _mm256_round_pd(z, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
    __m256d last = _mm256_max_pd(_mm256_min_pd(z_floor, iz), zero);
    const __m256d off = _mm256_andnot_pd(sign_bit, _mm256_sub_pd(_mm256_sub_pd(z, z_floor), half));
    const int settle = _mm256_movemask_pd(_mm256_and_pd(_mm256_cmp_pd(off, near, _CMP_GT_OQ), alive));
    if (settle != 0) [[unlikely]]
      last = SettleLanes(settle, last, t_column, iz, s, *c);
    // Misses [last, iz] of the column, in the lanes with a ray in the thread's rows: one block
    // from `last` where they fit in it (almost always), else ApplyMisses.
    __m256d use = alive;
    if constexpr (!kAllRows) {
      const __m256d row = _mm256_sub_pd(py, by);
      use = _mm256_and_pd(use,
                          _mm256_and_pd(_mm256_cmp_pd(row, row_a, _CMP_GE_OQ), _mm256_cmp_pd(row, row_b, _CMP_LT_OQ)));
    }
    const __m256d run = _mm256_sub_pd(_mm256_add_pd(iz, one), last);
    const __m256d fits = _mm256_and_pd(_mm256_cmp_pd(run, lanes, _CMP_LE_OQ), _mm256_cmp_pd(last, top, _CMP_LE_OQ));
    const int other = _mm256_movemask_pd(_mm256_andnot_pd(fits, use));
    if (other != 0) [[unlikely]]
      ApplyLongRuns(other, last, iz, col, c);
    const __m256d block_lanes = _mm256_and_pd(fits, use);
    run_misses = _mm256_add_pd(run_misses, _mm256_and_pd(run, block_lanes));
    const __m256i first = _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(last));
    const __m256i block = _mm256_add_epi64(votes, _mm256_slli_epi64(_mm256_add_epi64(col, first), 1));
    const __m256i mask = _mm256_cvtepi32_epi64(_mm256_cvttpd_epi32(_mm256_sub_pd(first_lanes, run)));
    const __m256i apply = _mm256_castpd_si256(block_lanes);
    ApplyMissBlocks(_mm256_blendv_epi8(no_block, block, apply), _mm256_blendv_epi8(no_lanes, mask, apply));
    iz = last;
    // Step x where tx <= ty (ties: x first), else y.
    const __m256d step_is_x = _mm256_cmp_pd(tx, ty, _CMP_LE_OQ);
    px = _mm256_add_pd(px, _mm256_and_pd(step_is_x, sx));
    py = _mm256_add_pd(py, _mm256_andnot_pd(step_is_x, sy));
    col = _mm256_add_epi64(col, _mm256_castpd_si256(_mm256_blendv_pd(_mm256_castsi256_pd(step_y),
                                                                     _mm256_castsi256_pd(step_x), step_is_x)));
    tx = _mm256_blendv_pd(tx, _mm256_mul_pd(_mm256_sub_pd(px, ox), inv_x), step_is_x);
    ty = _mm256_blendv_pd(_mm256_mul_pd(_mm256_sub_pd(py, oy), inv_y), ty, step_is_x);
    const int out = _mm256_movemask_pd(
        _mm256_or_pd(_mm256_cmp_pd(px, x_stop, _CMP_EQ_OQ), _mm256_cmp_pd(py, y_stop, _CMP_EQ_OQ)));
    if (out != 0) [[unlikely]] {
      // Lanes that left the grid (or the thread's rows) have no last column: new rays.
      store();
      for (int m = out; m != 0; m &= m - 1) feed.Refill(__builtin_ctz(m), &s);
      load();
    }
  }
  c->misses += SumLanes(run_misses);
}

}  // namespace

// WalkRays with the rays that go down walked four at a time in lanes.
void WalkRaysAvx2(const RaySetup* rays, size_t count, WalkContext* c) {
  if (c->ya == 0 && c->yb == c->ny) {
    WalkRaysInLanesT<true>(rays, count, c);
  } else {
    WalkRaysInLanesT<false>(rays, count, c);
  }
}

}  // namespace romunect::fusion::insert_internal

#pragma GCC pop_options
#endif  // ROMUNECT_FUSION_KERNEL_AVX2
