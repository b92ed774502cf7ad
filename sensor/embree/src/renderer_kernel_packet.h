// The renderer's packet kernel as one template over a lane type V (renderer_kernel.h): V
// provides kWidth (lanes per vector, 4, 8 or 16), the GCC vector types F (float) and U
// (unsigned) of that width, and Sqrt. Included by one unit per instruction set, after its
// target pragma; everything here has internal linkage, so no inline function is shared between
// units compiled for different instruction sets. Every lane performs the same IEEE operations in
// the same order as 3-vector Eigen code (products and dot products sum right to left,
// a0 b0 + (a1 b1 + a2 b2); normalize divides by the square root), so every kernel writes the
// same bytes.
#pragma once

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <limits>

#include <immintrin.h>

#include "renderer_kernel.h"

namespace romunect::embree::renderer_internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Writes 4 points given by their coordinates x, y, z (4 lanes each) as x0 y0 z0 x1 y1 z1 ...
// (SSE, which every kernel has; each compiles it in its own encoding).
inline void StoreXyz4(float* to, const float* x, const float* y, const float* z) {
  const __m128 vx = _mm_load_ps(x), vy = _mm_load_ps(y), vz = _mm_load_ps(z);
  const __m128 xy_lo = _mm_unpacklo_ps(vx, vy), xy_hi = _mm_unpackhi_ps(vx, vy);  // x0 y0 x1 y1, x2 y2 x3 y3
  const __m128 zx_lo = _mm_unpacklo_ps(vz, vx), zx_hi = _mm_unpackhi_ps(vz, vx);  // z0 x0 z1 x1, z2 x2 z3 x3
  const __m128 yz_lo = _mm_unpacklo_ps(vy, vz), yz_hi = _mm_unpackhi_ps(vy, vz);  // y0 z0 y1 z1, y2 z2 y3 z3
  _mm_storeu_ps(to, _mm_shuffle_ps(xy_lo, zx_lo, _MM_SHUFFLE(3, 0, 1, 0)));       // x0 y0 z0 x1
  _mm_storeu_ps(to + 4, _mm_shuffle_ps(yz_lo, xy_hi, _MM_SHUFFLE(1, 0, 3, 2)));   // y1 z1 x2 y2
  _mm_storeu_ps(to + 8, _mm_shuffle_ps(zx_hi, yz_hi, _MM_SHUFFLE(3, 2, 3, 0)));   // z2 x3 y3 z3
}

// One packet's lanes through the steps of RenderPacket: 16 entries each, one per sample.
struct PacketLanes {
  // Lens point o_C (z = 0) and pinhole direction (z = 1) of each lane; lanes past `count` keep
  // sample 0's: the pinhole centre ray, no lens offset.
  alignas(64) float lens_x[16], lens_y[16], ray_x[16], ray_y[16];
  alignas(64) RTCRayHit16 rh;
  alignas(64) int valid_lanes[16];
  alignas(64) float dir_x[16], dir_y[16];  // direction in C (z = 1)
  // The hits: the part each lane hit (0 static, instance i + 1), its material and object.
  alignas(64) int hit_lanes[16], material[16], object_id[16];
  alignas(64) unsigned part[16];
  alignas(64) float R_lanes[9][16];  // R_C_part per lane, where a moving part was hit
  alignas(64) RTCRay16 shadow;
  alignas(64) int shadow_lanes[16];
  alignas(64) float p_out[3][16], n_out[3][16];
  alignas(64) uint8_t lit[16];
};

template <class V>
struct PacketKernel {
  static constexpr int kWidth = V::kWidth;
  using F = typename V::F;
  using U = typename V::U;
  static_assert(16 % kWidth == 0 && sizeof(F) == 4 * kWidth && sizeof(U) == sizeof(F));

  static F LoadF(const float* p) {
    F v;
    std::memcpy(&v, p, sizeof v);
    return v;
  }

