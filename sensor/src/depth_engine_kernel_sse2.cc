// The matching kernel on SSE2 (the x86-64 baseline): 32 shifts = 2 x 16 bytes, 4 x 8 int16.
// The operations every instruction set provides, for the 32 shifts k of a block:
//   AbsDiff(obs, ref): |obs - ref[k]| (8 bits); OrBytes: | bytes[k]; Widen, WidenDiff: to
//   int16 (a, a - b); Load, Store, Add, Sub, Min, Or: int16 lanes, shift k stored at Lane(k);
//   HorizontalMin: the least lane; EqualMask, LessMask: bit k set where shift k's lane is equal
//   to, less than the value.
#include "depth_engine_kernel_rows.h"

#if ROMUNECT_DEPTH_KERNEL_SSE2
#include <emmintrin.h>

namespace {

struct Sse2Lanes {
  struct U8 {
    __m128i v[2];
  };
  struct I16 {
    __m128i v[4];
  };
  static __m128i LoadU(const void* p) { return _mm_loadu_si128(static_cast<const __m128i*>(p)); }
  template <typename Fn>
  static I16 Map(Fn fn) {
    return I16{{fn(0), fn(1), fn(2), fn(3)}};
  }
  static constexpr int Lane(int k) { return k; }
  static U8 AbsDiff(uint8_t obs, const uint8_t* ref) {
    const __m128i o = _mm_set1_epi8(static_cast<char>(obs));
    U8 out;
    for (int i = 0; i < 2; ++i) {
      const __m128i q = LoadU(ref + 16 * i);
      out.v[i] = _mm_or_si128(_mm_subs_epu8(o, q), _mm_subs_epu8(q, o));
    }
    return out;
  }
  static U8 OrBytes(const U8& a, const uint8_t* bytes) {
    return U8{{_mm_or_si128(a.v[0], LoadU(bytes)), _mm_or_si128(a.v[1], LoadU(bytes + 16))}};
  }
  static I16 Widen(const U8& a) {
    const __m128i zero = _mm_setzero_si128();
    return I16{{_mm_unpacklo_epi8(a.v[0], zero), _mm_unpackhi_epi8(a.v[0], zero), _mm_unpacklo_epi8(a.v[1], zero),
                _mm_unpackhi_epi8(a.v[1], zero)}};
  }
  static I16 WidenDiff(const U8& a, const U8& b) { return Sub(Widen(a), Widen(b)); }
  static I16 Load(const int16_t* p) {
    return Map([&](int i) { return LoadU(p + 8 * i); });
  }
  static void Store(int16_t* p, const I16& a) {
    for (int i = 0; i < 4; ++i) _mm_storeu_si128(reinterpret_cast<__m128i*>(p + 8 * i), a.v[i]);
  }
  static I16 Add(const I16& a, const I16& b) {
    return Map([&](int i) { return _mm_add_epi16(a.v[i], b.v[i]); });
  }
  static I16 Sub(const I16& a, const I16& b) {
    return Map([&](int i) { return _mm_sub_epi16(a.v[i], b.v[i]); });
  }
  static I16 Min(const I16& a, const I16& b) {
    return Map([&](int i) { return _mm_min_epi16(a.v[i], b.v[i]); });
  }
  static I16 Or(const I16& a, const I16& b) {
    return Map([&](int i) { return _mm_or_si128(a.v[i], b.v[i]); });
  }
  static int HorizontalMin(const I16& a) {
    __m128i m = _mm_min_epi16(_mm_min_epi16(a.v[0], a.v[1]), _mm_min_epi16(a.v[2], a.v[3]));
    m = _mm_min_epi16(m, _mm_shuffle_epi32(m, 0x4E));
    m = _mm_min_epi16(m, _mm_shuffle_epi32(m, 0xB1));
    m = _mm_min_epi16(m, _mm_shufflelo_epi16(m, 0xB1));
    return static_cast<int16_t>(_mm_cvtsi128_si32(m));
  }
  template <typename Compare>
  static uint32_t Mask(const I16& a, Compare compare) {
    const __m128i lo = _mm_packs_epi16(compare(a.v[0]), compare(a.v[1]));
    const __m128i hi = _mm_packs_epi16(compare(a.v[2]), compare(a.v[3]));
    return static_cast<uint32_t>(_mm_movemask_epi8(lo)) | static_cast<uint32_t>(_mm_movemask_epi8(hi)) << 16;
  }
  static uint32_t EqualMask(const I16& a, int value) {
    const __m128i c = _mm_set1_epi16(static_cast<int16_t>(value));
    return Mask(a, [&](__m128i v) { return _mm_cmpeq_epi16(v, c); });
  }
  static uint32_t LessMask(const I16& a, int value) {
    const __m128i c = _mm_set1_epi16(static_cast<int16_t>(value));
    return Mask(a, [&](__m128i v) { return _mm_cmplt_epi16(v, c); });
  }
};

}  // namespace

namespace romunect::depth_engine_internal {

void MatchRowsSse2(const KernelArgs& args, KernelStats* stats) { MatchRowsAnyBlocks<Sse2Lanes>(args, stats); }

}  // namespace romunect::depth_engine_internal
#endif  // ROMUNECT_DEPTH_KERNEL_SSE2
