// The matching kernel on AVX2: 32 shifts = one 32-byte vector, 2 x 16 int16 (operations as in
// depth_engine_kernel_sse2.cc). AVX2 unpacks within 128-bit halves, so the int16 lanes hold the
// shifts in the order 0-7, 16-23 | 8-15, 24-31 (Lane); minima do not care, and the masks come out
// in shift order. Compiled for AVX2 under a pragma, not a build flag, and called
// only where CpuSupports(Isa::kAvx2) (depth_engine.cc's dispatch). Standard headers and the shared
// structs come before the pragma so that their inline functions stay baseline code.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "depth_engine_kernel.h"

#if ROMUNECT_DEPTH_KERNEL_AVX2
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2")
#include "depth_engine_kernel_rows.h"

namespace {

struct Avx2Lanes {
  struct U8 {
    __m256i v;
  };
  struct I16 {
    __m256i v[2];
  };
  static __m256i LoadU(const void* p) { return _mm256_loadu_si256(static_cast<const __m256i*>(p)); }
  static constexpr int Lane(int k) { return ((k >> 3) & 1) * 16 + (k >> 4) * 8 + (k & 7); }
  static U8 AbsDiff(uint8_t obs, const uint8_t* ref) {
    const __m256i o = _mm256_set1_epi8(static_cast<char>(obs));
    const __m256i q = LoadU(ref);
    return U8{_mm256_or_si256(_mm256_subs_epu8(o, q), _mm256_subs_epu8(q, o))};
  }
  static U8 OrBytes(const U8& a, const uint8_t* bytes) { return U8{_mm256_or_si256(a.v, LoadU(bytes))}; }
  static I16 Widen(const U8& a) {
    const __m256i zero = _mm256_setzero_si256();
    return I16{{_mm256_unpacklo_epi8(a.v, zero), _mm256_unpackhi_epi8(a.v, zero)}};
  }
  // a - b in one multiply-add per 16 lanes: bytes (a, b) interleaved times (1, -1).
  static I16 WidenDiff(const U8& a, const U8& b) {
    const __m256i plus_minus = _mm256_set1_epi16(static_cast<int16_t>(0xFF01));
    return I16{{_mm256_maddubs_epi16(_mm256_unpacklo_epi8(a.v, b.v), plus_minus),
                _mm256_maddubs_epi16(_mm256_unpackhi_epi8(a.v, b.v), plus_minus)}};
  }
  static I16 Load(const int16_t* p) { return I16{{LoadU(p), LoadU(p + 16)}}; }
  static void Store(int16_t* p, const I16& a) {
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(p), a.v[0]);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(p + 16), a.v[1]);
  }
  static I16 Add(const I16& a, const I16& b) {
    return I16{{_mm256_add_epi16(a.v[0], b.v[0]), _mm256_add_epi16(a.v[1], b.v[1])}};
  }
  static I16 Sub(const I16& a, const I16& b) {
    return I16{{_mm256_sub_epi16(a.v[0], b.v[0]), _mm256_sub_epi16(a.v[1], b.v[1])}};
  }
  static I16 Min(const I16& a, const I16& b) {
    return I16{{_mm256_min_epi16(a.v[0], b.v[0]), _mm256_min_epi16(a.v[1], b.v[1])}};
  }
  static I16 Or(const I16& a, const I16& b) {
    return I16{{_mm256_or_si256(a.v[0], b.v[0]), _mm256_or_si256(a.v[1], b.v[1])}};
  }
  static int HorizontalMin(const I16& a) {
    const __m256i m = _mm256_min_epi16(a.v[0], a.v[1]);
    const __m128i h = _mm_min_epi16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    // Costs are non-negative int16, so the unsigned minimum (SSE4.1) is the signed one.
    return _mm_cvtsi128_si32(_mm_minpos_epu16(h)) & 0xFFFF;
  }
  // packs interleaves the 128-bit halves, which puts the lanes back in shift order.
  static uint32_t EqualMask(const I16& a, int value) {
    const __m256i c = _mm256_set1_epi16(static_cast<int16_t>(value));
    return static_cast<uint32_t>(
        _mm256_movemask_epi8(_mm256_packs_epi16(_mm256_cmpeq_epi16(a.v[0], c), _mm256_cmpeq_epi16(a.v[1], c))));
  }
  static uint32_t LessMask(const I16& a, int value) {
    const __m256i c = _mm256_set1_epi16(static_cast<int16_t>(value));
    return static_cast<uint32_t>(
        _mm256_movemask_epi8(_mm256_packs_epi16(_mm256_cmpgt_epi16(c, a.v[0]), _mm256_cmpgt_epi16(c, a.v[1]))));
  }
};

}  // namespace

namespace romunect::depth_engine_internal {

void MatchRowsAvx2(const KernelArgs& args, KernelStats* stats) { MatchRowsAnyBlocks<Avx2Lanes>(args, stats); }

}  // namespace romunect::depth_engine_internal

#pragma GCC pop_options
#endif  // ROMUNECT_DEPTH_KERNEL_AVX2