  template <typename T>  // unsigned or int (lane masks)
  static U LoadU(const T* p) {
    static_assert(sizeof(T) * kWidth == sizeof(U));
    U v;
    std::memcpy(&v, p, sizeof v);
    return v;
  }

  template <typename T, typename W>
  static void Store(T* p, W v) {
    static_assert(sizeof(T) * kWidth == sizeof v);
    std::memcpy(p, &v, sizeof v);
  }

  // Row r of a row-major 3 x 3 matrix times (x, y, z), as Eigen sums it.
  static F RowTimes(const float* m, int r, F x, F y, F z) {
    return m[3 * r] * x + (m[3 * r + 1] * y + m[3 * r + 2] * z);
  }

  static F Dot(F ax, F ay, F az, F bx, F by, F bz) { return ax * bx + (ay * by + az * bz); }

  // Whether any of the 16 lanes is set.
  static bool AnyLane(const int* lanes) {
    U any = {};
    for (int j = 0; j < 16; j += kWidth) any |= LoadU(lanes + j);
    uint64_t words[kWidth / 2];
    std::memcpy(words, &any, sizeof any);
    uint64_t word = 0;
    for (uint64_t w : words) word |= w;
    return word != 0;
  }

  // Closest hits of a packet: the static part (coherent, no instance to enter), then the moving
  // parts up to that distance. A hit on a moving part carries its instance id; a static hit
  // carries RTC_INVALID_GEOMETRY_ID there.
  static void IntersectPacket(const FrameSetup& f, const int* valid, RTCRayHit16* rh) {
    RTCIntersectContext coherent;
    rtcInitIntersectContext(&coherent);
    coherent.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    rtcIntersect16(valid, f.static_scene, &coherent, rh);
    if (f.moving_camera == nullptr) return;
    RTCHit16& hit = rh->hit;
    const U invalid_id = U{} + RTC_INVALID_GEOMETRY_ID;
    alignas(64) RTCHit16 static_hit;
    for (int j = 0; j < 16; j += kWidth) {
      Store(static_hit.geomID + j, LoadU(hit.geomID + j));
      Store(static_hit.Ng_x + j, LoadF(hit.Ng_x + j));
      Store(static_hit.Ng_y + j, LoadF(hit.Ng_y + j));
      Store(static_hit.Ng_z + j, LoadF(hit.Ng_z + j));
      Store(hit.geomID + j, invalid_id);
    }
    rtcIntersect16(valid, f.moving_camera, &coherent, rh);  // tfar holds the static hit: nearer only
    for (int j = 0; j < 16; j += kWidth) {
      const U moving_nearer = LoadU(hit.geomID + j) != invalid_id;
      Store(hit.geomID + j, moving_nearer ? LoadU(hit.geomID + j) : LoadU(static_hit.geomID + j));
      Store(hit.instID[0] + j, moving_nearer ? LoadU(hit.instID[0] + j) : invalid_id);
      Store(hit.Ng_x + j, moving_nearer ? LoadF(hit.Ng_x + j) : LoadF(static_hit.Ng_x + j));
      Store(hit.Ng_y + j, moving_nearer ? LoadF(hit.Ng_y + j) : LoadF(static_hit.Ng_y + j));
      Store(hit.Ng_z + j, moving_nearer ? LoadF(hit.Ng_z + j) : LoadF(static_hit.Ng_z + j));
    }
  }

  // Occlusion of the shadow rays: the static part with a coherent packet, then the moving parts
  // for the rays still free. Coherent occlusion rays through instances never return in Debian's
  // Embree 3.13.5 on AVX-512, so the instances get the default context.
  static void OccludedPacket(const FrameSetup& f, int* valid, RTCRay16* shadow) {
    if (!AnyLane(valid)) return;
    RTCIntersectContext coherent;
    rtcInitIntersectContext(&coherent);
    coherent.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    rtcOccluded16(valid, f.static_scene, &coherent, shadow);
    if (f.moving_shadow == nullptr) return;
    alignas(64) int free_rays[16];
    for (int j = 0; j < 16; j += kWidth) {
      Store(free_rays + j, LoadU(valid + j) & (LoadF(shadow->tfar + j) >= F{}));
    }
    if (!AnyLane(free_rays)) return;
    RTCIntersectContext incoherent;
    rtcInitIntersectContext(&incoherent);
    rtcOccluded16(free_rays, f.moving_shadow, &incoherent, shadow);
  }

