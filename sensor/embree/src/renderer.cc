#include "romunect/sensor/embree/renderer.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <sstream>
#include <thread>

#include <immintrin.h>

#include <Eigen/Geometry>

#include "ray_scene_impl.h"
#include "renderer_kernel.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/keep_or_zero.h"

namespace romunect::embree {
namespace {

using renderer_internal::Counters;
using renderer_internal::FrameSetup;
using renderer_internal::kPacket;
using renderer_internal::Lanes;
using renderer_internal::RenderPacketFn;

constexpr double kInf = std::numeric_limits<double>::infinity();

// The packet kernels compiled in (renderer_kernel.h), narrowest first.
constexpr renderer_internal::Kernel kKernels[] = {
#if ROMUNECT_RENDER_KERNEL_SSE2
    {Isa::kSse2, &renderer_internal::RenderPacketSse2},
#endif
#if ROMUNECT_RENDER_KERNEL_AVX2
    {Isa::kAvx2, &renderer_internal::RenderPacketAvx2},
#endif
#if ROMUNECT_RENDER_KERNEL_AVX512
    {Isa::kAvx512, &renderer_internal::RenderPacketAvx512},
#endif
};

// The kernel for `requested` (ResolveIsa over kKernels); null where it is not compiled in or the
// CPU lacks it.
const renderer_internal::Kernel* KernelFor(Isa requested) { return ResolveKernel(requested, kKernels); }

// The samples of one layer's 4 x 4 block at (u0, v0): the whole block, or at the image's border
// the pixels inside it.
Lanes Block(const FrameSetup& f, int layer_index, int u0, int v0) {
  Lanes lanes;
  if (u0 + kPacket <= f.width && v0 + kPacket <= f.height) {
    lanes.Add(u0, v0, layer_index);
    lanes.count = 16;
    lanes.block = true;
    return lanes;
  }
  for (int i = 0; i < 16; ++i) {
    const int u = u0 + i % kPacket, v = v0 + i / kPacket;
    if (u < f.width && v < f.height) lanes.Add(u, v, layer_index);
  }
  return lanes;
}

// Marks (1 in *refine, CV_8U) both pixels of every horizontal and vertical neighbour pair of
// layer 0 between which the object (or hit / miss), the shadow, or the depth changes: there the
// pixel's area holds more than its centre sample shows. A depth step counts when it exceeds
// max_slope pixel footprints (z / fx): a surface steeper than atan(max_slope) or an edge.
int64_t MarkEdges(const GeometryLayer& layer, double fx, double max_slope, cv::Mat* refine) {
  const int rows = layer.p_C.rows, cols = layer.p_C.cols;
  refine->create(rows, cols, CV_8U);
  refine->setTo(0);
  const float step_per_m = static_cast<float>(max_slope / fx);
  auto edge = [&](int v0, int u0, int v1, int u1) {
    const int id0 = layer.object_id.ptr<int>(v0)[u0], id1 = layer.object_id.ptr<int>(v1)[u1];
    if (id0 != id1) return true;
    if (id0 < 0) return false;  // both missed
    if (layer.lit.ptr<uint8_t>(v0)[u0] != layer.lit.ptr<uint8_t>(v1)[u1]) return true;
    const float z0 = layer.p_C.ptr<cv::Vec3f>(v0)[u0][2], z1 = layer.p_C.ptr<cv::Vec3f>(v1)[u1][2];
    return std::abs(z0 - z1) > step_per_m * std::min(z0, z1);
  };
  for (int v = 0; v < rows; ++v) {
    uint8_t* mark = refine->ptr<uint8_t>(v);
    uint8_t* mark_below = v + 1 < rows ? refine->ptr<uint8_t>(v + 1) : nullptr;
    for (int u = 0; u < cols; ++u) {
      if (u + 1 < cols && edge(v, u, v, u + 1)) mark[u] = mark[u + 1] = 1;
      if (mark_below != nullptr && edge(v, u, v + 1, u)) mark[u] = mark_below[u] = 1;
    }
  }
  return cv::countNonZero(*refine);
}

// Copies the samples of `rect` from one layer to another.
void CopySamples(const GeometryLayer& from, const cv::Rect& rect, GeometryLayer* to) {
  const cv::Mat* sources[] = {&from.p_C, &from.normal_C, &from.material, &from.object_id, &from.lit};
  cv::Mat* targets[] = {&to->p_C, &to->normal_C, &to->material, &to->object_id, &to->lit};
  for (int i = 0; i < 5; ++i) {
    cv::Mat target = (*targets[i])(rect);  // a view: copyTo writes into the layer
    (*sources[i])(rect).copyTo(target);
  }
}

cv::Mat OffsetRayTable(const CameraModel& camera, const Eigen::Vector2f& offset_px) {
  if (offset_px.isZero()) return camera.RayTable();
  cv::Mat table(camera.height, camera.width, CV_32FC2);
  for (int v = 0; v < camera.height; ++v) {
    auto* row = table.ptr<cv::Vec2f>(v);
    for (int u = 0; u < camera.width; ++u) {
      const Eigen::Vector3d ray = camera.Ray(Eigen::Vector2d(u + offset_px.x(), v + offset_px.y()));
      row[u] = cv::Vec2f(static_cast<float>(ray.x()), static_cast<float>(ray.y()));
    }
  }
  return table;
}

// The bounds of a ray table's finite entries (x = ray_x, y = ray_y): min x, max x, min y, max y.
Eigen::Vector4d RayTableBounds(const cv::Mat& table) {
  Eigen::Vector4d b(kInf, -kInf, kInf, -kInf);
  for (int v = 0; v < table.rows; ++v) {
    const auto* row = table.ptr<cv::Vec2f>(v);
    for (int u = 0; u < table.cols; ++u) {
      if (!std::isfinite(row[u][0]) || !std::isfinite(row[u][1])) continue;  // such rays hit nothing
      b = Eigen::Vector4d(std::min<double>(b[0], row[u][0]), std::max<double>(b[1], row[u][0]),
                          std::min<double>(b[2], row[u][1]), std::max<double>(b[3], row[u][1]));
    }
  }
  return b;
}

// A half-space n . q >= c of C.
struct HalfSpace {
  Eigen::Vector3d n;
  double c;
};

// Far above the float rounding of rays, hits and instance transforms at metres (~1e-7 m).
constexpr double kReachMarginM = 1e-4;

// Which moving parts no camera ray and no shadow ray of the frame can meet (per part: out of
// reach of camera rays, out of reach of shadow rays). A camera ray leaves its lens point
// o = (o_x, o_y, 0) along (s_x, s_y, 1) with slopes inside the bounds of its layer's table (less
// the lens offset over the focus distance), so its points q = o + t d, t >= 0, keep q_z >= 0 and
// s_lo q_z - a <= q_x <= s_hi q_z + a (a = the largest |o_x|; y alike): five half-spaces. A
// shadow ray runs from within the bias of a camera ray's hit to the projector centre, so it
// stays in each of those half-spaces (widened by the bias) that holds the centre too: they are
// convex. A part whose bounding box (its eight corners in C) lies beyond one of them cannot be
// met. The test only skips work: a part in reach is traced as before.
std::vector<std::array<bool, 2>> MovingPartsOutOfReach(const std::vector<Part>& moving, const Pose& T_W_C,
                                                       const Eigen::Vector3d& p_P_C,
                                                       const std::vector<LensSample>& samples,
                                                       const std::vector<Eigen::Vector4d>& table_bounds,
                                                       double inv_focus_m, double bias_m) {
  Eigen::Vector4d slopes(kInf, -kInf, kInf, -kInf);
  Eigen::Vector2d lens(0.0, 0.0);
  for (size_t l = 0; l < samples.size(); ++l) {
    const Eigen::Vector2d o = samples[l].lens_offset_m.cast<double>();
    const Eigen::Vector4d& b = table_bounds[l];
    slopes = Eigen::Vector4d(std::min(slopes[0], b[0] - o.x() * inv_focus_m),
                             std::max(slopes[1], b[1] - o.x() * inv_focus_m),
                             std::min(slopes[2], b[2] - o.y() * inv_focus_m),
                             std::max(slopes[3], b[3] - o.y() * inv_focus_m));
    lens = lens.cwiseMax(o.cwiseAbs());
  }
  const HalfSpace view[] = {{Eigen::Vector3d(0, 0, 1), 0.0},
                            {Eigen::Vector3d(1, 0, -slopes[0]), -lens.x()},
                            {Eigen::Vector3d(-1, 0, slopes[1]), -lens.x()},
                            {Eigen::Vector3d(0, 1, -slopes[2]), -lens.y()},
                            {Eigen::Vector3d(0, -1, slopes[3]), -lens.y()}};
  const Pose T_C_W = T_W_C.inverse();
  std::vector<std::array<bool, 2>> out(moving.size(), {false, false});
  for (size_t i = 0; i < moving.size(); ++i) {
    const Part& part = moving[i];
    const Pose T_C_O = T_C_W * part.T_W_O;
    Eigen::Vector3d corners[8];
    for (int k = 0; k < 8; ++k) {
      corners[k] = T_C_O * part.bounds_O.corner(static_cast<Eigen::AlignedBox3d::CornerType>(k));
    }
    // Whether every corner lies beyond h, widened by `widen` (m) and the margin.
    auto beyond = [&](const HalfSpace& h, double widen) {
      const double limit = h.c - (widen + kReachMarginM) * h.n.norm();
      for (const Eigen::Vector3d& q : corners) {
        if (!(h.n.dot(q) < limit)) return false;
      }
      return true;
    };
    for (const HalfSpace& h : view) {
      out[i][0] = out[i][0] || beyond(h, 0.0);
      const bool holds_projector = h.n.dot(p_P_C) >= h.c - bias_m * h.n.norm();
      out[i][1] = out[i][1] || (holds_projector && beyond(h, bias_m));
    }
  }
  return out;
}

}  // namespace

std::string RenderOptions::Problem() const {
  std::ostringstream s;
  if (samples_per_pixel != 1 && samples_per_pixel != 4) {
    s << "samples_per_pixel = " << samples_per_pixel << ": must be 1 or 4";
  } else if (!(focus_distance_m > 0.0) || !std::isfinite(focus_distance_m)) {
    s << "focus_distance_m = " << focus_distance_m << ": must be positive";
  } else if (!(aperture_radius_m >= 0.0) || !std::isfinite(aperture_radius_m)) {
    s << "aperture_radius_m = " << aperture_radius_m << ": must be >= 0";
  } else if (threads < 1 || threads > 256) {
    s << "threads = " << threads << ": must be in [1, 256]";
  } else if (tile_size_px < kPacket || tile_size_px % kPacket != 0) {
    s << "tile_size_px = " << tile_size_px << ": must be a positive multiple of " << kPacket;
  } else if (!(shadow_bias_m >= 0.0) || !std::isfinite(shadow_bias_m)) {
    s << "shadow_bias_m = " << shadow_bias_m << ": must be >= 0";
  } else if (adaptive && samples_per_pixel == 1) {
    s << "adaptive = true: needs samples_per_pixel = 4 (the samples it adds at edges)";
  } else if (!(edge_slope > 0.0) || !std::isfinite(edge_slope)) {
    s << "edge_slope = " << edge_slope << ": must be positive";
  } else if (KernelFor(isa) == nullptr) {
    s << "isa = " << ToString(isa) << ": ";
    if (std::none_of(std::begin(kKernels), std::end(kKernels), [&](const auto& k) { return k.isa == isa; })) {
      const char* separator = "the renderer implements ";
      for (const renderer_internal::Kernel& k : kKernels) {
        s << separator << ToString(k.isa);
        separator = ", ";
      }
    } else {
      s << "this CPU does not support it";
    }
  }
  return s.str();
}

std::string RenderStats::BriefReport() const {
  std::ostringstream s;
  s << "render: " << camera_rays << " camera rays, " << hits << " hits, " << shadow_rays << " shadow rays, " << lit
    << " lit, " << refined_pixels << " refined, " << seconds * 1e3 << " ms";
  return s.str();
}

std::vector<LensSample> QualitySamplePattern(int samples_per_pixel, double aperture_radius_m) {
  ROMUNECT_CHECK(samples_per_pixel == 1 || samples_per_pixel == 4);
  std::vector<LensSample> samples(1);
  if (samples_per_pixel == 1) return samples;
  // Ring radius of the outer three: the centroid radius of the ring [R/2, R] is
  // (2/3) (R^3 - R^3/8) / (R^2 - R^2/4) = 7/9 R.
  const double ring = 7.0 / 9.0 * aperture_radius_m;
  for (int k = 0; k < 3; ++k) {
    const double pixel_angle = M_PI / 6.0 + k * 2.0 * M_PI / 3.0;
    const double lens_angle = pixel_angle + M_PI / 3.0;
    LensSample s;
    s.pixel_offset_px = Eigen::Vector2f(static_cast<float>(std::cos(pixel_angle) / 3.0),
                                        static_cast<float>(std::sin(pixel_angle) / 3.0));
    s.lens_offset_m = Eigen::Vector2f(static_cast<float>(ring * std::cos(lens_angle)),
                                      static_cast<float>(ring * std::sin(lens_angle)));
    samples.push_back(s);
  }
  return samples;
}

struct GeometryRenderer::Cache {
  bool valid = false;
  CameraModel camera;
  std::vector<Eigen::Vector2f> offsets;  // the pixel offset each table was made for
  std::vector<cv::Mat> tables;
  std::vector<Eigen::Vector4d> table_bounds;  // RayTableBounds of each table
  cv::Mat refine;                             // adaptive sampling: pixels that get the extra samples

