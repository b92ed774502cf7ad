#include "romunect/sensor/embree/renderer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>
#include <thread>

#include <pmmintrin.h>
#include <xmmintrin.h>

#include <Eigen/Geometry>

#include "ray_scene_impl.h"
#include "romunect/sensor/check.h"

namespace romunect::embree {
namespace {

constexpr int kPacket = 4;  // packets are 4 x 4 pixels: one RTCRayHit16
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Per-frame constants shared by all threads (read only while tracing).
struct FrameSetup {
  RTCScene top = nullptr;
  int width = 0, height = 0;
  Eigen::Matrix3f R_W_C;
  Eigen::Vector3f t_W_C;
  Eigen::Vector3f p_P_C;  // projector centre in C
  Eigen::Vector3f p_P_W;  // projector centre in W
  float shadow_bias_m = 0.0f;
  float inv_focus_m = 0.0f;
  std::vector<Eigen::Matrix3f> R_C_O;             // by top-level instance id
  std::vector<const std::vector<GeometryInfo>*> info;  // by top-level instance id
  std::vector<LensSample> samples;
  const std::vector<cv::Mat>* ray_tables = nullptr;  // one CV_32FC2 per sample
};

struct Counters {
  int64_t camera_rays = 0, hits = 0, shadow_rays = 0, lit = 0;
};

void RenderPacket(const FrameSetup& f, int layer_index, int u0, int v0, GeometryLayer* layer,
                  Counters* counters) {
  const cv::Mat& table = (*f.ray_tables)[layer_index];
  const LensSample& sample = f.samples[layer_index];
  const Eigen::Vector3f o_C(sample.lens_offset_m.x(), sample.lens_offset_m.y(), 0.0f);
  const Eigen::Vector3f o_W = f.R_W_C * o_C + f.t_W_C;

  alignas(64) RTCRayHit16 rh;
  alignas(64) int valid[16];
  Eigen::Vector3f dir_C[16];
  for (int i = 0; i < 16; ++i) {
    const int u = u0 + i % kPacket, v = v0 + i / kPacket;
    valid[i] = (u < f.width && v < f.height) ? -1 : 0;
    rh.ray.org_x[i] = o_W.x();
    rh.ray.org_y[i] = o_W.y();
    rh.ray.org_z[i] = o_W.z();
    rh.ray.tnear[i] = 0.0f;
    rh.ray.time[i] = 0.0f;
    rh.ray.mask[i] = 0xFFFFFFFFu;
    rh.ray.id[i] = static_cast<unsigned>(i);
    rh.ray.flags[i] = 0;
    rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    if (!valid[i]) {
      dir_C[i] = Eigen::Vector3f::UnitZ();
      rh.ray.dir_x[i] = rh.ray.dir_y[i] = 0.0f;
      rh.ray.dir_z[i] = 1.0f;
      rh.ray.tfar[i] = -1.0f;
      continue;
    }
    const cv::Vec2f xy_n = table.at<cv::Vec2f>(v, u);
    // Thin lens: through the lens point o_C towards the point the pinhole ray meets at the
    // focus depth; scaled to z = 1, so that the hit depth (z in C) is exactly t.
    dir_C[i] = Eigen::Vector3f(xy_n[0] - o_C.x() * f.inv_focus_m, xy_n[1] - o_C.y() * f.inv_focus_m,
                               1.0f);
    const Eigen::Vector3f dir_W = f.R_W_C * dir_C[i];
    rh.ray.dir_x[i] = dir_W.x();
    rh.ray.dir_y[i] = dir_W.y();
    rh.ray.dir_z[i] = dir_W.z();
    rh.ray.tfar[i] = std::numeric_limits<float>::infinity();
    ++counters->camera_rays;
  }
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  context.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
  rtcIntersect16(valid, f.top, &context, &rh);

  alignas(64) RTCRay16 shadow;
  alignas(64) int shadow_valid[16];
  Eigen::Vector3f p_C[16], n_C[16];
  for (int i = 0; i < 16; ++i) {
    shadow_valid[i] = 0;
    shadow.org_x[i] = shadow.org_y[i] = shadow.org_z[i] = 0.0f;
    shadow.dir_x[i] = shadow.dir_y[i] = shadow.dir_z[i] = 1.0f;
    shadow.tnear[i] = 0.0f;
    shadow.tfar[i] = 1.0f;
    shadow.time[i] = 0.0f;
    shadow.mask[i] = 0xFFFFFFFFu;
    shadow.id[i] = static_cast<unsigned>(i);
    shadow.flags[i] = 0;
    if (!valid[i] || rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
    const float t = rh.ray.tfar[i];
    p_C[i] = o_C + t * dir_C[i];
    const unsigned instance = rh.hit.instID[0][i];
    ROMUNECT_DCHECK(instance < f.R_C_O.size());
    // Embree reports the geometric normal in the instanced (object) frame.
    Eigen::Vector3f n =
        f.R_C_O[instance] * Eigen::Vector3f(rh.hit.Ng_x[i], rh.hit.Ng_y[i], rh.hit.Ng_z[i]);
    n.normalize();
    if (n.dot(dir_C[i]) > 0.0f) n = -n;
    n_C[i] = n;
    // A surface facing away from the projector shadows itself: no ray needed.
    if (n.dot(f.p_P_C - p_C[i]) <= 0.0f) continue;
    const Eigen::Vector3f origin_W = f.R_W_C * (p_C[i] + f.shadow_bias_m * n) + f.t_W_C;
    const Eigen::Vector3f to_P_W = f.p_P_W - origin_W;
    shadow.org_x[i] = origin_W.x();
    shadow.org_y[i] = origin_W.y();
    shadow.org_z[i] = origin_W.z();
    shadow.dir_x[i] = to_P_W.x();
    shadow.dir_y[i] = to_P_W.y();
    shadow.dir_z[i] = to_P_W.z();
    shadow_valid[i] = -1;
    ++counters->shadow_rays;
  }
  // Shadow rays use the default (incoherent) context: rtcOccluded16 with the coherent flag
  // never returns in Debian's Embree 3.13.5 on AVX-512 (seen on this machine).
  RTCIntersectContext shadow_context;
  rtcInitIntersectContext(&shadow_context);
  rtcOccluded16(shadow_valid, f.top, &shadow_context, &shadow);

  for (int i = 0; i < 16; ++i) {
    if (!valid[i]) continue;
    const int u = u0 + i % kPacket, v = v0 + i / kPacket;
    cv::Vec3f& p_out = layer->p_C.at<cv::Vec3f>(v, u);
    cv::Vec3f& n_out = layer->normal_C.at<cv::Vec3f>(v, u);
    if (rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) {
      p_out = cv::Vec3f(kNaN, kNaN, kNaN);
      n_out = cv::Vec3f(0.0f, 0.0f, 0.0f);
      layer->material.at<int>(v, u) = -1;
      layer->object_id.at<int>(v, u) = -1;
      layer->lit.at<uint8_t>(v, u) = 0;
      continue;
    }
    ++counters->hits;
    p_out = cv::Vec3f(p_C[i].x(), p_C[i].y(), p_C[i].z());
    n_out = cv::Vec3f(n_C[i].x(), n_C[i].y(), n_C[i].z());
    const GeometryInfo& g = (*f.info[rh.hit.instID[0][i]])[rh.hit.geomID[i]];
    layer->material.at<int>(v, u) = g.material;
    layer->object_id.at<int>(v, u) = g.object_id;
    // Embree sets tfar to -inf for occluded rays.
    const bool lit = shadow_valid[i] && shadow.tfar[i] >= 0.0f;
    layer->lit.at<uint8_t>(v, u) = lit ? 1 : 0;
    counters->lit += lit;
  }
}

cv::Mat OffsetRayTable(const CameraModel& camera, const Eigen::Vector2f& offset_px) {
  if (offset_px.isZero()) return camera.RayTable();
  cv::Mat table(camera.height, camera.width, CV_32FC2);
  for (int v = 0; v < camera.height; ++v) {
    auto* row = table.ptr<cv::Vec2f>(v);
    for (int u = 0; u < camera.width; ++u) {
      const Eigen::Vector3d ray =
          camera.Ray(Eigen::Vector2d(u + offset_px.x(), v + offset_px.y()));
      row[u] = cv::Vec2f(static_cast<float>(ray.x()), static_cast<float>(ray.y()));
    }
  }
  return table;
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
  }
  return s.str();
}

std::string RenderStats::BriefReport() const {
  std::ostringstream s;
  s << "render: " << camera_rays << " camera rays, " << hits << " hits, " << shadow_rays
    << " shadow rays, " << lit << " lit, " << seconds * 1e3 << " ms";
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
};

GeometryRenderer::GeometryRenderer() : cache_(std::make_unique<Cache>()) {}
GeometryRenderer::~GeometryRenderer() = default;
GeometryRenderer::GeometryRenderer(GeometryRenderer&&) noexcept = default;
GeometryRenderer& GeometryRenderer::operator=(GeometryRenderer&&) noexcept = default;

RenderStats GeometryRenderer::Render(const RayScene& scene, const CameraModel& camera,
                                     const Pose& T_W_C, const Pose& T_C_P,
                                     const RenderOptions& options, GeometryBuffer* out) {
  const auto start = std::chrono::steady_clock::now();
  ROMUNECT_CHECK(out != nullptr);
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  ROMUNECT_CHECK_MSG(camera.Problem().empty(), camera.Problem().c_str());
  ROMUNECT_CHECK_MSG(scene.committed(), "RayScene::Commit() before rendering");
  const RayScene::Impl& s = *scene.impl_;

  FrameSetup f;
  f.top = s.top.get();
  f.width = camera.width;
  f.height = camera.height;
  f.samples = QualitySamplePattern(options.samples_per_pixel, options.aperture_radius_m);
  const int layers = static_cast<int>(f.samples.size());

  // Ray tables depend only on the camera and the fixed pixel offsets: computed once.
  Cache& cache = *cache_;
  if (!cache.valid || !(cache.camera == camera)) {
    cache = Cache();
    cache.valid = true;
    cache.camera = camera;
  }
  for (int l = static_cast<int>(cache.tables.size()); l < layers; ++l) {
    cache.offsets.push_back(f.samples[l].pixel_offset_px);
    cache.tables.push_back(OffsetRayTable(camera, f.samples[l].pixel_offset_px));
  }
  for (int l = 0; l < layers; ++l) ROMUNECT_CHECK(cache.offsets[l] == f.samples[l].pixel_offset_px);
  f.ray_tables = &cache.tables;

  f.R_W_C = T_W_C.rotation().cast<float>();
  f.t_W_C = T_W_C.translation().cast<float>();
  f.p_P_C = T_C_P.translation().cast<float>();
  f.p_P_W = (T_W_C * T_C_P.translation()).cast<float>();
  f.shadow_bias_m = static_cast<float>(options.shadow_bias_m);
  f.inv_focus_m = static_cast<float>(1.0 / options.focus_distance_m);
  const Eigen::Matrix3d R_C_W = T_W_C.rotation().transpose();
  f.R_C_O.assign(s.part_of_instance.size(), Eigen::Matrix3f::Identity());
  f.info.assign(s.part_of_instance.size(), nullptr);
  for (size_t id = 0; id < s.part_of_instance.size(); ++id) {
    const int part_index = s.part_of_instance[id];
    if (part_index == -2) continue;
    const Part& part = part_index == -1 ? s.static_part : s.moving[part_index];
    f.R_C_O[id] = (R_C_W * part.T_W_O.rotation()).cast<float>();
    f.info[id] = &part.geometries;
  }

  out->materials = s.materials;
  out->layers.resize(layers);
  for (int l = 0; l < layers; ++l) {
    GeometryLayer& layer = out->layers[l];
    layer.p_C.create(camera.height, camera.width, CV_32FC3);
    layer.normal_C.create(camera.height, camera.width, CV_32FC3);
    layer.material.create(camera.height, camera.width, CV_32S);
    layer.object_id.create(camera.height, camera.width, CV_32S);
    layer.lit.create(camera.height, camera.width, CV_8U);
    layer.pixel_offset_px = f.samples[l].pixel_offset_px;
    layer.lens_offset_m = f.samples[l].lens_offset_m;
  }

  // Tiles are handed out in order through an atomic counter; every pixel's result depends
  // only on its own rays and fixed packet layout, so any thread count gives the same bytes.
  const int tile = options.tile_size_px;
  const int tiles_x = (camera.width + tile - 1) / tile;
  const int tiles_y = (camera.height + tile - 1) / tile;
  const int tile_count = tiles_x * tiles_y;
  std::atomic<int> next_tile{0};
  const int thread_count = std::min(options.threads, tile_count);
  std::vector<Counters> counters(thread_count);
  auto work = [&](int thread) {
    // Embree wants denormals flushed (its traversal slows down badly on them); every thread
    // runs in the same mode, so results stay independent of the thread count.
    const unsigned saved_mxcsr = _mm_getcsr();
    _MM_SET_FLUSH_ZERO_MODE(_MM_FLUSH_ZERO_ON);
    _MM_SET_DENORMALS_ZERO_MODE(_MM_DENORMALS_ZERO_ON);
    for (int t = next_tile++; t < tile_count; t = next_tile++) {
      const int tu = (t % tiles_x) * tile, tv = (t / tiles_x) * tile;
      const int u_end = std::min(tu + tile, camera.width), v_end = std::min(tv + tile, camera.height);
      for (int l = 0; l < layers; ++l) {
        for (int v = tv; v < v_end; v += kPacket) {
          for (int u = tu; u < u_end; u += kPacket) {
            RenderPacket(f, l, u, v, &out->layers[l], &counters[thread]);
          }
        }
      }
    }
    _mm_setcsr(saved_mxcsr);
  };
  std::vector<std::thread> pool;
  for (int i = 1; i < thread_count; ++i) pool.emplace_back(work, i);
  work(0);
  for (auto& thread : pool) thread.join();

  RenderStats stats;
  for (const Counters& c : counters) {
    stats.camera_rays += c.camera_rays;
    stats.hits += c.hits;
    stats.shadow_rays += c.shadow_rays;
    stats.lit += c.lit;
  }
  stats.seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
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
    for (int u = 0; u < p_C.cols; ++u) row[u] = std::isnan(in[u][2]) ? 0.0f : in[u][2];
  }
  return depth_m;
}

}  // namespace romunect::embree