  // Each lane's lens point and pinhole direction from the ray tables.
  static void LoadRays(const FrameSetup& f, const Lanes& lanes, PacketLanes* p) {
    if (lanes.block) {
      const cv::Mat& table = (*f.ray_tables)[lanes.layer[0]];
      for (int r = 0; r < kPacket; ++r) {
        const float* xy = table.ptr<float>(lanes.v[0] + r) + 2 * lanes.u[0];
        for (int c = 0; c < kPacket; ++c) {
          p->ray_x[kPacket * r + c] = xy[2 * c];
          p->ray_y[kPacket * r + c] = xy[2 * c + 1];
        }
      }
      std::fill_n(p->lens_x, 16, f.samples[lanes.layer[0]].lens_offset_m.x());
      std::fill_n(p->lens_y, 16, f.samples[lanes.layer[0]].lens_offset_m.y());
      return;
    }
    std::fill_n(p->lens_x, 16, 0.0f);
    std::fill_n(p->lens_y, 16, 0.0f);
    std::fill_n(p->ray_x, 16, 0.0f);
    std::fill_n(p->ray_y, 16, 0.0f);
    for (int i = 0; i < lanes.count; ++i) {
      const cv::Vec2f xy = (*f.ray_tables)[lanes.layer[i]].ptr<cv::Vec2f>(lanes.v[i])[lanes.u[i]];
      p->ray_x[i] = xy[0];
      p->ray_y[i] = xy[1];
      p->lens_x[i] = f.samples[lanes.layer[i]].lens_offset_m.x();
      p->lens_y[i] = f.samples[lanes.layer[i]].lens_offset_m.y();
    }
  }

  // The camera rays in W (rh.ray) and their directions in C, for the first `count` lanes.
  static void SetCameraRays(const FrameSetup& f, int count, PacketLanes* p) {
    U lane0;  // 0, 1, ..., kWidth - 1
    for (int k = 0; k < kWidth; ++k) lane0[k] = static_cast<unsigned>(k);
    const F zero = {};
    const F one = zero + 1.0f;
    const U none = {};
    const U invalid_id = none + RTC_INVALID_GEOMETRY_ID;
    const float* R_W_C = f.R_W_C;
    RTCRayHit16& rh = p->rh;
    for (int j = 0; j < 16; j += kWidth) {
      const U lane = lane0 + static_cast<unsigned>(j);
      const U valid = lane < static_cast<unsigned>(count);
      const F ox = LoadF(p->lens_x + j), oy = LoadF(p->lens_y + j);
      // Thin lens: through the lens point o_C towards the point the pinhole ray meets at the
      // focus depth; scaled to z = 1, so that the hit depth (z in C) is exactly t.
      const F dx = valid ? LoadF(p->ray_x + j) - ox * f.inv_focus_m : zero;
      const F dy = valid ? LoadF(p->ray_y + j) - oy * f.inv_focus_m : zero;
      Store(p->dir_x + j, dx);
      Store(p->dir_y + j, dy);
      Store(p->valid_lanes + j, valid);
      Store(rh.ray.org_x + j, RowTimes(R_W_C, 0, ox, oy, zero) + f.t_W_C[0]);
      Store(rh.ray.org_y + j, RowTimes(R_W_C, 1, ox, oy, zero) + f.t_W_C[1]);
      Store(rh.ray.org_z + j, RowTimes(R_W_C, 2, ox, oy, zero) + f.t_W_C[2]);
      Store(rh.ray.dir_x + j, RowTimes(R_W_C, 0, dx, dy, one));
      Store(rh.ray.dir_y + j, RowTimes(R_W_C, 1, dx, dy, one));
      Store(rh.ray.dir_z + j, RowTimes(R_W_C, 2, dx, dy, one));
      Store(rh.ray.tnear + j, zero);
      Store(rh.ray.time + j, zero);
      Store(rh.ray.tfar + j, valid ? zero + std::numeric_limits<float>::infinity() : zero - 1.0f);
      Store(rh.ray.mask + j, ~none);
      Store(rh.ray.id + j, lane);
      Store(rh.ray.flags + j, none);
      Store(rh.hit.geomID + j, invalid_id);
      Store(rh.hit.instID[0] + j, invalid_id);
    }
  }

