// The matching kernel's template (see depth_engine_kernel.h). Included once per instruction set
// by depth_engine_kernel_{scalar,sse2,avx2,avx512}.cc; everything here has internal linkage.
#pragma once

#include <algorithm>
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

// The sub-pixel fit's parameters (DepthEngineOptions::subpixel_*).
struct SubPixelFit {
  float weight, rounding_slope, quarter_correction, eighth_correction;
};

// The best shift's sub-pixel offset in [-0.5, 0.5] px from its window cost c0 and its
// neighbours' (cm at -1 px, cp at +1 px): a weight w times the equiangular (V) fit plus the rest
// times the parabola's, then the quarter- and eighth-pixel corrections (DepthEngineOptions).
// w = weight - rounding_slope c0 / a, clamped to [0, 1] (a = max(cm, cp) - c0): blur and faint,
// noisy dots lift and round the minimum. Branch-free so that a row of it vectorizes; every
// instruction set gives the same bits (one IEEE operation per step, no contraction), and so
// does the reference matcher.
inline float SubPixelOffset(float c0, float cm, float cp, const SubPixelFit& f) {
  // V = (cm - cp) / 2a and parabola = (cm - cp) / 2b, weighted by w2 = 2a w and 2a - w2, in one
  // division (a = b = 0 only when all three costs are equal: offset 0). The row's other pixels
  // hold stale costs: never 0 / 0. Selects are spelled as arithmetic on 0/1 (exact), which
  // vectorizes where branches would not.
  const float a = std::max(cm, cp) - c0, b = cm + cp - 2.f * c0, a2 = 2.f * a;
  const float fit = static_cast<float>((a > 0.f) & (b > 0.f));
  const float w2 = std::min(std::max(a2 * f.weight - f.rounding_slope * (2.f * c0), 0.f), a2);
  const float d = (cm - cp) * (w2 * b + (a2 - w2) * a) * fit / (a2 * a2 * b * fit + (1.f - fit));
  // From the nearest half pixel, then the nearest quarter pixel (all steps exact).
  const float u = d - 0.5f * (static_cast<float>(d > 0.25f) - static_cast<float>(d < -0.25f));
  const float e = d - f.quarter_correction * u * (1.f - 16.f * u * u);
  const float h = e - 0.5f * (static_cast<float>(e > 0.25f) - static_cast<float>(e < -0.25f));
  const float v = h - 0.25f * (static_cast<float>(h > 0.125f) - static_cast<float>(h < -0.125f));
  return e - f.eighth_correction * v * (1.f - 64.f * v * v);
}

