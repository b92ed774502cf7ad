// The renderer's packet kernel on AVX2: 8 lanes per vector. Compiled for AVX2 under a pragma,
// not a build flag, and called only where the CPU reports it (renderer.cc's dispatch). The
// shared header (and the standard headers through it) comes before the pragma so that its
// inline functions stay baseline code.
#include "renderer_kernel.h"

#if ROMUNECT_RENDER_KERNEL_AVX2
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2")
#include "renderer_kernel_packet.h"

namespace romunect::embree::renderer_internal {
namespace {

struct Avx2Lanes {
  static constexpr int kWidth = 8;
  using F = float __attribute__((vector_size(32)));
  using U = unsigned __attribute__((vector_size(32)));
  static F Sqrt(F x) { return _mm256_sqrt_ps(x); }
};

}  // namespace

void RenderPacketAvx2(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters) {
  PacketKernel<Avx2Lanes>::RenderPacket(f, lanes, out, counters);
}

}  // namespace romunect::embree::renderer_internal

#pragma GCC pop_options
#endif  // ROMUNECT_RENDER_KERNEL_AVX2
