// The insertion kernel on AVX-512 (F, BW, DQ): a block is 32 votes, one 64-byte register, and
// each thread sets a frame's rays up itself, eight at a time in double lanes, tile by tile, and
// walks the rays that go down eight at a time. Compiled for AVX-512 under a pragma, not a build
// flag, and called only where the CPU reports it (frame_inserter.cc). Standard headers, OpenCV and
// insert_kernel.h come before the pragma so that their inline functions stay baseline code.
//
// Why lanes: one ray's walk is a chain of dependent steps (the next crossing decides the axis,
// which decides the next crossing), about 20 cycles each; eight independent rays fill the core.
// Each lane evaluates the exact double expressions of WalkRayT<-1, kAllRows> (ray_walk.inc:
// crossing times, the z at a column's exit, its floor and the near-plane test; no FMA, so every
// lane rounds as the scalar code does) and steps x or y under a mask instead of a branch. A group
// of eight neighbouring rays (their walks are about as long) runs until its last ray ends; a ray's
// last column is a column like the others, at t_exit, with its hit stored by compression into the
// thread's hit list. Votes are applied as they are found, a masked 32-vote block per lane and
// column (masked lanes are neither read nor written, so a block may reach past its column): a
// frame's misses commute (voting_grid.h), so interleaving rays changes nothing. Rare cases go to
// the scalar code: a lane near a z plane (SettleLastZ), a run longer than one block.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include <opencv2/core.hpp>

#include "insert_kernel.h"

#if ROMUNECT_FUSION_KERNEL_AVX512
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2,avx512f,avx512bw,avx512dq")
// GCC 12 warns inside its own AVX-512 headers (their _mm512_undefined_* placeholders).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"