// The second pass over one row: the sub-pixel refinement (SubPixelOffset, for the whole row
// first, parked in shift_row) and the raw value, with the float arithmetic of depth_engine.h and
// the reference matcher. Writes every pixel of the row and counts it. kDistorted: the row y of
// the disparity distortion's maps is added (the undistorted rows compile without it).
template <bool kDistorted>
inline void RefineRow(const KernelArgs& a, int y, const int16_t* code, const int16_t* best_cost,
                      const int16_t* best_j, const int16_t* cost_minus, const int16_t* cost_plus, uint16_t* raw_row,
                      float* depth_row, float* shift_row, KernelStats* stats) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const SubPixelFit fit{a.equiangular_weight, a.rounding_slope, a.quarter_correction, a.eighth_correction};
  for (int x = 0; x < a.width; ++x) {
    shift_row[x] = SubPixelOffset(best_cost[x], cost_minus[x], cost_plus[x], fit);
  }
  for (int x = 0; x < a.width; ++x) {
    const float delta = shift_row[x];
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
    float s8f = 8.f * (static_cast<float>(a.min_shift_px + best_j[x]) + delta);
    if constexpr (kDistorted) {  // the distortion raises raw: lowers the shift
      const size_t i = static_cast<size_t>(y) * a.float_step + x;
      const float raw_f = static_cast<float>(a.raw_at_reference) - s8f;
      s8f -= a.distortion_radial[i] * std::exp(a.distortion_alpha0 - a.distortion_alpha1 * raw_f) +
             a.distortion_pattern[i] * std::exp(a.distortion_pattern_alpha0 - a.distortion_pattern_alpha1 * raw_f);
    }
    const long s8 = static_cast<long>(std::floor(s8f + 0.5f));
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

// The band's sliding window at row y: the rows it takes in and leaves (the old row exists from
// the band's second row on), and the reference rows reversed, pointed at p = W - 1 (x = 0,
// j = 0), so that column x reads at -x. Stored rows: image row + r (KernelArgs).
struct RowWindow {
  int y = 0;
  bool first_row = false;
  const uint8_t *obs_new = nullptr, *obs_old = nullptr;
  const uint8_t *ref_new = nullptr, *ref_old = nullptr;
  const uint8_t* outside = nullptr;
};

inline RowWindow WindowAt(const KernelArgs& a, int y) {
  RowWindow w;
  w.y = y;
  w.first_row = y == a.y_begin;
  const size_t row_new = static_cast<size_t>(y + 2 * a.radius);
  const size_t row_old = w.first_row ? row_new : static_cast<size_t>(y - 1);
  w.obs_new = a.obs + row_new * a.obs_step;
  w.obs_old = a.obs + row_old * a.obs_step;
  w.ref_new = a.ref_rev + row_new * a.ref_step + (a.width - 1);
  w.ref_old = a.ref_rev + row_old * a.ref_step + (a.width - 1);
  w.outside = a.outside + (a.width - 1);
  return w;
}

// Column x's window sums (kLanes = NB x 32 shifts at colsum + x kLanes): summed for the band's
// first row, then + new row - old row. Columns near the image sides also see shifts without a
// reference column (difference 255).
template <class V, int NB>
[[gnu::always_inline]] inline void UpdateColumn(const KernelArgs& a, const RowWindow& w, int x, int16_t* colsum) {
  using I16 = typename V::I16;
  using U8 = typename V::U8;
  const int r = a.radius;
  int16_t* c = colsum + x * NB * kLanesPerBlock;
  const bool clean = x >= a.clean_begin && x < a.clean_end;
  for (int b = 0; b < NB; ++b) {
    const int p = b * kLanesPerBlock - x;
    auto masked = [&](U8 d) { return clean ? d : V::OrBytes(d, w.outside + p); };
    if (w.first_row) {
      I16 sum = V::Widen(masked(V::AbsDiff(a.obs[w.y * a.obs_step + x], w.ref_new + p - 2 * r * a.ref_step)));
      for (int dy = -r + 1; dy <= r; ++dy) {
        const size_t row = static_cast<size_t>(w.y + r + dy);
        sum = V::Add(sum, V::Widen(masked(V::AbsDiff(a.obs[row * a.obs_step + x],
                                                     a.ref_rev + row * a.ref_step + (a.width - 1) + p))));
      }
      V::Store(c + b * kLanesPerBlock, sum);
    } else {
      const I16 diff = V::WidenDiff(masked(V::AbsDiff(w.obs_new[x], w.ref_new + p)),
                                    masked(V::AbsDiff(w.obs_old[x], w.ref_old + p)));
      V::Store(c + b * kLanesPerBlock, V::Add(V::Load(c + b * kLanesPerBlock), diff));
    }
  }
}

// The search's results for one row (the first pass), read by RefineRow.
struct SearchRow {
  int16_t* code = nullptr;
  int16_t* best_cost = nullptr;
  int16_t* best_j = nullptr;
  int16_t* cost_minus = nullptr;
  int16_t* cost_plus = nullptr;
};

// The search at pixel x of a textured window with costs s (the last block's padding lanes
// raised to kCostMax by `pad`): weak, ambiguous, at the edge of the range, or a candidate with
// its best shift and the neighbours' costs. `lanes` holds NB x 32 values of scratch.
template <class V, int NB>
[[gnu::always_inline]] inline void SearchPixel(const KernelArgs& a, const typename V::I16 (&s)[NB],
                                               const typename V::I16& pad, int max_best_cost, int x,
                                               int16_t* lanes, const SearchRow& out) {
  using I16 = typename V::I16;
  constexpr int kWords = (NB + 1) / 2;  // 64-bit lane masks
  const I16 last = V::Or(s[NB - 1], pad);
  I16 m = last;
  for (int b = 0; b < NB - 1; ++b) m = V::Min(m, s[b]);
  const int c0 = V::HorizontalMin(m);
  out.best_cost[x] = static_cast<int16_t>(c0);
  if (c0 > max_best_cost) {
    out.code[x] = kWeak;
    return;
  }
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
    out.code[x] = kAmbiguous;
  } else if (j == 0 || j == a.range - 1) {
    out.code[x] = kEdgeOfRange;
  } else {
    out.code[x] = kCandidate;
    out.best_j[x] = static_cast<int16_t>(j);
    for (int b = 0; b < NB; ++b) V::Store(lanes + b * kLanesPerBlock, s[b]);
    out.cost_minus[x] = lanes[(j - 1) / kLanesPerBlock * kLanesPerBlock + V::Lane((j - 1) % kLanesPerBlock)];
    out.cost_plus[x] = lanes[(j + 1) / kLanesPerBlock * kLanesPerBlock + V::Lane((j + 1) % kLanesPerBlock)];
  }
}

