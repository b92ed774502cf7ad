// The IR synthesis row kernels on AVX-512 (F and DQ): 16 pixels per vector, masks in mask
// registers. Compiled for AVX-512 under a pragma, not a build flag, and called only where the
// CPU reports it (ir_synthesis.cc). Standard headers and the shared structs come before the
// pragma so that their inline functions stay baseline code.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>

#include "ir_synthesis_kernel.h"
#include "romunect/sensor/pattern.h"

#if ROMUNECT_IR_KERNEL_AVX512
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2,avx512f,avx512dq")
// GCC 12 warns inside its own AVX-512 headers (their _mm512_undefined_* placeholders).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "ir_synthesis_kernel_rows.h"

namespace romunect::ir_synthesis_internal {
namespace {

// Component c of pixel j is float 3 j + c of 16 pixels: lane l of the blend takes the one of
// the three vectors whose float 16 s + l is a component c (3 and 16 are coprime, so exactly
// one does), and the permutation puts pixel j's float from lane (3 j + c) mod 16 into lane j.
struct XyzShuffle {
  __mmask16 from_b = 0, from_c = 0;
  alignas(64) int32_t index[16] = {};
};
constexpr XyzShuffle MakeXyzShuffle(int comp) {
  XyzShuffle s;
  for (int l = 0; l < 16; ++l) {
    if ((16 + l) % 3 == comp) s.from_b = static_cast<__mmask16>(s.from_b | (1u << l));
    if ((32 + l) % 3 == comp) s.from_c = static_cast<__mmask16>(s.from_c | (1u << l));
    s.index[l] = (3 * l + comp) % 16;
  }
  return s;
}
constexpr XyzShuffle kXyzShuffles[3] = {MakeXyzShuffle(0), MakeXyzShuffle(1), MakeXyzShuffle(2)};

// Avx512Lanes' lane types. Their operators are free functions: GCC 12 compiles friends defined in a
// class without the pragma's target.
struct Mask {
  __mmask16 v;
  Mask(bool b) : v(b ? 0xFFFF : 0) {}  // NOLINT: broadcast, as for a scalar bool
  Mask(__mmask16 m) : v(m) {}          // NOLINT
};
struct Floats {
  __m512 v;
  Floats() = default;
  Floats(__m512 x) : v(x) {}                 // NOLINT
  Floats(float s) : v(_mm512_set1_ps(s)) {}  // NOLINT: broadcast
};
struct Ints {
  __m512i v;
  Ints() = default;
  Ints(__m512i x) : v(x) {}                     // NOLINT
  Ints(int32_t s) : v(_mm512_set1_epi32(s)) {}  // NOLINT: broadcast
};
Mask operator&(Mask a, Mask b) { return static_cast<__mmask16>(a.v & b.v); }
Mask operator!(Mask a) { return static_cast<__mmask16>(~a.v); }
Floats operator+(Floats a, Floats b) { return _mm512_add_ps(a.v, b.v); }
Floats operator-(Floats a, Floats b) { return _mm512_sub_ps(a.v, b.v); }
Floats operator*(Floats a, Floats b) { return _mm512_mul_ps(a.v, b.v); }
Floats operator/(Floats a, Floats b) { return _mm512_div_ps(a.v, b.v); }
Floats operator-(Floats a) { return _mm512_xor_ps(a.v, _mm512_set1_ps(-0.f)); }  // the sign bit, as -x
Mask operator<(Floats a, Floats b) { return _mm512_cmp_ps_mask(a.v, b.v, _CMP_LT_OQ); }
Mask operator>(Floats a, Floats b) { return _mm512_cmp_ps_mask(a.v, b.v, _CMP_GT_OQ); }
Mask operator<=(Floats a, Floats b) { return _mm512_cmp_ps_mask(a.v, b.v, _CMP_LE_OQ); }
Mask operator>=(Floats a, Floats b) { return _mm512_cmp_ps_mask(a.v, b.v, _CMP_GE_OQ); }
Ints operator+(Ints a, Ints b) { return _mm512_add_epi32(a.v, b.v); }
Ints operator-(Ints a, Ints b) { return _mm512_sub_epi32(a.v, b.v); }
Ints operator*(Ints a, Ints b) { return _mm512_mullo_epi32(a.v, b.v); }
Ints operator&(Ints a, Ints b) { return _mm512_and_si512(a.v, b.v); }
Ints operator|(Ints a, Ints b) { return _mm512_or_si512(a.v, b.v); }
Ints operator<<(Ints a, int n) { return _mm512_sll_epi32(a.v, _mm_cvtsi32_si128(n)); }
Ints operator>>(Ints a, int n) { return _mm512_sra_epi32(a.v, _mm_cvtsi32_si128(n)); }
Mask operator==(Ints a, Ints b) { return _mm512_cmpeq_epi32_mask(a.v, b.v); }
Mask operator<(Ints a, Ints b) { return _mm512_cmplt_epi32_mask(a.v, b.v); }
Mask operator>(Ints a, Ints b) { return _mm512_cmpgt_epi32_mask(a.v, b.v); }
Mask operator>=(Ints a, Ints b) { return _mm512_cmpge_epi32_mask(a.v, b.v); }

struct Avx512Lanes {
  static constexpr int kLanes = 16;
  using M = Mask;
  using F = Floats;
  using I = Ints;