  // The part, material and object of each hit; returns whether a lane hit a moving part (then
  // R_lanes holds each lane's rotation of normals into C).
  static bool HitParts(const FrameSetup& f, PacketLanes* p) {
    const U invalid_id = U{} + RTC_INVALID_GEOMETRY_ID;
    // The part each lane hit: RTC_INVALID_GEOMETRY_ID (static) + 1 wraps to 0, instance i is i + 1.
    for (int j = 0; j < 16; j += kWidth) {
      const U hit = LoadU(p->valid_lanes + j) & (LoadU(p->rh.hit.geomID + j) != invalid_id);
      Store(p->hit_lanes + j, hit);
      Store(p->part + j, hit & (LoadU(p->rh.hit.instID[0] + j) + 1u));
    }
    bool moving_hit = false;
    for (int i = 0; i < 16; ++i) {
      p->material[i] = p->object_id[i] = -1;
      if (!p->hit_lanes[i]) continue;
      ROMUNECT_DCHECK(p->part[i] < f.parts.size());
      const GeometryInfo& g = (*f.parts[p->part[i]].info)[p->rh.hit.geomID[i]];
      p->material[i] = g.material;
      p->object_id[i] = g.object_id;
      moving_hit |= p->part[i] != 0;
    }
    // Embree reports the geometric normal in the frame of the part it hit (W or O).
    if (moving_hit) {
      for (int i = 0; i < 16; ++i) {
        for (int k = 0; k < 9; ++k) p->R_lanes[k][i] = f.parts[p->part[i]].R_C_part[k];
      }
    }
    return moving_hit;
  }