namespace romunect::fusion::insert_internal {
namespace {

// The block operations of ray_walk.inc (insert_kernel_sse2.cc), on 32 votes.
using Block = __m512i;
inline Block LoadBlock(const Vote* p) { return _mm512_loadu_si512(p); }
inline void StoreBlock(Vote* p, Block v) { _mm512_storeu_si512(p, v); }
inline Block AndBlocks(Block a, Block b) { return _mm512_and_si512(a, b); }
inline Block AddMiss(Block v, Block mask) {
  return _mm512_max_epi16(_mm512_add_epi16(v, mask), _mm512_set1_epi16(kVoteMin));
}
#include "ray_walk.inc"
static_assert(kLanes == kAvx512BlockVotes);

constexpr int kGroupLanes = kLaneGroup;
constexpr int kBlockVotes = kAvx512BlockVotes;  // votes in one masked block

// One group's per-lane start: the start of WalkRayT<-1, kAllRows> for each ray (StartWalk).
struct alignas(64) LaneGroup {
  double tx[8], ty[8], px[8], py[8], sx[8], sy[8], inv_x[8], inv_y[8], dz[8], t_exit[8], iz[8];
  int64_t column[8];
  double inv_z[8];
  uint8_t ends_inside = 0;  // lane bits
};

// Walks the lanes `lanes` of a group of rays going down, applying each step's misses (a masked
// block per lane; an empty mask touches no memory) as it goes.
template <bool kAllRows>
inline void WalkGroup(const LaneGroup& g, __mmask8 lanes, WalkContext* c) {
  const int nz = c->nz;
  const __m512d ox = _mm512_set1_pd(c->ox), oy = _mm512_set1_pd(c->oy), oz = _mm512_set1_pd(c->oz);
  const __m512d half = _mm512_set1_pd(0.5), near = _mm512_set1_pd(0.5 - kNearPlane);
  const __m512d zero = _mm512_setzero_pd(), one = _mm512_set1_pd(1.0);
  const __m512d block_votes = _mm512_set1_pd(kBlockVotes);
  const __m512d row_a = _mm512_set1_pd(c->ya), row_b = _mm512_set1_pd(c->yb);
  const __m512i votes = _mm512_set1_epi64(reinterpret_cast<int64_t>(c->votes));
  const __m512i one64 = _mm512_set1_epi64(1);
  const __m512i nz64 = _mm512_set1_epi64(nz);
  const __m512d sx = _mm512_load_pd(g.sx), sy = _mm512_load_pd(g.sy);
  const __m512d inv_x = _mm512_load_pd(g.inv_x), inv_y = _mm512_load_pd(g.inv_y), dz = _mm512_load_pd(g.dz);
  const __m512d t_exit = _mm512_load_pd(g.t_exit);
  // Stop planes (WalkRayT's x_stop, y_stop) and steps of the column index and the vote offset.
  const __mmask8 x_up = _mm512_cmp_pd_mask(sx, zero, _CMP_GT_OQ), y_up = _mm512_cmp_pd_mask(sy, zero, _CMP_GT_OQ);
  const __m512d x_stop = _mm512_mask_blend_pd(x_up, _mm512_set1_pd(-1.0), _mm512_set1_pd(c->nx + 1.0));
  const __m512d y_stop = _mm512_mask_blend_pd(y_up, _mm512_set1_pd(kAllRows ? -1.0 : c->ya - 1.0),
                                              _mm512_set1_pd((kAllRows ? c->ny : c->yb) + 1.0));
  const __m512d by = _mm512_mask_blend_pd(y_up, zero, one);
  const __m512i step_x = _mm512_cvttpd_epi64(sx);
  const __m512i step_y = _mm512_mullo_epi64(_mm512_cvttpd_epi64(sy), _mm512_set1_epi64(c->nx));
  const __m512i offset_step_x = _mm512_mullo_epi64(step_x, nz64), offset_step_y = _mm512_mullo_epi64(step_y, nz64);
  __m512d tx = _mm512_load_pd(g.tx), ty = _mm512_load_pd(g.ty);
  __m512d px = _mm512_load_pd(g.px), py = _mm512_load_pd(g.py);
  __m512d iz = _mm512_load_pd(g.iz);
  __m512i column = _mm512_load_si512(g.column);
  __m512i offset = _mm512_mullo_epi64(column, nz64);  // of the column's first vote
  __m512i misses = _mm512_setzero_si512();
  __mmask8 alive = lanes;
  const __mmask8 ends_inside = g.ends_inside;
  const __m512i vote_min = _mm512_set1_epi16(kVoteMin), vote_one = _mm512_set1_epi16(1);
  alignas(64) Vote idle[kGroupLanes][kBlockVotes];  // never read or written: empty masks only
  const __m512i idle_lines = _mm512_add_epi64(_mm512_set1_epi64(reinterpret_cast<int64_t>(&idle[0][0])),
                                              _mm512_set_epi64(448, 384, 320, 256, 192, 128, 64, 0));
  while (alive != 0) {
    // This column ends at the next crossing, or at t_exit for lanes at their last column.
    const __m512d t_next = _mm512_min_pd(tx, ty);
    const __mmask8 last_column = alive & ~_mm512_mask_cmp_pd_mask(alive, t_next, t_exit, _CMP_LT_OQ);
    const __m512d t_column = _mm512_mask_blend_pd(last_column, t_next, t_exit);
    // The column's last z voxel (LastZ<-1>).
    const __m512d z = _mm512_add_pd(oz, _mm512_mul_pd(t_column, dz));
    const __m512d z_floor = _mm512_roundscale_pd(z, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
    __m512d last = _mm512_max_pd(_mm512_min_pd(z_floor, iz), zero);
    const __m512d off = _mm512_abs_pd(_mm512_sub_pd(_mm512_sub_pd(z, z_floor), half));
    const __mmask8 settle = _mm512_mask_cmp_pd_mask(alive, off, near, _CMP_GT_OQ);
    if (settle != 0) [[unlikely]] {
      alignas(64) double a_t[8], a_last[8], a_iz[8];
      _mm512_store_pd(a_t, t_column);
      _mm512_store_pd(a_last, last);
      _mm512_store_pd(a_iz, iz);
      for (unsigned m = settle; m != 0; m &= m - 1) {
        const int l = __builtin_ctz(m);
        a_last[l] = SettleLastZ<-1>(static_cast<int>(a_last[l]), static_cast<int>(a_iz[l]), nz, c->oz, g.inv_z[l],
                                    a_t[l]);
      }
      last = _mm512_load_pd(a_last);
    }
    __mmask8 owned = alive;
    if constexpr (!kAllRows) {
      const __m512d row = _mm512_sub_pd(py, by);
      owned = _mm512_mask_cmp_pd_mask(_mm512_mask_cmp_pd_mask(alive, row, row_a, _CMP_GE_OQ), row, row_b, _CMP_LT_OQ);
    }
    // Misses [lo, iz] with lo = last, or last + 1 above a hit: a lane's last column in the grid.
    const __mmask8 hit = last_column & ends_inside & owned;
    const __m512d lo = _mm512_mask_add_pd(last, hit, last, one);
    const __m512d run = _mm512_sub_pd(_mm512_add_pd(iz, one), lo);
    const __mmask8 long_run = _mm512_mask_cmp_pd_mask(owned, run, block_votes, _CMP_GT_OQ);
    if (long_run != 0) [[unlikely]] {
      alignas(64) double a_lo[8], a_iz[8];
      alignas(64) int64_t a_offset[8];
      _mm512_store_pd(a_lo, lo);
      _mm512_store_pd(a_iz, iz);
      _mm512_store_si512(a_offset, offset);
      for (unsigned m = long_run; m != 0; m &= m - 1) {
        const int l = __builtin_ctz(m);
        ApplyMisses(c->votes + a_offset[l], static_cast<int>(a_lo[l]), static_cast<int>(a_iz[l]) + 1, c);
      }
    }
    const __mmask8 block_lanes = owned & ~long_run;
    const __m512i run64 = _mm512_cvttpd_epi64(run);
    const __m512i lo64 = _mm512_cvttpd_epi64(lo);
    misses = _mm512_mask_add_epi64(misses, block_lanes, misses, run64);
    // Lanes without a block get an empty mask on a line of their own (a lane that left the grid
    // holds a column outside it).
    alignas(64) Vote* block_at[kGroupLanes];
    alignas(32) uint32_t block_bits[kGroupLanes];
    _mm512_store_si512(block_at, _mm512_mask_add_epi64(idle_lines, block_lanes, votes,
                                                       _mm512_slli_epi64(_mm512_add_epi64(offset, lo64), 1)));
    _mm256_store_si256(reinterpret_cast<__m256i*>(block_bits),
                       _mm512_cvtepi64_epi32(
                           _mm512_maskz_sub_epi64(block_lanes, _mm512_sllv_epi64(one64, run64), one64)));
    for (int l = 0; l < kGroupLanes; ++l) {
      const __mmask32 k = block_bits[l];
      const __m512i v = _mm512_maskz_loadu_epi16(k, block_at[l]);
      _mm512_mask_storeu_epi16(block_at[l], k, _mm512_max_epi16(_mm512_sub_epi16(v, vote_one), vote_min));
    }
    // Hits for after the frame's misses: (column, z) as HitRecord's bytes; no branch (a ray's
    // last column comes at any step).
    const __m512i record = _mm512_or_si512(column, _mm512_slli_epi64(_mm512_cvttpd_epi64(last), 32));
    _mm512_storeu_si512(c->hits + c->hit_count, _mm512_maskz_compress_epi64(hit, record));  // kHitSlack
    c->hit_count += __builtin_popcount(hit);
    alive &= ~last_column;
    iz = last;
    // Step x where tx <= ty (ties: x first), else y; the other lanes keep their state.
    const __mmask8 step_is_x = _mm512_mask_cmp_pd_mask(alive, tx, ty, _CMP_LE_OQ);
    const __mmask8 step_is_y = alive & ~step_is_x;
    px = _mm512_mask_add_pd(px, step_is_x, px, sx);
    py = _mm512_mask_add_pd(py, step_is_y, py, sy);
    column = _mm512_mask_add_epi64(_mm512_mask_add_epi64(column, step_is_x, column, step_x), step_is_y, column, step_y);
    offset = _mm512_mask_add_epi64(_mm512_mask_add_epi64(offset, step_is_x, offset, offset_step_x), step_is_y, offset,
                                   offset_step_y);
    tx = _mm512_mask_mul_pd(tx, step_is_x, _mm512_sub_pd(px, ox), inv_x);
    ty = _mm512_mask_mul_pd(ty, step_is_y, _mm512_sub_pd(py, oy), inv_y);
    // Lanes that left the grid (or the thread's rows) end without a last column.
    alive &= ~(_mm512_mask_cmp_pd_mask(step_is_x, px, x_stop, _CMP_EQ_OQ) |
               _mm512_mask_cmp_pd_mask(step_is_y, py, y_stop, _CMP_EQ_OQ));
  }
  c->misses += static_cast<size_t>(_mm512_reduce_add_epi64(misses));
}

// Walks the rays of the lanes `walk` one after the other with WalkRay: their points, their
// segments' part in the box [t0, t1), and whether each point is in the grid (lane bits).
template <bool kAllRows>
inline void WalkLanes(__mmask8 walk, const __m512d p_g[3], __m512d t0, __m512d t1, __mmask8 inside, WalkContext* c) {
  alignas(64) double a_p[3][8], a_t0[8], a_t1[8];
  for (int a = 0; a < 3; ++a) _mm512_store_pd(a_p[a], p_g[a]);
  _mm512_store_pd(a_t0, t0);
  _mm512_store_pd(a_t1, t1);
  for (unsigned m = walk; m != 0; m &= m - 1) {
    const int l = __builtin_ctz(m);
    RaySetup ray{};
    for (int a = 0; a < 3; ++a) ray.p_g[a] = a_p[a][l];
    ray.t_enter = a_t0[l];
    ray.t_exit = a_t1[l];
    ray.ends_inside = (inside >> l) & 1;
    WalkRay<kAllRows>(ray, c);
  }
}

// clamp(floor(x), 0, n - 1): StartIndex in lanes (as a double; its int is the same).
inline __m512d StartIndexLanes(__m512d x, int n) {
  const __m512d floor = _mm512_roundscale_pd(x, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC);
  return _mm512_min_pd(_mm512_max_pd(floor, _mm512_setzero_pd()), _mm512_set1_pd(n - 1.0));
}

// The setup of frame_inserter.cc (SetUpRay: direction, point, clip to the box) and StartWalk's
// start state for the tile's valid pixels, eight at a time with the same double expressions in
// each lane (no FMA). Rays that enter the box going down are kept in *t (returns how many); others
// that enter are walked by WalkRay at once. Counts the rays that miss the box or end outside it,
// and widens *bounds by the segments of those that enter.
// Needs count + 8 slots of t->pixel and t->depth, the last 8 zero. Without kAllRows only the
// rays that may touch the thread's rows are walked or kept (RaySetup::iy_lo, iy_hi), and with a
// `weight` (ny counters) each entering ray counts at its middle row, as the scalar setup does.
template <bool kAllRows>
inline size_t SetUpTile(const SetupFrame& f, int count, TileRays* t, WalkContext* c, InsertStats* s,
                        SegmentBounds* bounds, uint32_t* weight) {
  const __m512d zero = _mm512_setzero_pd(), one = _mm512_set1_pd(1.0);
  const __m512d inf = _mm512_set1_pd(std::numeric_limits<double>::infinity());
  const __m512d ox = _mm512_set1_pd(f.o_g[0]), oy = _mm512_set1_pd(f.o_g[1]), oz = _mm512_set1_pd(f.o_g[2]);
  size_t kept = 0;
  __m512d x_lo = inf, x_hi = _mm512_set1_pd(-std::numeric_limits<double>::infinity()), y_lo = inf, y_hi = x_hi;
  for (int i = 0; i < count; i += kGroupLanes) {
    const __mmask8 valid = static_cast<__mmask8>((1u << std::min(kGroupLanes, count - i)) - 1);
    const __m512d d = _mm512_cvtps_pd(_mm256_loadu_ps(t->depth + i));
    const __m256i ray_index = _mm256_slli_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(t->pixel + i)), 1);
    const __m512d r[2] = {_mm512_mask_i32gather_pd(zero, valid, ray_index, f.ray_C, 8),
                          _mm512_mask_i32gather_pd(zero, valid, ray_index, f.ray_C + 1, 8)};
    __m512d p_g[3], dg[3], inv[3];
    __mmask8 inside = valid, outside_slab = 0;
    __m512d t0 = zero, t1 = one;
    for (int a = 0; a < 3; ++a) {
      const __m512d dir = _mm512_add_pd(_mm512_add_pd(_mm512_mul_pd(_mm512_set1_pd(f.R[a][0]), r[0]),
                                                      _mm512_mul_pd(_mm512_set1_pd(f.R[a][1]), r[1])),
                                        _mm512_set1_pd(f.R[a][2]));
      const __m512d p_W = _mm512_add_pd(_mm512_set1_pd(f.o_W[a]), _mm512_mul_pd(d, dir));
      p_g[a] = _mm512_div_pd(_mm512_sub_pd(p_W, _mm512_set1_pd(f.min_W[a])), _mm512_set1_pd(f.voxel));
      dg[a] = _mm512_sub_pd(p_g[a], _mm512_set1_pd(f.o_g[a]));
      inside = _mm512_mask_cmp_pd_mask(_mm512_mask_cmp_pd_mask(inside, p_g[a], zero, _CMP_GE_OQ), p_g[a],
                                       _mm512_set1_pd(f.n[a]), _CMP_LT_OQ);
      // The slab test where the segment moves along the axis; where it does not, the camera
      // centre must lie within the slab.
      const __mmask8 moves = _mm512_cmp_pd_mask(dg[a], zero, _CMP_NEQ_OQ);
      inv[a] = _mm512_div_pd(one, dg[a]);
      const __m512d ta = _mm512_mul_pd(_mm512_set1_pd(0.0 - f.o_g[a]), inv[a]);
      const __m512d tb = _mm512_mul_pd(_mm512_set1_pd(static_cast<double>(f.n[a]) - f.o_g[a]), inv[a]);
      const __mmask8 swap = _mm512_cmp_pd_mask(ta, tb, _CMP_GT_OQ);
      const __m512d lo = _mm512_mask_blend_pd(swap, ta, tb), hi = _mm512_mask_blend_pd(swap, tb, ta);
      t0 = _mm512_mask_blend_pd(_mm512_mask_cmp_pd_mask(moves, t0, lo, _CMP_LT_OQ), t0, lo);  // std::max(t0, lo)
      t1 = _mm512_mask_blend_pd(_mm512_mask_cmp_pd_mask(moves, hi, t1, _CMP_LT_OQ), t1, hi);  // std::min(t1, hi)
      if (!(f.o_g[a] >= 0.0 && f.o_g[a] < f.n[a])) outside_slab |= static_cast<__mmask8>(~moves);
    }
    const __mmask8 enters = _mm512_mask_cmp_pd_mask(valid & ~outside_slab, t0, t1, _CMP_LT_OQ);
    s->points_outside_box += __builtin_popcount(valid & ~inside);
    s->rays_missing_box += __builtin_popcount(valid & ~enters);
    // The segment's ends in (x, y): SegmentBounds::Add, and the rows it may visit.
    const __m512d x_a = _mm512_add_pd(ox, _mm512_mul_pd(t0, dg[0])), x_b = _mm512_add_pd(ox, _mm512_mul_pd(t1, dg[0]));
    const __m512d y_a = _mm512_add_pd(oy, _mm512_mul_pd(t0, dg[1])), y_b = _mm512_add_pd(oy, _mm512_mul_pd(t1, dg[1]));
    x_lo = _mm512_mask_min_pd(x_lo, enters, x_lo, _mm512_min_pd(x_a, x_b));
    x_hi = _mm512_mask_max_pd(x_hi, enters, x_hi, _mm512_max_pd(x_a, x_b));
    y_lo = _mm512_mask_min_pd(y_lo, enters, y_lo, _mm512_min_pd(y_a, y_b));
    y_hi = _mm512_mask_max_pd(y_hi, enters, y_hi, _mm512_max_pd(y_a, y_b));
    // The rows each segment may visit: floor of its lowest and highest y, widened by one, clamped.
    __mmask8 mine = enters;
    alignas(64) double row_lo[8], row_hi[8];
    if (!kAllRows || weight != nullptr) {
      const __m512d last_row = _mm512_set1_pd(f.n[1] - 1.0);
      auto clamp_row = [&](__m512d y) { return _mm512_min_pd(_mm512_max_pd(y, zero), last_row); };
      const __m512d lo = clamp_row(
          _mm512_sub_pd(_mm512_roundscale_pd(_mm512_min_pd(y_a, y_b), _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC), one));
      const __m512d hi = clamp_row(
          _mm512_add_pd(_mm512_roundscale_pd(_mm512_max_pd(y_a, y_b), _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC), one));
      _mm512_store_pd(row_lo, lo);
      _mm512_store_pd(row_hi, hi);
      if (!kAllRows) {
        mine = _mm512_mask_cmp_pd_mask(_mm512_mask_cmp_pd_mask(enters, hi, _mm512_set1_pd(c->ya), _CMP_GE_OQ), lo,
                                       _mm512_set1_pd(c->yb), _CMP_LT_OQ);
      }
      if (weight != nullptr) {
        for (unsigned m = enters; m != 0; m &= m - 1) {
          const int l = __builtin_ctz(m);
          ++weight[(static_cast<int>(row_lo[l]) + static_cast<int>(row_hi[l])) / 2];
        }
      }
    }
    const __mmask8 down = _mm512_mask_cmp_pd_mask(mine, dg[2], zero, _CMP_LT_OQ);
    if (const __mmask8 other = mine & ~down; other != 0) [[unlikely]] {
      WalkLanes<kAllRows>(other, p_g, t0, t1, inside, c);
    }
    // StartWalk's state.
    const __m512d x0 = StartIndexLanes(x_a, f.n[0]);
    const __m512d y0 = StartIndexLanes(y_a, f.n[1]);
    const __m512d z0 = StartIndexLanes(_mm512_add_pd(oz, _mm512_mul_pd(t0, dg[2])), f.n[2]);
    const __mmask8 x_up = _mm512_cmp_pd_mask(dg[0], zero, _CMP_GT_OQ),
                   x_down = _mm512_cmp_pd_mask(dg[0], zero, _CMP_LT_OQ);
    const __mmask8 y_up = _mm512_cmp_pd_mask(dg[1], zero, _CMP_GT_OQ),
                   y_down = _mm512_cmp_pd_mask(dg[1], zero, _CMP_LT_OQ);
    const __m512d sx = _mm512_mask_blend_pd(x_down, _mm512_maskz_mov_pd(x_up, one), _mm512_set1_pd(-1.0));
    const __m512d sy = _mm512_mask_blend_pd(y_down, _mm512_maskz_mov_pd(y_up, one), _mm512_set1_pd(-1.0));
    const __m512d px = _mm512_mask_add_pd(x0, x_up, x0, one), py = _mm512_mask_add_pd(y0, y_up, y0, one);
    const __m512d tx = _mm512_mask_mul_pd(inf, x_up | x_down, _mm512_sub_pd(px, ox), inv[0]);
    const __m512d ty = _mm512_mask_mul_pd(inf, y_up | y_down, _mm512_sub_pd(py, oy), inv[1]);
    const __m512i column = _mm512_add_epi64(_mm512_mullo_epi64(_mm512_cvttpd_epi64(y0), _mm512_set1_epi64(f.n[0])),
                                            _mm512_cvttpd_epi64(x0));
    // Compressed in a register, then stored whole into the slack of kSlots (as the hits: kHitSlack).
    auto keep = [&](double* to, __m512d v) { _mm512_storeu_pd(to + kept, _mm512_maskz_compress_pd(down, v)); };
    keep(t->tx, tx);
    keep(t->ty, ty);
    keep(t->px, px);
    keep(t->py, py);
    keep(t->sx, sx);
    keep(t->sy, sy);
    keep(t->inv_x, inv[0]);
    keep(t->inv_y, inv[1]);
    keep(t->dz, dg[2]);
    keep(t->t_exit, t1);
    keep(t->iz, z0);
    keep(t->inv_z, inv[2]);
    _mm512_storeu_si512(t->column + kept, _mm512_maskz_compress_epi64(down, column));
    _mm512_storeu_si512(t->ends_inside + kept,
                        _mm512_maskz_compress_epi64(down, _mm512_maskz_mov_epi64(inside, _mm512_set1_epi64(1))));
    kept += __builtin_popcount(down);
  }
  bounds->Merge(SegmentBounds{_mm512_reduce_min_pd(x_lo), _mm512_reduce_max_pd(x_hi), _mm512_reduce_min_pd(y_lo),
                              _mm512_reduce_max_pd(y_hi)});  // empty where no ray entered
  return kept;
}

// The first min(n, 16) of 16 lanes (n > 0): a row's pixels left from a column on.
inline __mmask16 FirstLanes16(int n) { return static_cast<__mmask16>(n >= 16 ? 0xffff : (1u << n) - 1); }

// Lines to prefetch, as rectangles: box b holds rows x cols lines at base + r row_bytes +
// c col_bytes, and Prefetch(n) issues the next n of them in order. As fast as a list of the
// lines' pointers, without its 64 KB per thread to write and read back each tile.
class TileAhead {
 public:
  void Clear() { boxes_ = 0, total_ = 0, box_ = 0, col_ = 0; }
  // Adds a box while fewer than kMaxLines lines and kMaxBoxes boxes are held (a hint only).
  void Add(const void* base, int rows, int cols, ptrdiff_t row_bytes, ptrdiff_t col_bytes) {
    const size_t lines = static_cast<size_t>(rows) * cols;
    if (boxes_ == kMaxBoxes || total_ + lines > kMaxLines || lines == 0) return;
    box_at_[boxes_++] = Box{static_cast<const char*>(base), rows, cols, row_bytes, col_bytes};
    if (boxes_ == 1) row_start_ = line_ = box_at_[0].base, row_ = 0;
    total_ += lines;
  }
  size_t lines() const { return total_; }
  void Prefetch(size_t n) {
    for (; n > 0 && box_ < boxes_; --n) {
      _mm_prefetch(line_, _MM_HINT_T0);
      const Box& b = box_at_[box_];
      line_ += b.col_bytes;
      if (++col_ == b.cols) {
        col_ = 0;
        if (++row_ < b.rows) {
          row_start_ += b.row_bytes;
        } else if (++box_ < boxes_) {
          row_ = 0;
          row_start_ = box_at_[box_].base;
        }
        line_ = row_start_;
      }
    }
  }