  static F Load(const float* p) { return _mm512_loadu_ps(p); }
  static I Load(const int32_t* p) { return _mm512_loadu_si512(p); }
  static I LoadU8(const uint8_t* p) {
    return _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(p)));
  }
  static void LoadXyz(const float* p, F* x, F* y, F* z) {
    const __m512 a = _mm512_loadu_ps(p), b = _mm512_loadu_ps(p + 16), c = _mm512_loadu_ps(p + 32);
    F* out[3] = {x, y, z};
    for (int comp = 0; comp < 3; ++comp) {
      const XyzShuffle& s = kXyzShuffles[comp];
      const __m512 t = _mm512_mask_blend_ps(s.from_c, _mm512_mask_blend_ps(s.from_b, a, b), c);
      *out[comp] = _mm512_permutexvar_ps(_mm512_load_si512(s.index), t);
    }
  }
  static void Store(float* p, F v) { _mm512_storeu_ps(p, v.v); }
  static void StoreU16(uint16_t* p, I v) {
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), _mm512_cvtepi32_epi16(v.v));
  }
  static I Iota() { return _mm512_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15); }
  static F Gather(const float* base, I i) { return _mm512_i32gather_ps(i.v, base, 4); }
  static F Gather(const float* base, I i, M m) {
    return _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m.v, i.v, base, 4);
  }
  static I Gather(const int32_t* base, I i) { return _mm512_i32gather_epi32(i.v, base, 4); }
  static F Lookup(const float* table, I i) { return _mm512_permutexvar_ps(i.v, _mm512_loadu_ps(table)); }
  // Both floats of a pair in one 64-bit element: half the loads of two gathers.
  static void GatherPair(const float* base, I i, M m, F* first, F* second) {
    const __m512 lo = _mm512_castpd_ps(_mm512_mask_i32gather_pd(_mm512_setzero_pd(), static_cast<__mmask8>(m.v),
                                                                _mm512_castsi512_si256(i.v), base, 4));
    const __m512 hi = _mm512_castpd_ps(_mm512_mask_i32gather_pd(_mm512_setzero_pd(), static_cast<__mmask8>(m.v >> 8),
                                                                _mm512_extracti64x4_epi64(i.v, 1), base, 4));
    const __m512i even = _mm512_setr_epi32(0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30);
    *first = _mm512_permutex2var_ps(lo, even, hi);
    *second = _mm512_permutex2var_ps(lo, _mm512_add_epi32(even, _mm512_set1_epi32(1)), hi);
  }
  static F Select(M m, F a, F b) { return _mm512_mask_blend_ps(m.v, b.v, a.v); }
  static I Select(M m, I a, I b) { return _mm512_mask_blend_epi32(m.v, b.v, a.v); }
  static F Sqrt(F v) { return _mm512_sqrt_ps(v.v); }
  static F Abs(F v) { return _mm512_abs_ps(v.v); }
  static F ToFloat(I v) { return _mm512_cvtepi32_ps(v.v); }
  static I Trunc(F v) { return _mm512_cvttps_epi32(v.v); }
  static F Round(F v) { return _mm512_roundscale_ps(v.v, _MM_FROUND_CUR_DIRECTION | _MM_FROUND_NO_EXC); }
  static I Bits(F v) { return _mm512_castps_si512(v.v); }
  static F FromBits(I v) { return _mm512_castsi512_ps(v.v); }
  static bool Any(M m) { return m.v != 0; }
  static bool All(M m) { return m.v == 0xFFFF; }

  // HashCounter (pattern.cc) on eight 64-bit counters per vector.
  static __m512i HashRound(__m512i z) {
    z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 30)), _mm512_set1_epi64(0xBF58476D1CE4E5B9LL));
    z = _mm512_mullo_epi64(_mm512_xor_si512(z, _mm512_srli_epi64(z, 27)), _mm512_set1_epi64(0x94D049BB133111EBLL));
    return _mm512_xor_si512(z, _mm512_srli_epi64(z, 31));
  }
  static void HashBits(uint64_t seed, uint64_t counter, I* high, I* middle) {
    const uint64_t first = seed * 0x9E3779B97F4A7C15ULL + counter + 0x632BE59BD9B4E019ULL;
    const __m512i step = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    const __m512i golden = _mm512_set1_epi64(static_cast<int64_t>(0x9E3779B97F4A7C15ULL));
    __m256i hi[2], mid[2];
    for (int half = 0; half < 2; ++half) {
      const __m512i z = _mm512_add_epi64(_mm512_set1_epi64(static_cast<int64_t>(first + 8 * half)), step);
      const __m512i h = HashRound(_mm512_add_epi64(HashRound(z), golden));
      hi[half] = _mm512_cvtepi64_epi32(_mm512_srli_epi64(h, 40));
      mid[half] = _mm512_cvtepi64_epi32(_mm512_srli_epi64(h, 8));
    }
    *high = _mm512_inserti64x4(_mm512_castsi256_si512(hi[0]), hi[1], 1);
    *middle = _mm512_and_si512(_mm512_inserti64x4(_mm512_castsi256_si512(mid[0]), mid[1], 1),
                               _mm512_set1_epi32(0xFFFFFF));
  }
};

}  // namespace

void ShadeRowAvx512(const ShadeArgs& args, const ShadeRowData& row) { ShadeRow<Avx512Lanes>(args, row); }
void FinishRowAvx512(const FinishArgs& args, const FinishRowData& row) { FinishRow<Avx512Lanes>(args, row); }
void DefocusRowAvx512(const DefocusArgs& args, const DefocusRowData& row) { DefocusRow<Avx512Lanes>(args, row); }

}  // namespace romunect::ir_synthesis_internal

#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // ROMUNECT_IR_KERNEL_AVX512
