// The IR synthesis row kernels on AVX2: 8 pixels per vector, masks as all-ones lanes.
// Compiled for AVX2 under a pragma, not a build flag, and called only where the CPU reports it
// (ir_synthesis.cc's dispatch). Standard headers and the shared structs come before the pragma
// so that their inline functions stay baseline code.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "ir_synthesis_kernel.h"
#include "romunect/sensor/pattern.h"

#if ROMUNECT_IR_KERNEL_AVX2
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2")
#include "ir_synthesis_kernel_rows.h"

namespace romunect::ir_synthesis_internal {
namespace {

// Component c of pixel j is float 3 j + c of 8 pixels: lane l of the blend takes the one of
// the three vectors whose float 8 s + l is a component c (3 and 8 are coprime, so exactly
// one does), and the permutation puts pixel j's float from lane (3 j + c) mod 8 into lane j.
struct XyzShuffle {
  int from_b = 0, from_c = 0;  // blend immediates
  alignas(32) int32_t index[8] = {};
};
constexpr XyzShuffle MakeXyzShuffle(int comp) {
  XyzShuffle s;
  for (int l = 0; l < 8; ++l) {
    if ((8 + l) % 3 == comp) s.from_b |= 1 << l;
    if ((16 + l) % 3 == comp) s.from_c |= 1 << l;
    s.index[l] = (3 * l + comp) % 8;
  }
  return s;
}
constexpr XyzShuffle kXyzShuffles[3] = {MakeXyzShuffle(0), MakeXyzShuffle(1), MakeXyzShuffle(2)};

template <int kComp>
__m256 Deinterleave(__m256 a, __m256 b, __m256 c) {
  constexpr XyzShuffle s = kXyzShuffles[kComp];
  const __m256 t = _mm256_blend_ps(_mm256_blend_ps(a, b, s.from_b), c, s.from_c);
  return _mm256_permutevar8x32_ps(t, _mm256_load_si256(reinterpret_cast<const __m256i*>(kXyzShuffles[kComp].index)));
}

// a * b mod 2^64 per 64-bit lane, from 32 x 32-bit products (AVX2 has no 64-bit multiply).
__m256i MulLo64(__m256i a, __m256i b) {
  const __m256i cross = _mm256_add_epi64(_mm256_mul_epu32(_mm256_srli_epi64(a, 32), b),
                                         _mm256_mul_epu32(a, _mm256_srli_epi64(b, 32)));
  return _mm256_add_epi64(_mm256_mul_epu32(a, b), _mm256_slli_epi64(cross, 32));
}

// The low 32 bits of the 64-bit lanes of lo (lanes 0-3) and hi (lanes 4-7).
__m256i Narrow64(__m256i lo, __m256i hi) {
  const __m256 even = _mm256_shuffle_ps(_mm256_castsi256_ps(lo), _mm256_castsi256_ps(hi), _MM_SHUFFLE(2, 0, 2, 0));
  return _mm256_permute4x64_epi64(_mm256_castps_si256(even), _MM_SHUFFLE(3, 1, 2, 0));
}

// Avx2Lanes' lane types. Their operators are free functions: GCC 12 compiles friends defined in a
// class without the pragma's target.
struct Mask {
  __m256 v;
  Mask(bool b) : v(_mm256_castsi256_ps(_mm256_set1_epi32(b ? -1 : 0))) {}  // NOLINT: broadcast
  Mask(__m256 m) : v(m) {}                                                 // NOLINT
};
struct Floats {
  __m256 v;
  Floats() = default;
  Floats(__m256 x) : v(x) {}                 // NOLINT
  Floats(float s) : v(_mm256_set1_ps(s)) {}  // NOLINT: broadcast
};
struct Ints {
  __m256i v;
  Ints() = default;
  Ints(__m256i x) : v(x) {}                     // NOLINT
  Ints(int32_t s) : v(_mm256_set1_epi32(s)) {}  // NOLINT: broadcast
};
Mask operator&(Mask a, Mask b) { return _mm256_and_ps(a.v, b.v); }
Mask operator!(Mask a) { return _mm256_xor_ps(a.v, _mm256_castsi256_ps(_mm256_set1_epi32(-1))); }
Floats operator+(Floats a, Floats b) { return _mm256_add_ps(a.v, b.v); }
Floats operator-(Floats a, Floats b) { return _mm256_sub_ps(a.v, b.v); }
Floats operator*(Floats a, Floats b) { return _mm256_mul_ps(a.v, b.v); }
Floats operator/(Floats a, Floats b) { return _mm256_div_ps(a.v, b.v); }
Floats operator-(Floats a) { return _mm256_xor_ps(a.v, _mm256_set1_ps(-0.f)); }  // the sign bit, as -x
Mask operator<(Floats a, Floats b) { return _mm256_cmp_ps(a.v, b.v, _CMP_LT_OQ); }
Mask operator>(Floats a, Floats b) { return _mm256_cmp_ps(a.v, b.v, _CMP_GT_OQ); }
Mask operator<=(Floats a, Floats b) { return _mm256_cmp_ps(a.v, b.v, _CMP_LE_OQ); }
Mask operator>=(Floats a, Floats b) { return _mm256_cmp_ps(a.v, b.v, _CMP_GE_OQ); }
Ints operator+(Ints a, Ints b) { return _mm256_add_epi32(a.v, b.v); }
Ints operator-(Ints a, Ints b) { return _mm256_sub_epi32(a.v, b.v); }
Ints operator*(Ints a, Ints b) { return _mm256_mullo_epi32(a.v, b.v); }
Ints operator&(Ints a, Ints b) { return _mm256_and_si256(a.v, b.v); }
Ints operator|(Ints a, Ints b) { return _mm256_or_si256(a.v, b.v); }
Ints operator<<(Ints a, int n) { return _mm256_sll_epi32(a.v, _mm_cvtsi32_si128(n)); }
Ints operator>>(Ints a, int n) { return _mm256_sra_epi32(a.v, _mm_cvtsi32_si128(n)); }
Mask operator==(Ints a, Ints b) { return _mm256_castsi256_ps(_mm256_cmpeq_epi32(a.v, b.v)); }
Mask operator<(Ints a, Ints b) { return _mm256_castsi256_ps(_mm256_cmpgt_epi32(b.v, a.v)); }
Mask operator>(Ints a, Ints b) { return _mm256_castsi256_ps(_mm256_cmpgt_epi32(a.v, b.v)); }
Mask operator>=(Ints a, Ints b) { return !(a < b); }

struct Avx2Lanes {
  static constexpr int kLanes = 8;
  using M = Mask;
  using F = Floats;
  using I = Ints;