  // Hit points and unit normals facing the camera (p_out, n_out: NaN and 0 where missed), and
  // the shadow rays towards the projector centre of the hits facing it.
  static void ShadeHits(const FrameSetup& f, bool moving_hit, PacketLanes* p) {
    U lane0;  // 0, 1, ..., kWidth - 1
    for (int k = 0; k < kWidth; ++k) lane0[k] = static_cast<unsigned>(k);
    const F zero = {};
    const F one = zero + 1.0f;
    const U none = {};
    const F nan = zero + kNaN;
    const float* R_W_C = f.R_W_C;
    RTCRay16& shadow = p->shadow;
    for (int j = 0; j < 16; j += kWidth) {
      const U hit = LoadU(p->hit_lanes + j);
      const F ox = LoadF(p->lens_x + j), oy = LoadF(p->lens_y + j);
      const F t = LoadF(p->rh.ray.tfar + j);
      const F px = ox + t * LoadF(p->dir_x + j), py = oy + t * LoadF(p->dir_y + j), pz = zero + t;  // o_C + t dir
      F R[9];
      for (int k = 0; k < 9; ++k) R[k] = moving_hit ? LoadF(p->R_lanes[k] + j) : zero + f.parts[0].R_C_part[k];
      const F ngx = LoadF(p->rh.hit.Ng_x + j), ngy = LoadF(p->rh.hit.Ng_y + j), ngz = LoadF(p->rh.hit.Ng_z + j);
      F nx = R[0] * ngx + (R[1] * ngy + R[2] * ngz);
      F ny = R[3] * ngx + (R[4] * ngy + R[5] * ngz);
      F nz = R[6] * ngx + (R[7] * ngy + R[8] * ngz);
      const F squared_norm = Dot(nx, ny, nz, nx, ny, nz);
      const F norm = V::Sqrt(squared_norm);
      const U positive = squared_norm > zero;
      nx = positive ? nx / norm : nx;
      ny = positive ? ny / norm : ny;
      nz = positive ? nz / norm : nz;
      const U away = Dot(nx, ny, nz, px - ox, py - oy, pz - zero) > zero;  // n . (p_C - o_C)
      nx = away ? -nx : nx;
      ny = away ? -ny : ny;
      nz = away ? -nz : nz;
      // A surface facing away from the projector shadows itself: no ray needed.
      const U facing_away = Dot(nx, ny, nz, f.p_P_C[0] - px, f.p_P_C[1] - py, f.p_P_C[2] - pz) <= zero;
      const U shadow_valid = hit & ~facing_away;
      const F qx = px + f.shadow_bias_m * nx, qy = py + f.shadow_bias_m * ny, qz = pz + f.shadow_bias_m * nz;
      const F origin_x = RowTimes(R_W_C, 0, qx, qy, qz) + f.t_W_C[0];
      const F origin_y = RowTimes(R_W_C, 1, qx, qy, qz) + f.t_W_C[1];
      const F origin_z = RowTimes(R_W_C, 2, qx, qy, qz) + f.t_W_C[2];
      Store(shadow.org_x + j, shadow_valid ? origin_x : zero);
      Store(shadow.org_y + j, shadow_valid ? origin_y : zero);
      Store(shadow.org_z + j, shadow_valid ? origin_z : zero);
      Store(shadow.dir_x + j, shadow_valid ? f.p_P_W[0] - origin_x : one);
      Store(shadow.dir_y + j, shadow_valid ? f.p_P_W[1] - origin_y : one);
      Store(shadow.dir_z + j, shadow_valid ? f.p_P_W[2] - origin_z : one);
      Store(shadow.tnear + j, zero);
      Store(shadow.tfar + j, one);
      Store(shadow.time + j, zero);
      Store(shadow.mask + j, ~none);
      Store(shadow.id + j, lane0 + static_cast<unsigned>(j));
      Store(shadow.flags + j, none);
      Store(p->shadow_lanes + j, shadow_valid);
      Store(p->p_out[0] + j, hit ? px : nan);
      Store(p->p_out[1] + j, hit ? py : nan);
      Store(p->p_out[2] + j, hit ? pz : nan);
      Store(p->n_out[0] + j, hit ? nx : zero);
      Store(p->n_out[1] + j, hit ? ny : zero);
      Store(p->n_out[2] + j, hit ? nz : zero);
    }
  }

  // The lit mask from the occlusion results (Embree sets tfar to -inf for occluded rays), and
  // the packet's counts.
  static void CountLit(const Lanes& lanes, PacketLanes* p, Counters* counters) {
    const F zero = {};
    alignas(64) int lit_lanes[16];
    for (int j = 0; j < 16; j += kWidth) {
      Store(lit_lanes + j, LoadU(p->shadow_lanes + j) & (LoadF(p->shadow.tfar + j) >= zero));
    }
    int64_t hits = 0, shadow_rays = 0, lit_count = 0;
    for (int i = 0; i < 16; ++i) {
      p->lit[i] = static_cast<uint8_t>(-lit_lanes[i]);
      hits -= p->hit_lanes[i];
      shadow_rays -= p->shadow_lanes[i];
      lit_count -= lit_lanes[i];
    }
    counters->camera_rays += lanes.count;
    counters->hits += hits;
    counters->shadow_rays += shadow_rays;
    counters->lit += lit_count;
  }

