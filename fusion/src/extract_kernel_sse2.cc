// The highest vote of a column on SSE2 (the x86-64 baseline): 8 lanes at a time, the last block
// overlapping the one before where the range is not a multiple of 8 (a maximum does not mind),
// then the highest k holding it, searched from the top. Shorter ranges take the scalar loop.
#include <algorithm>
#include <cstdint>
#include <limits>

#include "extract_kernel.h"

#if ROMUNECT_FUSION_EXTRACT_SSE2
#include <emmintrin.h>

namespace romunect::fusion::extract_internal {

void MaxVoteSse2(const Vote* votes, int lo, int hi, int* best, int* best_k) {
  int k = lo;
  int m = std::numeric_limits<Vote>::min();
  if (hi - lo + 1 >= 8) {
    __m128i v = _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + lo));
    for (k = lo + 8; k + 8 <= hi + 1; k += 8) {
      v = _mm_max_epi16(v, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + k)));
    }
    if (k <= hi) v = _mm_max_epi16(v, _mm_loadu_si128(reinterpret_cast<const __m128i*>(votes + hi - 7)));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 8));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 4));
    v = _mm_max_epi16(v, _mm_srli_si128(v, 2));
    m = static_cast<int16_t>(_mm_cvtsi128_si32(v) & 0xffff);
    k = hi + 1;
  }
  for (; k <= hi; ++k) m = std::max(m, int{votes[k]});
  *best = m;
  int top = hi;
  while (votes[top] != m) --top;
  *best_k = top;
}

}  // namespace romunect::fusion::extract_internal

#endif  // ROMUNECT_FUSION_EXTRACT_SSE2
