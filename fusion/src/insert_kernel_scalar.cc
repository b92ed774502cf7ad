// The insertion walk in portable C++: a block is one vote. The path on CPUs without SSE2 and for
// columns shorter than an SSE2 block (frame_inserter.cc); the same votes as every other kernel.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>

#include "insert_kernel.h"

namespace romunect::fusion::insert_internal {
namespace {

// AddMiss adds a lane mask (0 or -1 per lane) and saturates at kVoteMin: v >= kVoteMin, so v - 1
// cannot wrap.
using Block = Vote;
inline Block LoadBlock(const Vote* p) { return *p; }
inline void StoreBlock(Vote* p, Block v) { *p = v; }
inline Block AndBlocks(Block a, Block b) { return static_cast<Block>(a & b); }
inline Block AddMiss(Block v, Block mask) { return static_cast<Block>(std::max(v + mask, int{kVoteMin})); }
#include "ray_walk.inc"

}  // namespace

void WalkRaysScalar(const RaySetup* rays, size_t count, WalkContext* c) { WalkRays(rays, count, c); }

}  // namespace romunect::fusion::insert_internal