  // Ray tables depend only on the camera and the fixed pixel offsets: computed once.
  void PrepareTables(const CameraModel& cam, const std::vector<LensSample>& samples) {
    if (!valid || !(camera == cam)) {
      *this = Cache();
      valid = true;
      camera = cam;
    }
    const int layers = static_cast<int>(samples.size());
    for (int l = static_cast<int>(tables.size()); l < layers; ++l) {
      offsets.push_back(samples[l].pixel_offset_px);
      tables.push_back(OffsetRayTable(cam, samples[l].pixel_offset_px));
      table_bounds.push_back(RayTableBounds(tables.back()));
    }
    for (int l = 0; l < layers; ++l) ROMUNECT_CHECK(offsets[l] == samples[l].pixel_offset_px);
  }
};

GeometryRenderer::GeometryRenderer() : cache_(std::make_unique<Cache>()) {}
GeometryRenderer::~GeometryRenderer() = default;
GeometryRenderer::GeometryRenderer(GeometryRenderer&&) noexcept = default;
GeometryRenderer& GeometryRenderer::operator=(GeometryRenderer&&) noexcept = default;

namespace {

// The frame's constants in floats (FrameSetup), but the ray tables and the moving parts' scenes.
FrameSetup SetUpFrame(const RayScene::Impl& s, const CameraModel& camera, const Pose& T_W_C, const Pose& T_C_P,
                      const RenderOptions& options) {
  FrameSetup f;
  f.static_scene = s.static_part.scene.get();
  f.width = camera.width;
  f.height = camera.height;
  // Adaptive: sub-pixel samples through the pinhole; the lens' defocus is left to synthesis.
  f.samples = QualitySamplePattern(options.samples_per_pixel, options.adaptive ? 0.0 : options.aperture_radius_m);
  const Eigen::Matrix3d R_W_C = T_W_C.rotation();
  const Eigen::Matrix3d R_C_W = R_W_C.transpose();
  auto to_floats = [](const auto& m, float* to) {
    for (int k = 0; k < static_cast<int>(m.size()); ++k) to[k] = static_cast<float>(m(k / m.cols(), k % m.cols()));
  };
  to_floats(R_W_C, f.R_W_C);
  to_floats(T_W_C.translation(), f.t_W_C);
  to_floats(T_C_P.translation(), f.p_P_C);
  const Eigen::Vector3d p_P_W = T_W_C * T_C_P.translation();
  to_floats(p_P_W, f.p_P_W);
  f.shadow_bias_m = static_cast<float>(options.shadow_bias_m);
  f.inv_focus_m = static_cast<float>(1.0 / options.focus_distance_m);
  f.parts.resize(1 + s.moving.size());
  to_floats(R_C_W, f.parts[0].R_C_part);
  f.parts[0].info = &s.static_part.geometries;
  for (size_t id = 0; id < s.moving.size(); ++id) {  // instance id = index in moving
    const Part& part = s.moving[id];
    const Eigen::Matrix3d R_C_O = R_C_W * part.T_W_O.rotation();
    to_floats(R_C_O, f.parts[1 + id].R_C_part);
    f.parts[1 + id].info = &part.geometries;
  }
  return f;
}

// The moving parts are traced (f's moving_camera, moving_shadow) when at least one is within
// reach of the rays; counts the parts out of reach into *stats.
void SetMovingParts(const RayScene::Impl& s, const Pose& T_W_C, const Pose& T_C_P, const RenderOptions& options,
                    const std::vector<Eigen::Vector4d>& table_bounds, FrameSetup* f, RenderStats* stats) {
  const std::vector<std::array<bool, 2>> out_of_reach = MovingPartsOutOfReach(
      s.moving, T_W_C, T_C_P.translation(), f->samples, table_bounds, f->inv_focus_m, options.shadow_bias_m);
  int64_t out_of_view = 0, out_of_shadows = 0;
  for (const auto& part : out_of_reach) {
    out_of_view += part[0];
    out_of_shadows += part[1];
  }
  const int64_t moving = static_cast<int64_t>(s.moving.size());
  f->moving_camera = out_of_view < moving ? s.top.get() : nullptr;
  f->moving_shadow = out_of_shadows < moving ? s.top.get() : nullptr;
  stats->moving_out_of_view = out_of_view;
  stats->moving_out_of_shadows = out_of_shadows;
}

// One layer per sample, its Mats reused when they already have the right size.
void PrepareLayers(const FrameSetup& f, const std::vector<IrMaterial>& materials, GeometryBuffer* out) {
  out->materials = materials;
  out->layers.resize(f.samples.size());
  for (size_t l = 0; l < f.samples.size(); ++l) {
    GeometryLayer& layer = out->layers[l];
    layer.p_C.create(f.height, f.width, CV_32FC3);
    layer.normal_C.create(f.height, f.width, CV_32FC3);
    layer.material.create(f.height, f.width, CV_32S);
    layer.object_id.create(f.height, f.width, CV_32S);
    layer.lit.create(f.height, f.width, CV_8U);
    layer.pixel_offset_px = f.samples[l].pixel_offset_px;
    layer.lens_offset_m = f.samples[l].lens_offset_m;
  }
}

// Traces a frame tile by tile on several threads. Tiles are handed out in order through an
// atomic counter; every pixel's result depends only on its own rays and fixed packet layout, so
// any thread count gives the same bytes.
class TileTracer {
 public:
  TileTracer(const FrameSetup& f, int tile, int threads, RenderPacketFn render_packet, GeometryBuffer* out)
      : f_(f),
        tile_(tile),
        tiles_x_((f.width + tile - 1) / tile),
        tile_count_(tiles_x_ * ((f.height + tile - 1) / tile)),
        counters_(std::min(threads, tile_count_)),
        render_packet_(render_packet),
        out_(out) {}