  static F Load(const float* p) { return _mm256_loadu_ps(p); }
  static I Load(const int32_t* p) { return _mm256_loadu_si256(reinterpret_cast<const __m256i*>(p)); }
  static I LoadU8(const uint8_t* p) {
    return _mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(p)));
  }
  static void LoadXyz(const float* p, F* x, F* y, F* z) {
    const __m256 a = _mm256_loadu_ps(p), b = _mm256_loadu_ps(p + 8), c = _mm256_loadu_ps(p + 16);
    *x = Deinterleave<0>(a, b, c);
    *y = Deinterleave<1>(a, b, c);
    *z = Deinterleave<2>(a, b, c);
  }
  static void Store(float* p, F v) { _mm256_storeu_ps(p, v.v); }
  static void StoreU16(uint16_t* p, I v) {
    // The low halves of the 32-bit lanes, in each 128-bit half, then the two halves together.
    const __m256i low = _mm256_shuffle_epi8(v.v,
                                            _mm256_setr_epi8(0, 1, 4, 5, 8, 9, 12, 13, -1, -1, -1, -1, -1, -1, -1, -1,
                                                             0, 1, 4, 5, 8, 9, 12, 13, -1, -1, -1, -1, -1, -1, -1, -1));
    _mm_storeu_si128(reinterpret_cast<__m128i*>(p),
                     _mm256_castsi256_si128(_mm256_permute4x64_epi64(low, _MM_SHUFFLE(3, 1, 2, 0))));
  }
  static I Iota() { return _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7); }
  static F Gather(const float* base, I i) { return _mm256_i32gather_ps(base, i.v, 4); }
  static F Gather(const float* base, I i, M m) {
    return _mm256_mask_i32gather_ps(_mm256_setzero_ps(), base, i.v, m.v, 4);
  }
  static I Gather(const int32_t* base, I i) {
    return _mm256_i32gather_epi32(reinterpret_cast<const int*>(base), i.v, 4);
  }
  static F Lookup(const float* table, I i) {
    const __m256 low = _mm256_permutevar8x32_ps(_mm256_loadu_ps(table), i.v);
    const __m256 high = _mm256_permutevar8x32_ps(_mm256_loadu_ps(table + 8), i.v);  // the low 3 bits of i
    return _mm256_blendv_ps(low, high, _mm256_castsi256_ps(_mm256_cmpgt_epi32(i.v, _mm256_set1_epi32(7))));
  }
  // Both floats of a pair in one 64-bit element: half the loads of two gathers.
  static void GatherPair(const float* base, I i, M m, F* first, F* second) {
    const __m256i mask = _mm256_castps_si256(m.v);
    __m256 half[2];
    for (int h = 0; h < 2; ++h) {
      const __m128i index = h == 0 ? _mm256_castsi256_si128(i.v) : _mm256_extracti128_si256(i.v, 1);
      const __m128i lanes = h == 0 ? _mm256_castsi256_si128(mask) : _mm256_extracti128_si256(mask, 1);
      half[h] = _mm256_castpd_ps(_mm256_mask_i32gather_pd(_mm256_setzero_pd(), reinterpret_cast<const double*>(base),
                                                          index, _mm256_castsi256_pd(_mm256_cvtepi32_epi64(lanes)), 4));
    }
    // As in Narrow64: the even (odd) floats of both halves, in lane order.
    *first = _mm256_castpd_ps(_mm256_permute4x64_pd(
        _mm256_castps_pd(_mm256_shuffle_ps(half[0], half[1], _MM_SHUFFLE(2, 0, 2, 0))), _MM_SHUFFLE(3, 1, 2, 0)));
    *second = _mm256_castpd_ps(_mm256_permute4x64_pd(
        _mm256_castps_pd(_mm256_shuffle_ps(half[0], half[1], _MM_SHUFFLE(3, 1, 3, 1))), _MM_SHUFFLE(3, 1, 2, 0)));
  }
  static F Select(M m, F a, F b) { return _mm256_blendv_ps(b.v, a.v, m.v); }
  static I Select(M m, I a, I b) {
    return _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(b.v), _mm256_castsi256_ps(a.v), m.v));
  }
  static F Sqrt(F v) { return _mm256_sqrt_ps(v.v); }
  static F Abs(F v) { return _mm256_and_ps(v.v, _mm256_castsi256_ps(_mm256_set1_epi32(0x7FFFFFFF))); }
  static F ToFloat(I v) { return _mm256_cvtepi32_ps(v.v); }
  static I Trunc(F v) { return _mm256_cvttps_epi32(v.v); }
  static F Round(F v) { return _mm256_round_ps(v.v, _MM_FROUND_CUR_DIRECTION | _MM_FROUND_NO_EXC); }
  static I Bits(F v) { return _mm256_castps_si256(v.v); }
  static F FromBits(I v) { return _mm256_castsi256_ps(v.v); }
  static bool Any(M m) { return _mm256_movemask_ps(m.v) != 0; }
  static bool All(M m) { return _mm256_movemask_ps(m.v) == 0xFF; }

  // HashCounter (pattern.cc) on four 64-bit counters per vector.
  static __m256i HashRound(__m256i z) {
    z = MulLo64(_mm256_xor_si256(z, _mm256_srli_epi64(z, 30)), _mm256_set1_epi64x(0xBF58476D1CE4E5B9LL));
    z = MulLo64(_mm256_xor_si256(z, _mm256_srli_epi64(z, 27)), _mm256_set1_epi64x(0x94D049BB133111EBLL));
    return _mm256_xor_si256(z, _mm256_srli_epi64(z, 31));
  }
  static void HashBits(uint64_t seed, uint64_t counter, I* high, I* middle) {
    const uint64_t first = seed * 0x9E3779B97F4A7C15ULL + counter + 0x632BE59BD9B4E019ULL;
    const __m256i step = _mm256_setr_epi64x(0, 1, 2, 3);
    const __m256i golden = _mm256_set1_epi64x(static_cast<int64_t>(0x9E3779B97F4A7C15ULL));
    __m256i h[2];
    for (int half = 0; half < 2; ++half) {
      const __m256i z = _mm256_add_epi64(_mm256_set1_epi64x(static_cast<int64_t>(first + 4 * half)), step);
      h[half] = HashRound(_mm256_add_epi64(HashRound(z), golden));
    }
    *high = Narrow64(_mm256_srli_epi64(h[0], 40), _mm256_srli_epi64(h[1], 40));
    *middle = _mm256_and_si256(Narrow64(_mm256_srli_epi64(h[0], 8), _mm256_srli_epi64(h[1], 8)),
                               _mm256_set1_epi32(0xFFFFFF));
  }
};

}  // namespace

void ShadeRowAvx2(const ShadeArgs& args, const ShadeRowData& row) { ShadeRow<Avx2Lanes>(args, row); }
void FinishRowAvx2(const FinishArgs& args, const FinishRowData& row) { FinishRow<Avx2Lanes>(args, row); }
void DefocusRowAvx2(const DefocusArgs& args, const DefocusRowData& row) { DefocusRow<Avx2Lanes>(args, row); }

}  // namespace romunect::ir_synthesis_internal

#pragma GCC pop_options
#endif  // ROMUNECT_IR_KERNEL_AVX2
