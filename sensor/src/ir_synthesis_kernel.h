// IR synthesis' per-row kernels (private to sensor/src): one template
// (ir_synthesis_kernel_rows.h), instantiated per instruction set in
// ir_synthesis_kernel_{scalar,avx2,avx512}.cc. The template performs the same IEEE operations
// in the same order in every lane as the scalar instantiation does per pixel (no FMA
// contraction: the sensor target builds with -ffp-contract=off), so every instruction set gives
// the same bytes (tested). Dispatch: a table of the instruction sets compiled in
// (ir_synthesis.cc), picked by ResolveKernel (docs/design.md, "SIMD kernels").
//
// This header holds what the synthesizer and the kernels share: plain pointers and constants,
// no inline code of its own, so that nothing is shared between units compiled for different
// targets; each kernel unit includes it before its target pragma.
#pragma once

#include <cstdint>

#include "romunect/sensor/cpu_features.h"

namespace romunect::ir_synthesis_internal {

// Small tables (level sigmas, materials) hold kTableSize floats or more, so that lanes can look
// up their first kTableSize entries by a permutation instead of a gather.
inline constexpr int kTableSize = 16;

// A blur stack (IrSynthesizer::LevelTable plus the levels' pixels): level k's sample at index
// i (row * stride + column) is at pixels[k * plane + i]. Find's lookup: start[bin], bins of
// 1 / lut_per_px of sigma.
struct LevelStack {
  const float* pixels = nullptr;
  int plane = 0;  // levels * plane < 2^31: lanes index with int32
  int stride = 0;
  float sigmas[kTableSize] = {};  // the first `count`, then padding
  int count = 0;                  // levels, at most kTableSize
  const int* start = nullptr;
  int start_count = 0;
  float lut_per_px = 0.f;
};

// Everything ShadeRow needs but the row itself (ShadeLayer in ir_synthesis.cc).
struct ShadeArgs {
  int width = 0;
  // IrMaterial's fields by material, each table max(material_count, kTableSize) long.
  const float* albedo = nullptr;
  const float* specular = nullptr;
  const float* shininess = nullptr;
  int material_count = 0;
  float R_P_C[9] = {};  // row-major
  float t_P_C[3] = {}, c_P[3] = {};
  float projector_e = 0.f, ambient_e = 0.f, footprint = 0.f, coc_scale = 0.f, inv_focus = 0.f;
  float box_sigma2 = 0.f;  // the pattern pixel's own sigma, squared
  float pfx = 0.f, pfy = 0.f, pcx = 0.f, pcy = 0.f;
  int pattern_cols = 0, pattern_rows = 0;  // the displayed image; the stack has a zero border of 1
  LevelStack pattern;
};

// One row of a layer (width pixels), and of layer 0 where a later layer is added to it.
struct ShadeRowData {
  const float* p_C = nullptr;       // 3 per pixel
  const float* normal_C = nullptr;  // 3 per pixel
  const int* material = nullptr;
  const uint8_t* lit = nullptr;
  float* electrons = nullptr;
  // Null for layer 0 (electrons written); else layer 0's row and radiance (electrons added).
  const float* base_p_C = nullptr;
  const float* base_normal_C = nullptr;
  const int* base_material = nullptr;
  const uint8_t* base_lit = nullptr;
  const float* base_electrons = nullptr;
};

// Everything FinishRow needs but the row: camera blur blend, noise, full well, quantization.
struct FinishArgs {
  int width = 0;
  LevelStack camera;  // count 1: electrons are read in place (no blend)
  bool noise = false, shot = false;
  uint64_t noise_seed = 0;
  float gain = 0.f, full_well = 0.f, read = 0.f;
  float speckle2 = 0.f;  // the speckle contrast squared
  int max_dn = 0;
};

struct FinishRowData {
  int y = 0;
  const float* sigma = nullptr;          // camera blur sigma per pixel (null for one level)
  const float* camera_levels = nullptr;  // row y of level 0 of the stack
  float* electrons = nullptr;            // out: the blend (may alias camera_levels for one level)
  uint16_t* ir = nullptr;
};

// The camera's blur sigma per pixel (Synthesize's defocus pass): the focused lens' PSF plus the
// defocus disk of layer 0's hit (sigma coc / 4).
struct DefocusArgs {
  int width = 0;
  float scale = 0.f, inv_focus = 0.f, psf2 = 0.f;
};

// Writes row's sigmas, and their smallest and largest value into *lo and *hi.
struct DefocusRowData {
  const float* p_C = nullptr;  // 3 per pixel
  float* sigma = nullptr;
  float* lo = nullptr;
  float* hi = nullptr;
};

// The instantiations, one per instruction set (the ones compiled in: see the macros below).
void ShadeRowScalar(const ShadeArgs& args, const ShadeRowData& row);
void FinishRowScalar(const FinishArgs& args, const FinishRowData& row);
void DefocusRowScalar(const DefocusArgs& args, const DefocusRowData& row);
void ShadeRowAvx2(const ShadeArgs& args, const ShadeRowData& row);
void FinishRowAvx2(const FinishArgs& args, const FinishRowData& row);
void DefocusRowAvx2(const DefocusArgs& args, const DefocusRowData& row);
void ShadeRowAvx512(const ShadeArgs& args, const ShadeRowData& row);
void FinishRowAvx512(const FinishArgs& args, const FinishRowData& row);
void DefocusRowAvx512(const DefocusArgs& args, const DefocusRowData& row);

// One entry of the synthesizer's dispatch table (ir_synthesis.cc, ResolveKernel).
struct Kernel {
  Isa isa;
  void (*shade)(const ShadeArgs& args, const ShadeRowData& row);
  void (*finish)(const FinishArgs& args, const FinishRowData& row);
  void (*defocus)(const DefocusArgs& args, const DefocusRowData& row);
};

// The level pair of one sigma (FindLevel, one value at a time): the blur levels a row blends.
void FindLevelScalar(const LevelStack& table, float sigma, int* k, float* w);

}  // namespace romunect::ir_synthesis_internal

// AVX2 and AVX-512 code is compiled under `#pragma GCC target` and runs only where the CPU
// reports the instruction set.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROMUNECT_IR_KERNEL_AVX2 1
#define ROMUNECT_IR_KERNEL_AVX512 1
#endif
