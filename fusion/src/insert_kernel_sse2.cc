// The insertion walk on SSE2 (the x86-64 baseline): a block is 8 votes, one 16-byte register. The
// operations every kernel defines for ray_walk.inc, per block of kLanes votes: LoadBlock,
// StoreBlock, AndBlocks, and AddMiss, which adds a lane mask (0 or -1 per lane) and saturates at
// kVoteMin (v >= kVoteMin, so v - 1 cannot wrap).
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "insert_kernel.h"

#if ROMUNECT_FUSION_KERNEL_SSE2
#include <emmintrin.h>

namespace romunect::fusion::insert_internal {
namespace {

using Block = __m128i;
inline Block LoadBlock(const Vote* p) { return _mm_loadu_si128(reinterpret_cast<const __m128i*>(p)); }
inline void StoreBlock(Vote* p, Block v) { _mm_storeu_si128(reinterpret_cast<__m128i*>(p), v); }
inline Block AndBlocks(Block a, Block b) { return _mm_and_si128(a, b); }
inline Block AddMiss(Block v, Block mask) { return _mm_max_epi16(_mm_add_epi16(v, mask), _mm_set1_epi16(kVoteMin)); }
#include "ray_walk.inc"
static_assert(kLanes == kSse2BlockVotes);

}  // namespace

void WalkRaysSse2(const RaySetup* rays, size_t count, WalkContext* c) { WalkRays(rays, count, c); }

}  // namespace romunect::fusion::insert_internal

#endif  // ROMUNECT_FUSION_KERNEL_SSE2
