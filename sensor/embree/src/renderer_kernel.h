// The renderer's packet kernel (private to sensor/embree/src): its own per-ray work around the
// Embree calls (camera rays, hit points, normals, shadow rays, outputs) for up to 16 samples.
// One template (renderer_kernel_packet.h), instantiated per instruction set in
// renderer_kernel_{sse2,avx2,avx512}.cc, each on GCC vectors of its register width. Every lane
// performs the same IEEE operations in the same order as 3-vector Eigen code (no FMA
// contraction: the target builds with -ffp-contract=off), so every instruction set writes the
// same bytes (tested). Embree picks its own instruction set. Dispatch: a table of the
// instruction sets compiled in (renderer.cc), picked by ResolveKernel (docs/design.md, "SIMD
// kernels").
//
// This header holds what the renderer and the kernels share, included by every kernel unit
// before its target pragma so that its inline functions stay baseline code.
#pragma once

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <vector>

#include <embree3/rtcore.h>
#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "ray_scene_impl.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/embree/renderer.h"
#include "romunect/sensor/geometry_buffer.h"

namespace romunect::embree::renderer_internal {

inline constexpr int kPacket = 4;  // packets are 4 x 4 pixels: one RTCRayHit16

// A part rays can hit: the rotation taking its normals into C (row-major) and its geometries.
struct PartSetup {
  float R_C_part[9];
  const std::vector<GeometryInfo>* info = nullptr;
};

// Per-frame constants shared by all threads (read only while tracing). Rotations are row-major.
struct FrameSetup {
  RTCScene static_scene = nullptr;  // the static part, in W, traced directly
  // Instances of the moving parts for camera rays and for shadow rays; null where there are
  // none or no such ray of the frame can meet any of them (MovingPartsOutOfReach).
  RTCScene moving_camera = nullptr;
  RTCScene moving_shadow = nullptr;
  int width = 0, height = 0;
  float R_W_C[9];
  float t_W_C[3];
  float p_P_C[3];  // projector centre in C
  float p_P_W[3];  // projector centre in W
  float shadow_bias_m = 0.0f;
  float inv_focus_m = 0.0f;
  std::vector<PartSetup> parts;  // the static part, then the moving ones by instance id
  std::vector<LensSample> samples;
  const std::vector<cv::Mat>* ray_tables = nullptr;  // one CV_32FC2 per sample
};

// Per-thread counters, a cache line each so that threads do not share one.
struct alignas(64) Counters {
  int64_t camera_rays = 0, hits = 0, shadow_rays = 0, lit = 0;
};

// Up to 16 samples traced together, each a pixel and a layer: a 4 x 4 block of one layer, or
// in adaptive sampling the extra samples of the next marked pixels of a tile (packets cost
// about the same however few of their lanes are in use, and a pixel's samples are coherent).
struct Lanes {
  int count = 0;
  // A whole 4 x 4 block of one layer: lane 4 r + c is pixel (u[0] + c, v[0] + r) of layer[0],
  // and only entries 0 are set.
  bool block = false;
  int u[16], v[16], layer[16];
  void Add(int u_px, int v_px, int layer_index) {
    u[count] = u_px;
    v[count] = v_px;
    layer[count] = layer_index;
    ++count;
  }
};

// The instantiations, one per instruction set (the ones compiled in: see the macros below):
// trace the samples of `lanes` and write them into their layers of *out.
void RenderPacketSse2(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters);
void RenderPacketAvx2(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters);
void RenderPacketAvx512(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters);

// One entry of the renderer's dispatch table (renderer.cc, ResolveKernel).
using RenderPacketFn = void (*)(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters);
struct Kernel {
  Isa isa;
  RenderPacketFn render_packet;
};

}  // namespace romunect::embree::renderer_internal

#if defined(__SSE2__)
#define ROMUNECT_RENDER_KERNEL_SSE2 1
#endif
// AVX2 and AVX-512 code is compiled under `#pragma GCC target` and runs only where the CPU
// reports the instruction set.
#if defined(__x86_64__) && defined(__GNUC__) && !defined(__clang__)
#define ROMUNECT_RENDER_KERNEL_AVX2 1
#define ROMUNECT_RENDER_KERNEL_AVX512 1
#endif