  // Writes each lane's sample into its layer of *out.
  static void WriteOutputs(const Lanes& lanes, const PacketLanes& p, GeometryBuffer* out) {
    if (lanes.block) {
      GeometryLayer& layer = out->layers[lanes.layer[0]];
      for (int r = 0; r < kPacket; ++r) {
        const int v = lanes.v[0] + r, u = lanes.u[0], i0 = kPacket * r;
        StoreXyz4(layer.p_C.ptr<float>(v) + 3 * u, p.p_out[0] + i0, p.p_out[1] + i0, p.p_out[2] + i0);
        StoreXyz4(layer.normal_C.ptr<float>(v) + 3 * u, p.n_out[0] + i0, p.n_out[1] + i0, p.n_out[2] + i0);
        std::copy_n(p.material + i0, kPacket, layer.material.ptr<int>(v) + u);
        std::copy_n(p.object_id + i0, kPacket, layer.object_id.ptr<int>(v) + u);
        std::copy_n(p.lit + i0, kPacket, layer.lit.ptr<uint8_t>(v) + u);
      }
      return;
    }
    for (int i = 0; i < lanes.count; ++i) {
      const int u = lanes.u[i], v = lanes.v[i];
      GeometryLayer& layer = out->layers[lanes.layer[i]];
      layer.p_C.ptr<cv::Vec3f>(v)[u] = cv::Vec3f(p.p_out[0][i], p.p_out[1][i], p.p_out[2][i]);
      layer.normal_C.ptr<cv::Vec3f>(v)[u] = cv::Vec3f(p.n_out[0][i], p.n_out[1][i], p.n_out[2][i]);
      layer.material.ptr<int>(v)[u] = p.material[i];
      layer.object_id.ptr<int>(v)[u] = p.object_id[i];
      layer.lit.ptr<uint8_t>(v)[u] = p.lit[i];
    }
  }

  // Traces the samples of `lanes` and writes them into their layers of *out.
  static void RenderPacket(const FrameSetup& f, const Lanes& lanes, GeometryBuffer* out, Counters* counters) {
    PacketLanes p;
    LoadRays(f, lanes, &p);
    // The output lines a block will write, fetched while its rays are traced: otherwise each
    // first store to a line waits for the line (the buffers are ~10 MB per layer). In this body,
    // not a function of their own: GCC 12 takes a function that only prefetches for one without
    // effect and drops its calls.
    if (lanes.block) {
      GeometryLayer& layer = out->layers[lanes.layer[0]];
      for (int r = 0; r < kPacket; ++r) {
        const int v = lanes.v[0] + r, u = lanes.u[0];
        const char* lines[] = {reinterpret_cast<const char*>(layer.p_C.ptr<float>(v) + 3 * u),
                               reinterpret_cast<const char*>(layer.normal_C.ptr<float>(v) + 3 * u),
                               reinterpret_cast<const char*>(layer.material.ptr<int>(v) + u),
                               reinterpret_cast<const char*>(layer.object_id.ptr<int>(v) + u),
                               reinterpret_cast<const char*>(layer.lit.ptr<uint8_t>(v) + u)};
        const int bytes[] = {12 * kPacket, 12 * kPacket, 4 * kPacket, 4 * kPacket, kPacket};
        for (int k = 0; k < 5; ++k) {
          __builtin_prefetch(lines[k], 1, 3);
          __builtin_prefetch(lines[k] + bytes[k] - 1, 1, 3);
        }
      }
    }
    SetCameraRays(f, lanes.count, &p);
    IntersectPacket(f, p.valid_lanes, &p.rh);
    const bool moving_hit = HitParts(f, &p);
    ShadeHits(f, moving_hit, &p);
    OccludedPacket(f, p.shadow_lanes, &p.shadow);
    CountLit(lanes, &p, counters);
    WriteOutputs(lanes, p, out);
  }
};

}  // namespace
}  // namespace romunect::embree::renderer_internal