  // Traces layers [first, last) of every tile. With `refine` (adaptive), only the pixels it
  // marks, packed 16 to a packet in the tile's row order; the others repeat layer 0's sample
  // (the centre sample stands for the whole pixel).
  void Trace(int first, int last, const cv::Mat* refine) {
    std::atomic<int> next_tile{0};
    auto work = [&](int thread) {
      // Embree wants denormals flushed (its traversal slows down badly on them); every thread
      // runs in the same mode, so results stay independent of the thread count.
      const unsigned saved_mxcsr = _mm_getcsr();
      _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
      _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
      for (int t = next_tile++; t < tile_count_; t = next_tile++) {
        const int tu = (t % tiles_x_) * tile_, tv = (t / tiles_x_) * tile_;
        const cv::Rect rect(tu, tv, std::min(tu + tile_, f_.width) - tu, std::min(tv + tile_, f_.height) - tv);
        if (refine == nullptr) {
          TraceBlocks(rect, first, last, &counters_[thread]);
        } else {
          TraceMarked(rect, first, last, *refine, &counters_[thread]);
        }
      }
      _mm_setcsr(saved_mxcsr);
    };
    std::vector<std::thread> pool;
    for (int i = 1; i < static_cast<int>(counters_.size()); ++i) pool.emplace_back(work, i);
    work(0);
    for (auto& thread : pool) thread.join();
  }

