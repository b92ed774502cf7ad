// The matching kernel's template (see depth_engine_kernel.h). Included once per instruction set
// by depth_engine_kernel_{scalar,sse2,avx2}.cc; everything here has internal linkage.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "depth_engine_kernel.h"

namespace {

using romunect::depth_engine_internal::kCostMax;
using romunect::depth_engine_internal::KernelArgs;
using romunect::depth_engine_internal::KernelStats;
using romunect::depth_engine_internal::kLanesPerBlock;
using romunect::depth_engine_internal::kRawNone;

// Why a pixel has no raw value, or kCandidate when the search found a match to refine.
enum PixelCode : int16_t { kCandidate, kBorder, kFlat, kWeak, kAmbiguous, kEdgeOfRange };

// The second pass over one row: the sub-pixel refinement (parabola through the neighbours'
// costs) and the raw value, with the float arithmetic of depth_engine.h and the reference
// matcher. Writes every pixel of the row and counts it.
inline void RefineRow(const KernelArgs& a, const int16_t* code, const int16_t* best_cost, const int16_t* best_j,
                      const int16_t* cost_minus, const int16_t* cost_plus, uint16_t* raw_row, float* depth_row,
                      float* shift_row, KernelStats* stats) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (int x = 0; x < a.width; ++x) {
    raw_row[x] = kRawNone;
    depth_row[x] = 0.f;
    shift_row[x] = nan;
    switch (code[x]) {
      case kBorder: ++stats->border; continue;
      case kFlat: ++stats->flat; continue;
      case kWeak: ++stats->weak; continue;
      case kAmbiguous: ++stats->ambiguous; continue;
      case kEdgeOfRange: ++stats->out_of_range; continue;
      default: break;
    }
    const float c0 = best_cost[x], cm = cost_minus[x], cp = cost_plus[x];
    const float denom = 2.f * (cm + cp - 2.f * c0);
    const float delta = denom > 0.f ? (cm - cp) / denom : 0.f;
    const long s8 =
        static_cast<long>(std::floor(8.f * (static_cast<float>(a.min_shift_px + best_j[x]) + delta) + 0.5f));
    const long raw = a.raw_at_reference - s8;
    if (raw < 0 || raw >= a.raw_limit) {
      ++stats->out_of_range;
      continue;
    }
    ++stats->valid;
    raw_row[x] = static_cast<uint16_t>(raw);
    depth_row[x] = a.chip_depth_lut[raw];
    shift_row[x] = static_cast<float>(s8) / 8.f;
  }
}

