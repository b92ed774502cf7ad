// The renderer's packet kernel on AVX-512 (F and DQ): 16 lanes per vector, one packet per
// vector. Compiled for AVX-512 under a pragma, not a build flag, and called only where the CPU
// reports it (renderer.cc's dispatch). The shared header (and the standard headers through it)
// comes before the pragma so that its inline functions stay baseline code.
#include "renderer_kernel.h"

#if ROMUNECT_RENDER_KERNEL_AVX512
#include <immintrin.h>

#pragma GCC push_options
#pragma GCC target("avx2,avx512f,avx512dq")
// GCC 12 warns inside its own AVX-512 headers (their _mm512_undefined_* placeholders).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#include "renderer_kernel_packet.h"

namespace romunect::embree::renderer_internal {
namespace {

struct Avx512Lanes {
  static constexpr int kWidth = 16;
  using F = float __attribute__((vector_size(64)));
  using U = unsigned __attribute__((vector_size(64)));
  static F Sqrt(F x) { return _mm512_sqrt_ps(x); }
};

}  // namespace

void RenderPacketAvx512(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters) {
  PacketKernel<Avx512Lanes>::RenderPacket(f, lanes, out, counters);
}

}  // namespace romunect::embree::renderer_internal

#pragma GCC diagnostic pop
#pragma GCC pop_options
#endif  // ROMUNECT_RENDER_KERNEL_AVX512