  void AddCounts(RenderStats* stats) const {
    for (const Counters& c : counters_) {
      stats->camera_rays += c.camera_rays;
      stats->hits += c.hits;
      stats->shadow_rays += c.shadow_rays;
      stats->lit += c.lit;
    }
  }

 private:
  // Every pixel of the tile, 4 x 4 blocks of one layer at a time.
  void TraceBlocks(const cv::Rect& rect, int first, int last, Counters* counters) {
    for (int l = first; l < last; ++l) {
      for (int v = rect.y; v < rect.y + rect.height; v += kPacket) {
        for (int u = rect.x; u < rect.x + rect.width; u += kPacket) {
          render_packet_(f_, Block(f_, l, u, v), out_, counters);
        }
      }
    }
  }

  // Marked pixels by 4 x 4 blocks, all their layers in a row, packed 16 samples a packet; the
  // others copy layer 0.
  void TraceMarked(const cv::Rect& rect, int first, int last, const cv::Mat& refine, Counters* counters) {
    for (int l = first; l < last; ++l) CopySamples(out_->layers[0], rect, &out_->layers[l]);
    const int u_end = rect.x + rect.width, v_end = rect.y + rect.height;
    Lanes lanes;
    for (int bv = rect.y; bv < v_end; bv += kPacket) {
      for (int bu = rect.x; bu < u_end; bu += kPacket) {
        for (int v = bv; v < std::min(bv + kPacket, v_end); ++v) {
          const uint8_t* marked = refine.ptr<uint8_t>(v);
          for (int u = bu; u < std::min(bu + kPacket, u_end); ++u) {
            if (!marked[u]) continue;
            for (int l = first; l < last; ++l) {
              lanes.Add(u, v, l);
              if (lanes.count == 16) {
                render_packet_(f_, lanes, out_, counters);
                lanes.count = 0;
              }
            }
          }
        }
      }
    }
    if (lanes.count > 0) render_packet_(f_, lanes, out_, counters);
  }