inline void AddStats(const KernelStats& s, KernelStats* to) {
  to->valid += s.valid;
  to->flat += s.flat;
  to->weak += s.weak;
  to->ambiguous += s.ambiguous;
  to->out_of_range += s.out_of_range;
  to->border += s.border;
}

// V: the instruction set's lanes (operations listed in depth_engine_kernel_sse2.cc).
// NB: blocks of 32 shifts, a constant so that the window costs stay in registers.
template <class V, int NB>
void MatchRows(const KernelArgs& args, KernelStats* stats_out) {
  using I16 = typename V::I16;
  constexpr int kLanes = NB * kLanesPerBlock;
  const KernelArgs a = args;  // a local copy: the output stores cannot alias it
  const int W = a.width, r = a.radius;
  int16_t* const colsum = a.scratch;
  SearchRow search;
  search.code = colsum + static_cast<size_t>(W) * kLanes;
  search.best_cost = search.code + W;
  search.best_j = search.best_cost + W;
  search.cost_minus = search.best_j + W;
  search.cost_plus = search.cost_minus + W;
  // Padding lanes (shifts j >= D) of the last block never win.
  alignas(64) int16_t pad_lanes[kLanesPerBlock] = {};
  for (int k = a.range - (NB - 1) * kLanesPerBlock; k < kLanesPerBlock; ++k) pad_lanes[V::Lane(k)] = kCostMax;
  const I16 pad = V::Load(pad_lanes);
  alignas(64) int16_t lanes[kLanes];
  KernelStats stats;
  const int searched = a.searched_width;
  for (int x = searched; x < W; ++x) search.code[x] = kBorder;
  auto column = [&](int x, int b) { return V::Load(colsum + x * kLanes + b * kLanesPerBlock); };

  for (int y = a.y_begin; y < a.y_end; ++y) {
    const RowWindow window = WindowAt(a, y);
    const float* sigma_row = a.sigma + y * a.sigma_step;
    // The window at x = 0, clipped to columns 0..r.
    I16 s[NB];
    const int first_columns = std::min(r + 1, W);
    for (int x = 0; x < first_columns; ++x) UpdateColumn<V, NB>(a, window, x, colsum);
    for (int b = 0; b < NB; ++b) {
      s[b] = column(0, b);
      for (int x = 1; x < first_columns; ++x) s[b] = V::Add(s[b], column(x, b));
    }
    // First pass: the search. Flat windows skip it (invalid whatever their costs). Then the
    // window slides to x + 1: column x + r + 1 comes in and column x - r leaves, where they exist;
    // the image's inner columns, where both always do, test neither.
    auto search_and_slide = [&](int x, bool enters, bool leaves, int columns) __attribute__((always_inline)) {
      if (sigma_row[x] < a.min_texture) {
        search.code[x] = kFlat;
      } else {
        SearchPixel<V, NB>(a, s, pad, a.max_best_cost_of_columns[columns], x, lanes, search);
      }
      if (enters) UpdateColumn<V, NB>(a, window, x + r + 1, colsum);
      for (int b = 0; b < NB; ++b) {
        if (enters && leaves) {
          s[b] = V::Add(s[b], V::Sub(column(x + r + 1, b), column(x - r, b)));
        } else if (enters) {
          s[b] = V::Add(s[b], column(x + r + 1, b));
        } else if (leaves) {
          s[b] = V::Sub(s[b], column(x - r, b));
        }
      }
    };
    auto clipped = [&](int x) __attribute__((always_inline)) {
      search_and_slide(x, x + r + 1 < W, x >= r, std::min(x + r, W - 1) - std::max(x - r, 0) + 1);
    };
    const int inner_begin = std::min(r, searched), inner_end = std::max(inner_begin, std::min(searched, W - r - 1));
    for (int x = 0; x < inner_begin; ++x) clipped(x);
    for (int x = inner_begin; x < inner_end; ++x) search_and_slide(x, true, true, 2 * r + 1);
    for (int x = inner_end; x < searched; ++x) clipped(x);
    if (a.distortion_radial == nullptr) {
      RefineRow<false>(a, y, search.code, search.best_cost, search.best_j, search.cost_minus, search.cost_plus,
                       a.raw + y * a.raw_step, a.depth_m + y * a.float_step, a.shift_px + y * a.float_step, &stats);
    } else {
      RefineRow<true>(a, y, search.code, search.best_cost, search.best_j, search.cost_minus, search.cost_plus,
                      a.raw + y * a.raw_step, a.depth_m + y * a.float_step, a.shift_px + y * a.float_step, &stats);
    }
  }
  AddStats(stats, stats_out);
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
