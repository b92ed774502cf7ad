// The IR synthesis row kernels as one template over a lane type L (ir_synthesis_kernel.h):
// ScalarLanes below (one pixel: F = float, I = int32_t, M = bool), and the AVX2 and AVX-512
// lanes of ir_synthesis_kernel_avx2.cc / ir_synthesis_kernel_avx512.cc. L provides
//   F, I, M: float, int32 and mask lanes, F and I with the arithmetic operators and
//     comparisons (giving M); M with & and !; F from a float and I from an int32 broadcast;
//   Load, LoadU8 (zero-extended), LoadXyz (three interleaved floats), Store, StoreU16 (low 16
//     bits), Iota (lane numbers), Gather (optionally masked: 0 where the mask is clear),
//     GatherPair (masked: base[i] and base[i + 1]), Lookup (table[i], 0 <= i < kTableSize),
//     Select (m ? a : b), Sqrt, Abs, ToFloat, Trunc (towards zero), Round (current rounding
//     mode), Bits, FromBits, Any, All, and HashBits (the top and middle 24 bits of
//     HashCounter(seed, counter + lane)).
// Every lane performs the IEEE operations of the scalar code in its order (Eigen's: a dot
// product of three is a0 + (a1 + a2)); where the scalar code branches, lanes compute both sides
// and select, and a branch taken by no lane is skipped. Included by one unit per instruction
// set, inside an anonymous namespace of its own.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "ir_synthesis_kernel.h"
#include "romunect/sensor/pattern.h"

