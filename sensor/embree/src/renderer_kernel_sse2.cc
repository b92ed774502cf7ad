// The renderer's packet kernel on SSE2 (the x86-64 baseline): 4 lanes per vector.
#include "renderer_kernel.h"

#if ROMUNECT_RENDER_KERNEL_SSE2
#include <immintrin.h>

#include "renderer_kernel_packet.h"

namespace romunect::embree::renderer_internal {
namespace {

struct Sse2Lanes {
  static constexpr int kWidth = 4;
  using F = float __attribute__((vector_size(16)));
  using U = unsigned __attribute__((vector_size(16)));
  static F Sqrt(F x) { return _mm_sqrt_ps(x); }
};

}  // namespace

void RenderPacketSse2(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters) {
  PacketKernel<Sse2Lanes>::RenderPacket(f, lanes, out, counters);
}

}  // namespace romunect::embree::renderer_internal
#endif  // ROMUNECT_RENDER_KERNEL_SSE2
