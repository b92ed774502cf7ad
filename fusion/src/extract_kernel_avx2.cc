// The column kernels of extraction on AVX2: 16 lanes at a time with masked ends. Loads start at
// lo or later and may read up to kAvx2ReadPastHi votes past hi, never before lo. Compiled for AVX2
// under a pragma, not a build flag, and called only where the CPU reports it (voting_grid.cc).
// Standard headers and extract_kernel.h come before the pragma so that their inline functions
// stay baseline code.
#include <algorithm>
#include <cstdint>
#include <limits>

#include "extract_kernel.h"

#if ROMUNECT_FUSION_EXTRACT_AVX2
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2")

namespace romunect::fusion::extract_internal {

// AnyPositiveScalar, 16 lanes at a time from the top (loads start at lo or later).
bool AnyPositiveAvx2(const Vote* votes, int lo, int hi) {
  const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  for (int top = hi; top >= lo; top -= 16) {
    const int start = std::max(lo, top - 15);
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(votes + start));
    const __m256i in_range = _mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<int16_t>(top - start + 1)), lane);
    if (!_mm256_testz_si256(_mm256_and_si256(_mm256_cmpgt_epi16(v, _mm256_setzero_si256()), in_range), in_range)) {
      return true;
    }
  }
  return false;
}

// MaxVoteSse2 with 16 lanes: lanes outside the range read as the lowest vote.
void MaxVoteAvx2(const Vote* votes, int lo, int hi, int* best, int* best_k) {
  const __m256i lane = _mm256_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
  const __m256i lowest = _mm256_set1_epi16(std::numeric_limits<Vote>::min());
  auto load = [&](int start, int count) {  // votes [start, start + count), the rest lowest
    const __m256i v = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(votes + start));
    return _mm256_blendv_epi8(lowest, v, _mm256_cmpgt_epi16(_mm256_set1_epi16(static_cast<int16_t>(count)), lane));
  };
  __m256i m = lowest;
  for (int k = lo; k <= hi; k += 16) m = _mm256_max_epi16(m, load(k, std::min(16, hi - k + 1)));
  __m128i h = _mm_max_epi16(_mm256_castsi256_si128(m), _mm256_extracti128_si256(m, 1));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 8));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 4));
  h = _mm_max_epi16(h, _mm_srli_si128(h, 2));
  const int16_t found = static_cast<int16_t>(_mm_cvtsi128_si32(h) & 0xffff);
  *best = found;
  const __m256i target = _mm256_set1_epi16(found);
  for (int top = hi;; top -= 16) {  // from the top: the highest k holding the maximum
    const int start = std::max(lo, top - 15);
    const __m256i v = load(start, top - start + 1);
    const uint32_t equal = static_cast<uint32_t>(_mm256_movemask_epi8(_mm256_cmpeq_epi16(v, target)));
    if (equal != 0) {
      *best_k = start + (31 - __builtin_clz(equal)) / 2;
      return;
    }
  }
}

}  // namespace romunect::fusion::extract_internal

#pragma GCC pop_options
#endif  // ROMUNECT_FUSION_EXTRACT_AVX2