namespace romunect::ir_synthesis_internal {
namespace {

struct ScalarLanes {
  static constexpr int kLanes = 1;
  using F = float;
  using I = int32_t;
  using M = bool;
  static F Load(const float* p) { return *p; }
  static I Load(const int32_t* p) { return *p; }
  static I LoadU8(const uint8_t* p) { return *p; }
  static void LoadXyz(const float* p, F* x, F* y, F* z) {
    *x = p[0];
    *y = p[1];
    *z = p[2];
  }
  static void Store(float* p, F v) { *p = v; }
  static void StoreU16(uint16_t* p, I v) { *p = static_cast<uint16_t>(v); }
  static I Iota() { return 0; }
  static F Gather(const float* base, I i) { return base[i]; }
  static F Gather(const float* base, I i, M m) { return m ? base[i] : 0.f; }
  static I Gather(const int32_t* base, I i) { return base[i]; }
  static F Lookup(const float* table, I i) { return table[i]; }
  static void GatherPair(const float* base, I i, M m, F* first, F* second) {
    *first = m ? base[i] : 0.f;
    *second = m ? base[i + 1] : 0.f;
  }
  static F Select(M m, F a, F b) { return m ? a : b; }
  static I Select(M m, I a, I b) { return m ? a : b; }
  static F Sqrt(F v) { return std::sqrt(v); }
  static F Abs(F v) { return std::abs(v); }
  static F ToFloat(I v) { return static_cast<float>(v); }
  static I Trunc(F v) { return static_cast<int32_t>(v); }
  static F Round(F v) { return std::nearbyint(v); }
  static I Bits(F v) {
    I bits;
    std::memcpy(&bits, &v, sizeof bits);
    return bits;
  }
  static F FromBits(I bits) {
    F v;
    std::memcpy(&v, &bits, sizeof v);
    return v;
  }
  static bool Any(M m) { return m; }
  static bool All(M m) { return m; }
  static void HashBits(uint64_t seed, uint64_t counter, I* high, I* middle) {
    const uint64_t h = HashCounter(seed, counter);
    *high = static_cast<I>(h >> 40);
    *middle = static_cast<I>((h >> 8) & 0xFFFFFFu);
  }
};

// std::isfinite
template <class L>
typename L::M IsFinite(typename L::F v) {
  return !((L::Bits(v) & 0x7F800000) == 0x7F800000);
}

// ln(x) for normal x > 0: the exponent plus the series 2 atanh(t), t = (m - 1) / (m + 1) with
// the mantissa m in [sqrt(1/2), sqrt(2)), so |t| < 0.172 and four terms leave < 3e-8.
template <class L>
typename L::F FastLog(typename L::F x) {
  using F = typename L::F;
  using I = typename L::I;
  const I bits = L::Bits(x);
  I mantissa = (bits & 0x7FFFFF) | 0x3F800000;
  const I high = L::Select(mantissa > 0x3FB504F3, I(1), I(0));  // m > sqrt(2): halve it
  mantissa = mantissa - (high << 23);
  const F exponent = L::ToFloat(((bits >> 23) & 0xFF) - 127 + high);
  const F m = L::FromBits(mantissa);
  const F t = (m - 1.f) / (m + 1.f), t2 = t * t;
  return exponent * 0.693147181f + 2.f * t * (1.f + t2 * (1.f / 3.f + t2 * (0.2f + t2 * (1.f / 7.f))));
}

// exp(x) for x in [-87, 0]: 2^(integer part) times a degree-6 Taylor polynomial of 2^f on
// [-0.5, 0.5]: relative error < 2e-7.
template <class L>
typename L::F FastExp(typename L::F x) {
  using F = typename L::F;
  const F y = L::Select(x < -87.f, F(-87.f), x) * 1.44269504f;
  const F n = L::Round(y);
  const F f = (y - n) * 0.693147181f;  // |f| <= ln(2) / 2
  const F p = 1.f + f * (1.f + f * (0.5f + f * (1.f / 6.f + f * (1.f / 24.f + f * (1.f / 120.f + f * (1.f / 720.f))))));
  return p * L::FromBits((L::Trunc(n) + 127) << 23);
}

// cos and sin of 2 pi u for u in [0, 1): the quadrant, then Taylor series of degree 10 and 11
// on [0, pi/2]: error < 1e-7.
template <class L>
void FastCosSin2Pi(typename L::F u, typename L::F* c, typename L::F* s) {
  using F = typename L::F;
  using I = typename L::I;
  const F q = u * 4.f;
  I quadrant = L::Trunc(q);
  quadrant = L::Select(quadrant > 3, I(3), quadrant);
  const F a = (q - L::ToFloat(quadrant)) * 1.57079633f, a2 = a * a;
  const F sin_a = a * (1.f - a2 / 6.f * (1.f - a2 / 20.f * (1.f - a2 / 42.f * (1.f - a2 / 72.f * (1.f - a2 / 110.f)))));
  const F cos_a = 1.f - a2 / 2.f * (1.f - a2 / 12.f * (1.f - a2 / 30.f * (1.f - a2 / 56.f * (1.f - a2 / 90.f))));
  // Quadrant k turns (cos a, sin a) by k * 90 degrees.
  const typename L::M q0 = quadrant == 0, q1 = quadrant == 1, q2 = quadrant == 2;
  *c = L::Select(q0, cos_a, L::Select(q1, -sin_a, L::Select(q2, -cos_a, sin_a)));
  *s = L::Select(q0, sin_a, L::Select(q1, cos_a, L::Select(q2, -sin_a, -cos_a)));
}

// The pair of levels of a sigma (count >= 2), in lanes: level k and weight w of
// (1 - w) level[k] + w level[k + 1]; sigmas below the first level or above the last take it
// whole. Also used one value at a time (ScalarLanes) for the range of levels a frame blends.
template <class L>
void FindLevel(const LevelStack& table, typename L::F sigma, typename L::I* k, typename L::F* w) {
  using F = typename L::F;
  using I = typename L::I;
  using M = typename L::M;
  const int n = table.count;
  // The start bin, clamped first so that no lane converts an out-of-range value.
  const F last_bin = static_cast<float>(table.start_count - 1);
  F bin = sigma * table.lut_per_px;
  bin = L::Select(bin < last_bin, bin, last_bin);
  bin = L::Select(bin > 0.f, bin, F(0.f));
  I i = L::Gather(table.start, L::Trunc(bin));
  for (;;) {
    const M up = (i < n - 2) & (sigma > L::Lookup(table.sigmas, i + 1));
    if (!L::Any(up)) break;
    i = i + L::Select(up, I(1), I(0));
  }
  const F lo = L::Lookup(table.sigmas, i), hi = L::Lookup(table.sigmas, i + 1);
  const M below = sigma <= table.sigmas[0], above = sigma >= table.sigmas[n - 1];
  *k = L::Select(below, I(0), L::Select(above, I(n - 2), i));
  *w = L::Select(below, F(0.f), L::Select(above, F(1.f), (sigma - lo) / (hi - lo)));
}

// ShadeLayer (ir_synthesis.cc) for the L pixels from column x.
template <class L>
void ShadePixels(const ShadeArgs& a, const ShadeRowData& row, int x) {
  using F = typename L::F;
  using I = typename L::I;
  using M = typename L::M;
  const I material = L::Load(row.material + x);
  const I lit = L::LoadU8(row.lit + x);
  F px, py, pz, nx, ny, nz;
  L::LoadXyz(row.p_C + 3 * x, &px, &py, &pz);
  L::LoadXyz(row.normal_C + 3 * x, &nx, &ny, &nz);
  // A later layer's sample that repeats layer 0's hit bit for bit shades the same.
  M same = false;
  if (row.base_electrons != nullptr) {
    F bx, by, bz, bnx, bny, bnz;
    L::LoadXyz(row.base_p_C + 3 * x, &bx, &by, &bz);
    L::LoadXyz(row.base_normal_C + 3 * x, &bnx, &bny, &bnz);
    same = (L::Bits(px) == L::Bits(bx)) & (L::Bits(py) == L::Bits(by)) & (L::Bits(pz) == L::Bits(bz)) &
           (L::Bits(nx) == L::Bits(bnx)) & (L::Bits(ny) == L::Bits(bny)) & (L::Bits(nz) == L::Bits(bnz)) &
           (material == L::Load(row.base_material + x)) & (lit == L::LoadU8(row.base_lit + x));
    if (L::All(same)) {
      L::Store(row.electrons + x, L::Load(row.electrons + x) + L::Load(row.base_electrons + x));
      return;
    }
  }
  const M valid = (material >= 0) & (material < a.material_count) & IsFinite<L>(pz);
  const I mat = L::Select(valid, material, I(0));
  // The material's field, 0 where m is clear.
  auto field = [&](const float* table, M m) {
    return a.material_count <= kTableSize ? L::Select(m, L::Lookup(table, mat), F(0.f)) : L::Gather(table, mat, m);
  };
  const F albedo = field(a.albedo, valid);
  F e = a.ambient_e * albedo;
  const float* R = a.R_P_C;
  const F ppx = R[0] * px + (R[1] * py + R[2] * pz) + a.t_P_C[0];
  const F ppy = R[3] * px + (R[4] * py + R[5] * pz) + a.t_P_C[1];
  const F ppz = R[6] * px + (R[7] * py + R[8] * pz) + a.t_P_C[2];
  const M lit_here = valid & !(lit == 0) & (ppz > 0.f);
  if (a.projector_e > 0.f && L::Any(lit_here)) {
    const F inv_z = 1.f / ppz;
    // Projector defocus (disk of diameter coc: sigma coc / 4) and the camera pixel's
    // footprint on the pattern, both in projector pixels.
    const F coc = a.coc_scale * L::Abs(inv_z - a.inv_focus);
    const F fp = a.footprint * pz * inv_z;
    const F sigma = L::Sqrt(a.box_sigma2 + fp * fp + 0.0625f * coc * coc);
    const F xp = a.pfx * ppx * inv_z + a.pcx, yp = a.pfy * ppy * inv_z + a.pcy;
    // The pattern there (PatternAt): off the pattern it is dark.
    const M on = lit_here & (xp > -1.f) & (yp > -1.f) & (xp < static_cast<float>(a.pattern_cols)) &
                 (yp < static_cast<float>(a.pattern_rows));
    I k;
    F w;
    FindLevel<L>(a.pattern, sigma, &k, &w);
    // In the padded levels, pixel (x, y) sits at (x + 1, y + 1); all four taps are inside.
    const F xs = L::Select(on, xp + 1.f, F(0.f)), ys = L::Select(on, yp + 1.f, F(0.f));
    const I x0 = L::Trunc(xs), y0 = L::Trunc(ys);
    const F fx = xs - L::ToFloat(x0), fy = ys - L::ToFloat(y0);
    const int stride = a.pattern.stride;
    const I tap = k * a.pattern.plane + y0 * stride + x0;
    auto bilinear = [&](I i, M m) {
      F r00, r01, r10, r11;
      L::GatherPair(a.pattern.pixels, i, m, &r00, &r01);
      L::GatherPair(a.pattern.pixels, i + stride, m, &r10, &r11);
      return (1.f - fy) * ((1.f - fx) * r00 + fx * r01) + fy * ((1.f - fx) * r10 + fx * r11);
    };
    const F value = bilinear(tap, on);
    const M blend = on & (w > 0.f);
    F pattern = value;
    if (L::Any(blend))
      pattern = L::Select(blend, (1.f - w) * value + w * bilinear(tap + a.pattern.plane, blend), value);
    const M bright = on & (pattern > 0.f);
    if (L::Any(bright)) {
      F tx = a.c_P[0] - px, ty = a.c_P[1] - py, tz = a.c_P[2] - pz;  // to the light
      const F d2 = tx * tx + (ty * ty + tz * tz);
      const F inv_d = 1.f / L::Sqrt(d2);
      tx = tx * inv_d;
      ty = ty * inv_d;
      tz = tz * inv_d;
      const F cos_in = nx * tx + (ny * ty + nz * tz);
      const M facing = bright & (cos_in > 0.f);
      F brdf_pi = albedo;  // pi * BRDF
      const F specular = field(a.specular, facing);
      const M shiny = facing & (specular > 0.f);
      if (L::Any(shiny)) {
        const F shininess = field(a.shininess, shiny);
        const F two_cos = 2.f * cos_in;
        const F rx = two_cos * nx - tx, ry = two_cos * ny - ty, rz = two_cos * nz - tz;  // reflected
        const F cos_r = -(rx * px + (ry * py + rz * pz)) / L::Sqrt(px * px + (py * py + pz * pz));
        const M lobe = shiny & (cos_r > 0.f);
        brdf_pi = L::Select(
            lobe, brdf_pi + specular * 0.5f * (shininess + 2.f) * FastExp<L>(shininess * FastLog<L>(cos_r)), brdf_pi);
      }
      e = L::Select(facing, e + a.projector_e * pattern * brdf_pi * cos_in / d2, e);
    }
  }
  e = L::Select(valid, e, F(0.f));
  if (row.base_electrons == nullptr) {
    L::Store(row.electrons + x, e);
  } else {
    L::Store(row.electrons + x, L::Load(row.electrons + x) + L::Select(same, L::Load(row.base_electrons + x), e));
  }
}

// Synthesize's last pass (ir_synthesis.cc) for the L pixels from column x: the camera blur
// blend, shot and read noise, full well, gain and quantization.
template <class L>
void FinishPixels(const FinishArgs& a, const FinishRowData& row, int x) {
  using F = typename L::F;
  using I = typename L::I;
  using M = typename L::M;
  F e;
  if (a.camera.count == 1) {
    e = L::Load(row.camera_levels + x);
  } else {
    I k;
    F w;
    FindLevel<L>(a.camera, L::Load(row.sigma + x), &k, &w);
    const I i = k * a.camera.plane + (L::Iota() + x);
    const F low = L::Gather(row.camera_levels, i);
    const M blend = w > 0.f;
    e = low;
    if (L::Any(blend)) {
      e = L::Select(blend, (1.f - w) * low + w * L::Gather(row.camera_levels, i + a.camera.plane, blend), low);
    }
  }
  if (row.electrons != row.camera_levels) L::Store(row.electrons + x, e);
  if (a.noise) {
    // Two standard normal values: Box-Muller on the two halves of a hash of (seed, pixel), so
    // each pixel's values depend on nothing else.
    I high, middle;
    L::HashBits(a.noise_seed, static_cast<uint64_t>(row.y) * a.width + x, &high, &middle);
    const F u1 = (L::ToFloat(high) + 0.5f) * 0x1p-24f;  // (0, 1)
    const F u2 = L::ToFloat(middle) * 0x1p-24f;         // [0, 1)
    const F r = L::Sqrt(-2.f * FastLog<L>(u1));
    F c, s;
    FastCosSin2Pi<L>(u2, &c, &s);
    const F g1 = r * c, g2 = r * s;
    // Shot noise and speckle share g1: independent Gaussians add their variances.
    const F lit = L::Select(e < 0.f, F(0.f), e);
    const F variance = (a.shot ? lit : F(0.f)) + a.speckle2 * lit * lit;
    e = e + (L::Sqrt(variance) * g1 + a.read * g2);
  }
  e = L::Select(e < 0.f, F(0.f), L::Select(a.full_well < e, F(a.full_well), e));  // std::clamp
  const I dn = L::Trunc(a.gain * e + 0.5f);
  L::StoreU16(row.ir + x, L::Select(a.max_dn < dn, I(a.max_dn), dn));
}

// The camera blur sigma of the L pixels from column x; *lo and *hi take the smallest and the
// largest so far, per lane.
template <class L>
void DefocusPixels(const DefocusArgs& a, const DefocusRowData& row, int x, typename L::F* lo, typename L::F* hi) {
  using F = typename L::F;
  F px, py, z;
  L::LoadXyz(row.p_C + 3 * x, &px, &py, &z);
  const typename L::M hit = IsFinite<L>(z) & (z > 0.f);
  const F coc = L::Select(hit, a.scale * L::Abs(1.f / z - a.inv_focus), F(0.f));
  const F s = L::Sqrt(a.psf2 + 0.0625f * coc * coc);
  L::Store(row.sigma + x, s);
  *lo = L::Select(s < *lo, s, *lo);  // std::min
  *hi = L::Select(*hi < s, s, *hi);  // std::max
}

// One row: L lanes at a time, the last width % kLanes pixels one by one.
template <class L>
void ShadeRow(const ShadeArgs& a, const ShadeRowData& row) {
  int x = 0;
  for (; x + L::kLanes <= a.width; x += L::kLanes) ShadePixels<L>(a, row, x);
  for (; x < a.width; ++x) ShadePixels<ScalarLanes>(a, row, x);
}

template <class L>
void FinishRow(const FinishArgs& a, const FinishRowData& row) {
  int x = 0;
  for (; x + L::kLanes <= a.width; x += L::kLanes) FinishPixels<L>(a, row, x);
  for (; x < a.width; ++x) FinishPixels<ScalarLanes>(a, row, x);
}

// The smallest and largest sigma do not depend on the order they are taken in (no NaN, no -0).
template <class L>
void DefocusRow(const DefocusArgs& a, const DefocusRowData& row) {
  typename L::F lo = std::numeric_limits<float>::max(), hi = 0.f;
  int x = 0;
  for (; x + L::kLanes <= a.width; x += L::kLanes) DefocusPixels<L>(a, row, x, &lo, &hi);
  float lanes_lo[L::kLanes], lanes_hi[L::kLanes];
  L::Store(lanes_lo, lo);
  L::Store(lanes_hi, hi);
  float row_lo = lanes_lo[0], row_hi = lanes_hi[0];
  for (int l = 1; l < L::kLanes; ++l) {
    row_lo = std::min(row_lo, lanes_lo[l]);
    row_hi = std::max(row_hi, lanes_hi[l]);
  }
  for (; x < a.width; ++x) DefocusPixels<ScalarLanes>(a, row, x, &row_lo, &row_hi);
  *row.lo = row_lo;
  *row.hi = row_hi;
}

}  // namespace
}  // namespace romunect::ir_synthesis_internal