// V: the instruction set's lanes (operations listed in depth_engine_kernel_sse2.cc).
// NB: blocks of 32 shifts, a constant so that the window costs stay in registers.
template <class V, int NB>
void MatchRows(const KernelArgs& args, KernelStats* stats_out) {
  using I16 = typename V::I16;
  using U8 = typename V::U8;
  constexpr int kLanes = NB * kLanesPerBlock;
  constexpr int kWords = (NB + 1) / 2;  // 64-bit lane masks
  const KernelArgs a = args;  // a local copy: the output stores cannot alias it
  const int W = a.width, r = a.radius;
  int16_t* const colsum = a.scratch;
  int16_t* const code = colsum + static_cast<size_t>(W) * kLanes;
  int16_t* const best_cost = code + W;
  int16_t* const best_j = best_cost + W;
  int16_t* const cost_minus = best_j + W;
  int16_t* const cost_plus = cost_minus + W;
  // Padding lanes (shifts j >= D) of the last block never win.
  alignas(64) int16_t pad_lanes[kLanesPerBlock] = {};
  for (int k = a.range - (NB - 1) * kLanesPerBlock; k < kLanesPerBlock; ++k) pad_lanes[V::Lane(k)] = kCostMax;
  const I16 pad = V::Load(pad_lanes);
  alignas(64) int16_t lanes[kLanes];
  KernelStats stats;
  for (int x = 0; x < r; ++x) code[x] = code[W - 1 - x] = kBorder;

  for (int y = a.y_begin; y < a.y_end; ++y) {
    const bool first_row = y == a.y_begin;
    // Row pointers; reference pointers at p = W - 1 (x = 0, j = 0), so column x reads at -x.
    // The old row (left by the sliding window) exists from the band's second row on.
    const size_t row_new = static_cast<size_t>(y + r), row_old = first_row ? row_new : static_cast<size_t>(y - r - 1);
    const uint8_t* obs_new = a.obs + row_new * a.obs_step;
    const uint8_t* obs_old = a.obs + row_old * a.obs_step;
    const uint8_t* ref_new = a.ref_rev + row_new * a.ref_step + (W - 1);
    const uint8_t* ref_old = a.ref_rev + row_old * a.ref_step + (W - 1);
    const uint8_t* outside = a.outside + (W - 1);
    // Column x's window sums: summed for the band's first row, then + new row - old row.
    // Columns near the image sides also see shifts without a reference column (difference 255).
    auto column = [&](int x) {
      int16_t* c = colsum + x * kLanes;
      const bool clean = x >= a.clean_begin && x < a.clean_end;
      for (int b = 0; b < NB; ++b) {
        const int p = b * kLanesPerBlock - x;
        auto masked = [&](U8 d) { return clean ? d : V::OrBytes(d, outside + p); };
        if (first_row) {
          I16 sum = V::Widen(masked(V::AbsDiff(a.obs[(y - r) * a.obs_step + x], ref_new + p - 2 * r * a.ref_step)));
          for (int dy = -r + 1; dy <= r; ++dy) {
            const size_t row = static_cast<size_t>(y + dy);
            sum = V::Add(sum, V::Widen(masked(V::AbsDiff(a.obs[row * a.obs_step + x],
                                                         a.ref_rev + row * a.ref_step + (W - 1) + p))));
          }
          V::Store(c + b * kLanesPerBlock, sum);
        } else {
          const I16 diff = V::WidenDiff(masked(V::AbsDiff(obs_new[x], ref_new + p)),
                                        masked(V::AbsDiff(obs_old[x], ref_old + p)));
          V::Store(c + b * kLanesPerBlock, V::Add(V::Load(c + b * kLanesPerBlock), diff));
        }
      }
    };
    const float* sigma_row = a.sigma + y * a.sigma_step;
    I16 s[NB];
    for (int x = 0; x <= 2 * r; ++x) column(x);
    for (int b = 0; b < NB; ++b) {
      s[b] = V::Load(colsum + b * kLanesPerBlock);
      for (int x = 1; x <= 2 * r; ++x) s[b] = V::Add(s[b], V::Load(colsum + x * kLanes + b * kLanesPerBlock));
    }
    // First pass: the search. Flat windows skip it (invalid whatever their costs).
    for (int x = r; x < W - r; ++x) {
      if (sigma_row[x] < a.min_texture) {
        code[x] = kFlat;
      } else {
        const I16 last = V::Or(s[NB - 1], pad);
        I16 m = last;
        for (int b = 0; b < NB - 1; ++b) m = V::Min(m, s[b]);
        const int c0 = V::HorizontalMin(m);
        best_cost[x] = static_cast<int16_t>(c0);
        if (c0 > a.max_best_cost) {
          code[x] = kWeak;
        } else {
          const int below = a.ambiguous_below[c0];
          uint64_t equal[kWords], less[kWords];
          for (int w = 0; w < kWords; ++w) {
            const int b = 2 * w;
            const I16& lo = b == NB - 1 ? last : s[b];
            equal[w] = V::EqualMask(lo, c0);
            less[w] = V::LessMask(lo, below);
            if (b + 1 < NB) {
              const I16& hi = b + 1 == NB - 1 ? last : s[b + 1];
              equal[w] |= static_cast<uint64_t>(V::EqualMask(hi, c0)) << 32;
              less[w] |= static_cast<uint64_t>(V::LessMask(hi, below)) << 32;
            }
          }
          int j = 0;  // the first shift at the best cost
          for (int w = 0; w < kWords; ++w) {
            if (equal[w] != 0) {
              j = 64 * w + __builtin_ctzll(equal[w]);
              break;
            }
          }
          uint64_t beyond = 0;
          for (int w = 0; w < kWords; ++w) {
            // Bits j - 1 .. j + 1 within this word.
            const int lo = j - 1 - 64 * w;
            const uint64_t near = lo >= 64 || lo < -2 ? 0 : lo >= 0 ? uint64_t{7} << lo : uint64_t{7} >> -lo;
            beyond |= less[w] & ~near;
          }
          if (beyond != 0) {
            code[x] = kAmbiguous;
          } else if (j == 0 || j == a.range - 1) {
            code[x] = kEdgeOfRange;
          } else {
            code[x] = kCandidate;
            best_j[x] = static_cast<int16_t>(j);
            for (int b = 0; b < NB; ++b) V::Store(lanes + b * kLanesPerBlock, s[b]);
            cost_minus[x] = lanes[(j - 1) / kLanesPerBlock * kLanesPerBlock + V::Lane((j - 1) % kLanesPerBlock)];
            cost_plus[x] = lanes[(j + 1) / kLanesPerBlock * kLanesPerBlock + V::Lane((j + 1) % kLanesPerBlock)];
          }
        }
      }
      if (x + r + 1 < W) {
        column(x + r + 1);
        for (int b = 0; b < NB; ++b) {
          s[b] = V::Add(s[b], V::Sub(V::Load(colsum + (x + r + 1) * kLanes + b * kLanesPerBlock),
                                     V::Load(colsum + (x - r) * kLanes + b * kLanesPerBlock)));
        }
      }
    }
    RefineRow(a, code, best_cost, best_j, cost_minus, cost_plus, a.raw + y * a.raw_step, a.depth_m + y * a.float_step,
              a.shift_px + y * a.float_step, &stats);
  }
  stats_out->valid += stats.valid;
  stats_out->flat += stats.flat;
  stats_out->weak += stats.weak;
  stats_out->ambiguous += stats.ambiguous;
  stats_out->out_of_range += stats.out_of_range;
  stats_out->border += stats.border;
}

// Instantiates MatchRows<V, NB> for the block count the engine needs.
template <class V>
void MatchRowsAnyBlocks(const KernelArgs& a, KernelStats* stats) {
  switch (a.blocks) {
    case 1: return MatchRows<V, 1>(a, stats);
    case 2: return MatchRows<V, 2>(a, stats);
    case 3: return MatchRows<V, 3>(a, stats);
    case 4: return MatchRows<V, 4>(a, stats);
    case 5: return MatchRows<V, 5>(a, stats);
    case 6: return MatchRows<V, 6>(a, stats);
    case 7: return MatchRows<V, 7>(a, stats);
    default: return MatchRows<V, 8>(a, stats);
  }
}

}  // namespace