  const FrameSetup& f_;
  const int tile_, tiles_x_, tile_count_;
  std::vector<Counters> counters_;  // per thread
  const RenderPacketFn render_packet_;
  GeometryBuffer* const out_;
};

}  // namespace

RenderStats GeometryRenderer::Render(const RayScene& scene, const CameraModel& camera, const Pose& T_W_C,
                                     const Pose& T_C_P, const RenderOptions& options, GeometryBuffer* out) {
  const Stopwatch stopwatch;
  ROMUNECT_CHECK(out != nullptr);
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  ROMUNECT_CHECK_MSG(camera.Problem().empty(), camera.Problem().c_str());
  ROMUNECT_CHECK_MSG(scene.committed(), "RayScene::Commit() before rendering");
  const RayScene::Impl& s = *scene.impl_;
  FrameSetup f = SetUpFrame(s, camera, T_W_C, T_C_P, options);
  Cache& cache = *cache_;
  cache.PrepareTables(camera, f.samples);
  f.ray_tables = &cache.tables;
  RenderStats stats;
  SetMovingParts(s, T_W_C, T_C_P, options, cache.table_bounds, &f, &stats);
  PrepareLayers(f, s.materials, out);

  const int layers = static_cast<int>(f.samples.size());
  TileTracer tracer(f, options.tile_size_px, options.threads, KernelFor(options.isa)->render_packet, out);
  if (options.adaptive) {
    tracer.Trace(0, 1, nullptr);
    stats.refined_pixels = MarkEdges(out->layers[0], camera.fx, options.edge_slope, &cache.refine);
    tracer.Trace(1, layers, &cache.refine);
  } else {
    tracer.Trace(0, layers, nullptr);
  }
  tracer.AddCounts(&stats);
  stats.seconds = stopwatch.seconds();
  return stats;
}

cv::Mat GroundTruthDepth(const GeometryBuffer& buffer) {
  ROMUNECT_CHECK(!buffer.layers.empty());
  const cv::Mat& p_C = buffer.layers[0].p_C;
  ROMUNECT_CHECK(p_C.type() == CV_32FC3);
  cv::Mat depth_m(p_C.size(), CV_32F);
  for (int v = 0; v < p_C.rows; ++v) {
    const auto* in = p_C.ptr<cv::Vec3f>(v);
    auto* row = depth_m.ptr<float>(v);
    for (int u = 0; u < p_C.cols; ++u) row[u] = KeepOrZero(in[u][2] == in[u][2], in[u][2]);  // NaN: no surface
  }
  return depth_m;
}

}  // namespace romunect::embree
