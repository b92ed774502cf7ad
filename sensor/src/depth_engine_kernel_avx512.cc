// The matching kernel on AVX-512 (F, BW): 32 shifts = one 32-byte vector of bytes, and one
// 64-byte register of 32 int16 (operations as in depth_engine_kernel_sse2.cc). The int16 lanes
// keep the shifts in order (Lane(k) = k) and comparisons give the lane masks directly. Compiled
// for AVX-512 under a pragma, not a build flag, and called only where the CPU reports it
// (depth_engine.cc). Standard headers and the shared structs come before the pragma so that their
// inline functions stay baseline code.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "depth_engine_kernel.h"

#if ROMUNECT_DEPTH_KERNEL_AVX512
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2,avx512f,avx512bw")
// GCC 12 warns inside its own AVX-512 headers (their _mm512_undefined_* placeholders).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "depth_engine_kernel_rows.h"

namespace {

struct Avx512Lanes {
  struct U8 {
    __m256i v;
  };
  struct I16 {
    __m512i v;
  };
  static __m256i LoadU(const void* p) { return _mm256_loadu_si256(static_cast<const __m256i*>(p)); }
  static constexpr int Lane(int k) { return k; }
  static U8 AbsDiff(uint8_t obs, const uint8_t* ref) {
    const __m256i o = _mm256_set1_epi8(static_cast<char>(obs));
    const __m256i q = LoadU(ref);
    return U8{_mm256_or_si256(_mm256_subs_epu8(o, q), _mm256_subs_epu8(q, o))};
  }
  static U8 OrBytes(const U8& a, const uint8_t* bytes) { return U8{_mm256_or_si256(a.v, LoadU(bytes))}; }
  static I16 Widen(const U8& a) { return I16{_mm512_cvtepu8_epi16(a.v)}; }
  static I16 WidenDiff(const U8& a, const U8& b) {
    return I16{_mm512_sub_epi16(_mm512_cvtepu8_epi16(a.v), _mm512_cvtepu8_epi16(b.v))};
  }
  static I16 Load(const int16_t* p) { return I16{_mm512_loadu_si512(p)}; }
  static void Store(int16_t* p, const I16& a) { _mm512_storeu_si512(p, a.v); }
  static I16 Add(const I16& a, const I16& b) { return I16{_mm512_add_epi16(a.v, b.v)}; }
  static I16 Sub(const I16& a, const I16& b) { return I16{_mm512_sub_epi16(a.v, b.v)}; }
  static I16 Min(const I16& a, const I16& b) { return I16{_mm512_min_epi16(a.v, b.v)}; }
  static I16 Or(const I16& a, const I16& b) { return I16{_mm512_or_si512(a.v, b.v)}; }
  static int HorizontalMin(const I16& a) {
    const __m256i m = _mm256_min_epi16(_mm512_castsi512_si256(a.v), _mm512_extracti64x4_epi64(a.v, 1));
    const __m128i h = _mm_min_epi16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
    // Costs are non-negative int16, so the unsigned minimum (SSE4.1) is the signed one.
    return _mm_cvtsi128_si32(_mm_minpos_epu16(h)) & 0xFFFF;
  }
  static uint32_t EqualMask(const I16& a, int value) {
    return _mm512_cmpeq_epi16_mask(a.v, _mm512_set1_epi16(static_cast<int16_t>(value)));
  }
  static uint32_t LessMask(const I16& a, int value) {
    return _mm512_cmplt_epi16_mask(a.v, _mm512_set1_epi16(static_cast<int16_t>(value)));
  }
};

}  // namespace

namespace romunect::depth_engine_internal {

void MatchRowsAvx512(const KernelArgs& args, KernelStats* stats) { MatchRowsAnyBlocks<Avx512Lanes>(args, stats); }

}  // namespace romunect::depth_engine_internal

#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // ROMUNECT_DEPTH_KERNEL_AVX512