 private:
  // ~2.5 k lines per tile of the benchmark; a tile seen at a grazing angle could reach much of
  // the grid, where a hint would only evict lines in use.
  static constexpr size_t kMaxLines = 8192;
  static constexpr int kMaxBoxes = 32;
  struct Box {
    const char* base;
    int rows, cols;
    ptrdiff_t row_bytes, col_bytes;
  };
  Box box_at_[kMaxBoxes];
  int boxes_ = 0;
  size_t total_ = 0;
  int box_ = 0, row_ = 0, col_ = 0;  // the next line: line_, in a row from row_start_
  const char* line_ = nullptr;
  const char* row_start_ = nullptr;
};

// The lines of votes that the rays of tile [u0, u1) x [v0, v1) may reach in rows [ya, yb), to be
// prefetched while the tile before it is walked: a tile's lines are seldom those of the tile
// before, and the frame's 12.5 MB of them have left an L3 of ~4-8 MB by the next frame,
// so each tile otherwise waits for ~650 of them from DRAM (~150 ns each, of which the walk's
// out-of-order window overlaps only a few). Per level of kLevelVotes votes, the (x, y) box of
// the tile's corner pixels' rays between the level's planes, from the box's top (or the camera)
// down to the z of the tile's farthest depth. Then the tile's rows of the ray table, for its
// setup's gathers (4.9 MB: they leave the caches between frames too). Only a hint: how close
// the boxes are changes the speed, never the votes.
constexpr int kLevelVotes = 32;  // a 64-byte line of int16 votes
inline void VoteLines(const SetupFrame& f, const cv::Mat& depth_m, int u0, int u1, int v0, int v1, int ya, int yb,
                      const Vote* votes, TileAhead* out) {
  // The largest finite depth, 16 pixels at a time.
  const __m512 inf = _mm512_set1_ps(std::numeric_limits<float>::infinity());
  __m512 d16 = _mm512_setzero_ps();
  for (int v = v0; v < v1; ++v) {
    const float* row = depth_m.ptr<float>(v);
    for (int u = u0; u < u1; u += 16) {
      const __mmask16 in = FirstLanes16(u1 - u);
      const __m512 d = _mm512_maskz_loadu_ps(in, row + u);
      d16 = _mm512_mask_max_ps(d16, _mm512_mask_cmp_ps_mask(in, _mm512_abs_ps(d), inf, _CMP_LT_OQ), d16, d);
    }
  }
  const float d_max = _mm512_reduce_max_ps(d16);
  if (!(d_max > 0.0f)) return;
  const int nx = f.n[0], nz = f.n[2];
  // The corner rays' directions in grid units per metre of depth, and the lowest z they reach.
  double dir[4][3];
  double z_low = f.o_g[2];
  for (int i = 0; i < 4; ++i) {
    const double* r = f.ray_C + 2 * (static_cast<size_t>(i < 2 ? v0 : v1 - 1) * f.width + (i % 2 == 0 ? u0 : u1 - 1));
    for (int a = 0; a < 3; ++a) dir[i][a] = (f.R[a][0] * r[0] + f.R[a][1] * r[1] + f.R[a][2]) / f.voxel;
    if (!(dir[i][2] < 0.0)) return;  // a corner looks up or sideways: no hint
    z_low = std::min(z_low, f.o_g[2] + d_max * dir[i][2]);
  }
  const double z_high = std::min(f.o_g[2], static_cast<double>(nz));
  if (!(z_low < z_high) || !(z_high > 0.0)) return;
  z_low = std::max(z_low, 0.0);
  auto clamp_index = [](double x, int lo, int hi) {
    return static_cast<int>(std::clamp(std::floor(x), double(lo), double(hi)));
  };
  for (int level = static_cast<int>(z_low) / kLevelVotes; level * kLevelVotes < z_high; ++level) {
    double x_lo = std::numeric_limits<double>::infinity(), x_hi = -x_lo, y_lo = x_lo, y_hi = -x_lo;
    for (const double z :
         {std::max(z_low, double(level * kLevelVotes)), std::min(z_high, double((level + 1) * kLevelVotes))}) {
      for (const auto& d : dir) {
        const double s = (z - f.o_g[2]) / d[2];
        x_lo = std::min(x_lo, f.o_g[0] + s * d[0]);
        x_hi = std::max(x_hi, f.o_g[0] + s * d[0]);
        y_lo = std::min(y_lo, f.o_g[1] + s * d[1]);
        y_hi = std::max(y_hi, f.o_g[1] + s * d[1]);
      }
    }
    if (!(x_hi >= 0.0 && x_lo < nx && y_hi >= ya && y_lo < yb)) continue;  // misses the rows (or NaN)
    const int x0 = clamp_index(x_lo, 0, nx - 1), x1 = clamp_index(x_hi, 0, nx - 1);
    const int y0 = clamp_index(y_lo, ya, yb - 1), y1 = clamp_index(y_hi, ya, yb - 1);
    const ptrdiff_t column_bytes = ptrdiff_t{nz} * sizeof(Vote);
    out->Add(votes + (static_cast<size_t>(y0) * nx + x0) * nz + level * kLevelVotes, y1 - y0 + 1, x1 - x0 + 1,
             nx * column_bytes, column_bytes);
  }
}
inline void TileLines(const SetupFrame& f, const cv::Mat& depth_m, int u0, int u1, int v0, int v1, int ya, int yb,
                      const Vote* votes, TileAhead* out) {
  out->Clear();
  VoteLines(f, depth_m, u0, u1, v0, v1, ya, yb, votes, out);
  // A row's pixels u0 .. u1 - 1 (16 bytes each); rows whose start is not 64-byte aligned as the
  // first row's may reach one line further.
  const ptrdiff_t row_bytes = ptrdiff_t{16} * f.width;
  const uintptr_t first = reinterpret_cast<uintptr_t>(f.ray_C + 2 * (static_cast<size_t>(v0) * f.width + u0)) / 64;
  const uintptr_t last = reinterpret_cast<uintptr_t>(f.ray_C + 2 * (static_cast<size_t>(v0) * f.width + u1) - 1) / 64;
  out->Add(reinterpret_cast<const void*>(first * 64), v1 - v0,
           static_cast<int>(last - first + 1 + (row_bytes % 64 != 0)), row_bytes, 64);
}

// One thread's insertion of a tile, pixels [u0, u1) x [v0, v1): classify the pixels, set the
// rays up eight at a time (SetUpTile), then walk those that go down in groups of eight (without
// kAllRows: only the rays that may touch the thread's rows). Lane l walks the l-th eighth of the
// kept rays (about four pixel rows of a full tile), so the lanes of a group are mostly rows apart
// and seldom update one block in the same step (a masked load waits until an earlier masked
// store to it has retired; the votes are exact either way), while their walks stay about as long.
// Spread over the groups, prefetches the lines `ahead` (the next tile's TileLines).
// Counts into *s, widens *bounds, counts rays per row into `weight` (may be null).
template <bool kAllRows>
inline void InsertTile(const SetupFrame& f, const cv::Mat& depth_m, int u0, int u1, int v0, int v1, TileRays* t,
                       WalkContext* c, InsertStats* s, SegmentBounds* bounds, uint32_t* weight, TileAhead* ahead) {
  // The tile's valid pixels in row order, 16 at a time: 0 is no measurement; NaN, inf and
  // negative depths are invalid; a compress into a register and a plain store keep the others
  // (at most 16 past the last kept pixel: within kSlots).
  int count = 0;
  const __m512 zero = _mm512_setzero_ps(), inf = _mm512_set1_ps(std::numeric_limits<float>::infinity());
  const __m512i iota = _mm512_set_epi32(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0);
  for (int v = v0; v < v1; ++v) {
    const float* row = depth_m.ptr<float>(v);
    for (int u = u0; u < u1; u += 16) {
      const __mmask16 in = FirstLanes16(u1 - u);
      const __m512 d = _mm512_maskz_loadu_ps(in, row + u);
      const __mmask16 none = _mm512_mask_cmp_ps_mask(in, d, zero, _CMP_EQ_OQ);
      const __mmask16 valid = _mm512_mask_cmp_ps_mask(_mm512_mask_cmp_ps_mask(in, d, zero, _CMP_GT_OQ), d, inf,
                                                      _CMP_LT_OQ);
      s->no_measurement += __builtin_popcount(none);
      s->invalid_depth += __builtin_popcount(in & ~none & ~valid);
      const __m512i pixel = _mm512_add_epi32(_mm512_set1_epi32(v * f.width + u), iota);
      _mm512_storeu_si512(t->pixel + count, _mm512_maskz_compress_epi32(valid, pixel));
      _mm512_storeu_ps(t->depth + count, _mm512_maskz_compress_ps(valid, d));
      count += __builtin_popcount(valid);
    }
  }
  s->rays += count;
  for (int i = count; i < count + kGroupLanes; ++i) t->pixel[i] = 0, t->depth[i] = 0.0f;
  const size_t rays = SetUpTile<kAllRows>(f, count, t, c, s, bounds, weight);
  // Group k: lane l takes ray first[l] + k of its eighth.
  alignas(32) int32_t first[kGroupLanes], size[kGroupLanes];
  int groups = 0;
  for (int l = 0; l < kGroupLanes; ++l) {
    first[l] = static_cast<int32_t>(rays * l / kGroupLanes);
    size[l] = static_cast<int32_t>(rays * (l + 1) / kGroupLanes) - first[l];
    groups = std::max(groups, size[l]);
  }
  const __m256i base = _mm256_load_si256(reinterpret_cast<const __m256i*>(first));
  const __m256i sizes = _mm256_load_si256(reinterpret_cast<const __m256i*>(size));
  LaneGroup group{};
  const size_t ahead_per_group = groups > 0 ? (ahead->lines() + groups - 1) / groups : 0;
  for (int k = 0; k < groups; ++k) {
    ahead->Prefetch(ahead_per_group);
    const __m256i kk = _mm256_set1_epi32(k);
    const __mmask8 lanes = static_cast<__mmask8>(
        _mm256_movemask_ps(_mm256_castsi256_ps(_mm256_cmpgt_epi32(sizes, kk))));
    const __m256i index = _mm256_add_epi32(base, kk);
    auto gather = [&](const double* from, double* to) {
      _mm512_store_pd(to, _mm512_mask_i32gather_pd(_mm512_setzero_pd(), lanes, index, from, 8));
    };
    gather(t->tx, group.tx);
    gather(t->ty, group.ty);
    gather(t->px, group.px);
    gather(t->py, group.py);
    gather(t->sx, group.sx);
    gather(t->sy, group.sy);
    gather(t->inv_x, group.inv_x);
    gather(t->inv_y, group.inv_y);
    gather(t->dz, group.dz);
    gather(t->t_exit, group.t_exit);
    gather(t->iz, group.iz);
    gather(t->inv_z, group.inv_z);
    _mm512_store_si512(group.column, _mm512_mask_i32gather_epi64(_mm512_setzero_si512(), lanes, index, t->column, 8));
    group.ends_inside = _mm512_mask_test_epi64_mask(
        lanes, _mm512_mask_i32gather_epi64(_mm512_setzero_si512(), lanes, index, t->ends_inside, 8),
        _mm512_set1_epi64(1));
    WalkGroup<kAllRows>(group, lanes, c);
  }
}

// InsertSlabAvx512: the tiles in row order, the next tile's lines prefetched while one is walked.
template <bool kAllRows>
void InsertTiles(const SetupFrame& f, const cv::Mat& depth_m, TileRays* tile, WalkContext* c, InsertStats* counts,
                 SegmentBounds* bounds, uint32_t* weight) {
  constexpr int kTile = kInsertionTilePx;
  const int width = depth_m.cols, height = depth_m.rows;
  TileAhead ahead;  // the next tile's lines
  for (int tv = 0; tv < height; tv += kTile) {
    for (int tu = 0; tu < width; tu += kTile) {
      const int nu = tu + kTile < width ? tu + kTile : 0, nv = tu + kTile < width ? tv : tv + kTile;
      if (nv < height) {
        TileLines(f, depth_m, nu, std::min(nu + kTile, width), nv, std::min(nv + kTile, height), c->ya, c->yb, c->votes,
                  &ahead);
      } else {
        ahead.Clear();
      }
      InsertTile<kAllRows>(f, depth_m, tu, std::min(tu + kTile, width), tv, std::min(tv + kTile, height), tile, c,
                           counts, bounds, weight, &ahead);
    }
  }
}

}  // namespace

void InsertSlabAvx512(const SetupFrame& f, const cv::Mat& depth_m, TileRays* tile, WalkContext* c, InsertStats* counts,
                      SegmentBounds* bounds, uint32_t* weight) {
  if (c->ya == 0 && c->yb == c->ny) {
    InsertTiles<true>(f, depth_m, tile, c, counts, bounds, weight);
  } else {
    InsertTiles<false>(f, depth_m, tile, c, counts, bounds, weight);
  }
}

}  // namespace romunect::fusion::insert_internal

#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // ROMUNECT_FUSION_KERNEL_AVX512
