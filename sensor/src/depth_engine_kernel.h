// The depth engine's matching kernel (private to sensor/src): one template, instantiated per
// instruction set in depth_engine_kernel_{scalar,sse2,avx2,avx512}.cc. Integer arithmetic in the same
// order everywhere, so every instruction set gives the same bytes (tested against each other and
// against the full-search reference in tests/sensor). The dispatch follows the one idiom of
// docs/design.md, "SIMD kernels": a table of the instruction sets compiled in (depth_engine.cc),
// picked by ResolveKernel.
//
// Layout: disparities run across SIMD lanes, in blocks of 32. Lane j of pixel x compares the
// pixel with reference column x - (min_shift + j). The reference rows are stored reversed, so
// those columns are contiguous and ascending in j: lane j of pixel x reads reversed index
// p = W - 1 - x + j. Per row band: column sums C[x][j] of the window's absolute differences
// (updated as the window slides down: + the new row, - the old one), then the window cost
// S[j] = sum of C over the window's columns (updated as it slides along the row). The cost per
// pixel does not depend on the window size. Each row runs in two passes: the search per pixel
// (best cost, its shift, the neighbours' costs, or why it was rejected), then the sub-pixel
// refinement and the raw value, free of the search's long dependency chains.
//
// This header holds what the engine and the kernels share; the kernel template itself is in
// depth_engine_kernel_rows.h, in an anonymous namespace, so that no inline function is shared
// between units compiled for different instruction sets.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "romunect/sensor/cpu_features.h"

namespace romunect::depth_engine_internal {

inline constexpr int kLanesPerBlock = 32;
inline constexpr int kMaxBlocks = 8;        // search_range_px <= 256
inline constexpr int16_t kCostMax = 32767;  // above any window cost (11 x 11 x 255 = 30855)
inline constexpr uint16_t kRawNone = 2047;  // kRawInvalid (depth_engine.h), kept free of its includes

struct KernelStats {
  int valid = 0, flat = 0, weak = 0, ambiguous = 0, out_of_range = 0, border = 0;
};

// Everything one call needs: rows [y_begin, y_end) of the image, 0 <= y_begin, y_end <= H.
// Windows at the image's sides are clipped to its columns (the weak test scaled to the columns
// left); the prefiltered frame and reference rows hold `radius` reflected rows above row 0 and
// below row H - 1 (image row y is stored row y + radius), the same rows for both, so that a
// window at the top or bottom compares like with like.
struct KernelArgs {
  int width = 0, radius = 0;
  int searched_width = 0;  // columns [searched_width, width) are the chip's border: no search
  int range = 0;   // D, the number of shifts searched
  int blocks = 0;  // ceil(D / 32)
  int min_shift_px = 0;
  const uint8_t* obs = nullptr;  // prefiltered frame, CV_8U, with the reflected rows
  size_t obs_step = 0;
  const float* sigma = nullptr;      // raw local standard deviation (DN), CV_32F
  size_t sigma_step = 0;             // in floats
  const uint8_t* ref_rev = nullptr;  // reversed, padded reference rows (and reflected rows): index p as above
  size_t ref_step = 0;
  const uint8_t* outside = nullptr;    // per p: 0xFF where the reference has no column x - s
  int clean_begin = 0, clean_end = 0;  // columns x whose shifts j < D all have a reference column
  float min_texture = 0.f;
  // Per number n of the window's columns inside the image (n <= 2 radius + 1): weak above this
  // window cost.
  const int* max_best_cost_of_columns = nullptr;
  // Per best cost c0 that is not weak: costs below this (beyond +-1 of the best) make the pixel
  // ambiguous (the integer form of "float(cost) < c0 (1 + uniqueness)").
  const int16_t* ambiguous_below = nullptr;
  int raw_at_reference = 0, raw_limit = 0;  // raw valid in [0, raw_limit)
  const float* chip_depth_lut = nullptr;
  uint16_t* raw = nullptr;
  size_t raw_step = 0;  // in uint16
  float* depth_m = nullptr;
  float* shift_px = nullptr;
  size_t float_step = 0;       // in floats, depth and shift
  // The fixed-pattern disparity distortion (disparity_distortion.h): beta's radial and pattern
  // parts per pixel, rows of float_step, each added times its factor exp(alpha0 - alpha1 raw)
  // to the unrounded raw; nullptr: none.
  const float* distortion_radial = nullptr;
  const float* distortion_pattern = nullptr;
  float distortion_alpha0 = 0.f, distortion_alpha1 = 0.f;
  float distortion_pattern_alpha0 = 0.f, distortion_pattern_alpha1 = 0.f;
  float equiangular_weight = 1.f;  // DepthEngineOptions::subpixel_equiangular_weight
  float rounding_slope = 0.f;      // DepthEngineOptions::subpixel_rounding_slope
  float quarter_correction = 0.f;  // DepthEngineOptions::subpixel_quarter_correction
  float eighth_correction = 0.f;   // DepthEngineOptions::subpixel_eighth_correction
  int16_t* scratch = nullptr;  // KernelScratchSize(width, blocks) values
  int y_begin = 0, y_end = 0;
};

// Column sums (width x blocks x 32) and one row of search results (5 x width).
inline size_t KernelScratchSize(int width, int blocks) {
  return static_cast<size_t>(width) * (blocks * kLanesPerBlock + 5);
}

// The instantiations, one per instruction set (the ones compiled in: see the macros below).
void MatchRowsScalar(const KernelArgs& args, KernelStats* stats);
void MatchRowsSse2(const KernelArgs& args, KernelStats* stats);
void MatchRowsAvx2(const KernelArgs& args, KernelStats* stats);
void MatchRowsAvx512(const KernelArgs& args, KernelStats* stats);

// One entry of the engine's dispatch table (depth_engine.cc, ResolveKernel).
using MatchRowsFn = void (*)(const KernelArgs& args, KernelStats* stats);
struct Kernel {
  Isa isa;
  MatchRowsFn match_rows;
};

}  // namespace romunect::depth_engine_internal

#if defined(__SSE2__)
#define ROMUNECT_DEPTH_KERNEL_SSE2 1
#endif
// AVX2 and AVX-512 code is compiled under `#pragma GCC target` and runs only where the CPU
// reports the instruction set.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROMUNECT_DEPTH_KERNEL_AVX2 1
#define ROMUNECT_DEPTH_KERNEL_AVX512 1
#endif
