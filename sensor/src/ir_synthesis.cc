#include "romunect/sensor/ir_synthesis.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <sstream>
#include <thread>

#include <opencv2/imgproc.hpp>

#include "parallel_rows.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/pattern.h"

namespace romunect {
namespace {

// A DLP mirror or laser dot is a small square: a box of one pixel has sigma 1/sqrt(12).
constexpr float kPixelBoxSigma = 0.29f;
constexpr float kLevelRatio = 1.5f;  // sigma ratio of consecutive blur levels
constexpr float kMaxPatternSigma = 12.0f;

// Blur levels sigma_0 = s0, s_k = s0 * ratio^k, up to max_sigma.
std::vector<float> LevelSigmas(float s0, float max_sigma) {
  std::vector<float> sigmas{s0};
  while (sigmas.back() < max_sigma) sigmas.push_back(sigmas.back() * kLevelRatio);
  return sigmas;
}

// ln(x) for normal x > 0: the exponent plus the series 2 atanh(t), t = (m - 1) / (m + 1) with
// the mantissa m in [sqrt(1/2), sqrt(2)), so |t| < 0.172 and four terms leave < 3e-8.
inline float FastLog(float x) {
  int32_t bits;
  std::memcpy(&bits, &x, sizeof bits);
  int32_t mantissa = (bits & 0x7FFFFF) | 0x3F800000;
  const int32_t high = mantissa > 0x3FB504F3 ? 1 : 0;  // m > sqrt(2): halve it
  mantissa -= high << 23;
  const float exponent = static_cast<float>(((bits >> 23) & 0xFF) - 127 + high);
  float m;
  std::memcpy(&m, &mantissa, sizeof m);
  const float t = (m - 1.f) / (m + 1.f), t2 = t * t;
  return exponent * 0.693147181f + 2.f * t * (1.f + t2 * (1.f / 3.f + t2 * (0.2f + t2 * (1.f / 7.f))));
}

// exp(x) for x in [-87, 0]: 2^(integer part) times a degree-6 Taylor polynomial of 2^f on
// [-0.5, 0.5]: relative error < 2e-7.
inline float FastExp(float x) {
  const float y = std::max(x, -87.f) * 1.44269504f;
  const float n = std::nearbyint(y);
  const float f = (y - n) * 0.693147181f;  // |f| <= ln(2) / 2
  const float p =
      1.f + f * (1.f + f * (0.5f + f * (1.f / 6.f + f * (1.f / 24.f + f * (1.f / 120.f + f * (1.f / 720.f))))));
  const int32_t bits = (static_cast<int32_t>(n) + 127) << 23;
  float scale;
  std::memcpy(&scale, &bits, sizeof scale);
  return p * scale;
}

// cos and sin of 2 pi u for u in [0, 1): the quadrant, then Taylor series of degree 10 and 11
// on [0, pi/2]: error < 1e-7.
inline void FastCosSin2Pi(float u, float* c, float* s) {
  const float q = u * 4.f;
  const int quadrant = std::min(static_cast<int>(q), 3);
  const float a = (q - quadrant) * 1.57079633f, a2 = a * a;
  const float sin_a =
      a * (1.f - a2 / 6.f * (1.f - a2 / 20.f * (1.f - a2 / 42.f * (1.f - a2 / 72.f * (1.f - a2 / 110.f)))));
  const float cos_a = 1.f - a2 / 2.f * (1.f - a2 / 12.f * (1.f - a2 / 30.f * (1.f - a2 / 56.f * (1.f - a2 / 90.f))));
  // Quadrant k turns (cos a, sin a) by k * 90 degrees.
  const float cs[4] = {cos_a, -sin_a, -cos_a, sin_a};
  const float sn[4] = {sin_a, cos_a, -sin_a, -cos_a};
  *c = cs[quadrant];
  *s = sn[quadrant];
}

// Two independent standard normal values for one pixel: Box-Muller on the two halves of a hash
// of (seed, pixel), so each pixel's values depend on nothing else. 24-bit uniforms reach 5.9
// sigma, beyond anything photon counts of a frame show.
inline void NormalPair(uint64_t seed, uint64_t pixel, float* g1, float* g2) {
  const uint64_t h = HashCounter(seed, pixel);
  const float u1 = (static_cast<float>(h >> 40) + 0.5f) * 0x1p-24f;  // (0, 1)
  const float u2 = static_cast<float>((h >> 8) & 0xFFFFFFu) * 0x1p-24f;  // [0, 1)
  const float r = std::sqrt(-2.f * FastLog(u1));
  float c, s;
  FastCosSin2Pi(u2, &c, &s);
  *g1 = r * c;
  *g2 = r * s;
}

}  // namespace

IrSynthesizer::LevelTable::LevelTable(std::vector<float> level_sigmas) : sigmas(std::move(level_sigmas)) {
  ROMUNECT_CHECK(!sigmas.empty());
  const int n = static_cast<int>(sigmas.size());
  start.resize(static_cast<size_t>(sigmas.back() * kLutPerPx) + 2);
  int i = 0;
  for (size_t b = 0; b < start.size(); ++b) {
    // The last level whose sigma is at most the bin's lower edge: Find() only walks upwards.
    while (i < n - 2 && sigmas[i + 1] <= b / kLutPerPx) ++i;
    start[b] = i;
  }
}

std::string IrSynthesisOptions::Problem() const {
  if (threads < 1 || threads > 256) return "threads: must be in [1, 256], found " + std::to_string(threads);
  return "";
}

std::string IrSynthesisStats::BriefReport() const {
  std::ostringstream s;
  s << "IR: " << pixels_hit << " hit, " << pixels_lit << " lit, " << pixels_saturated << " saturated, mean "
    << mean_dn << " DN, " << seconds * 1e3 << " ms";
  return s.str();
}

IrSynthesizer::IrSynthesizer(const IrSynthesisOptions& options) : options_(options) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
}

void IrSynthesizer::PreparePattern(const Rig& rig) {
  if (!pattern_levels_.empty() && cached_pattern_ == rig.pattern && cached_H_ == rig.H_P_rec &&
      cached_projector_ == rig.projector) {
    return;
  }
  const cv::Mat displayed = ProjectorImage(rig);
  pattern_table_ = LevelTable(LevelSigmas(kPixelBoxSigma, kMaxPatternSigma));
  pattern_levels_.assign(pattern_table_.sigmas.size(), cv::Mat());
  cv::Mat blurred;
  for (size_t k = 0; k < pattern_levels_.size(); ++k) {
    const float sigma = pattern_table_.sigmas[k];
    cv::GaussianBlur(displayed, blurred, cv::Size(0, 0), sigma, sigma, cv::BORDER_CONSTANT);
    // A zero border of one pixel: bilinear taps need no bounds checks.
    cv::copyMakeBorder(blurred, pattern_levels_[k], 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  }
  cached_pattern_ = rig.pattern;
  cached_H_ = rig.H_P_rec;
  cached_projector_ = rig.projector;
}

namespace {

// Whether pixel (y, x) of `layer` holds exactly the hit of `base` (then it shades the same).
inline bool SameSample(const GeometryLayer& base, const GeometryLayer& layer, int y, int x) {
  return std::memcmp(&base.p_C.ptr<cv::Vec3f>(y)[x], &layer.p_C.ptr<cv::Vec3f>(y)[x], sizeof(cv::Vec3f)) == 0 &&
         std::memcmp(&base.normal_C.ptr<cv::Vec3f>(y)[x], &layer.normal_C.ptr<cv::Vec3f>(y)[x], sizeof(cv::Vec3f)) == 0 &&
         base.material.ptr<int>(y)[x] == layer.material.ptr<int>(y)[x] &&
         base.lit.ptr<uint8_t>(y)[x] == layer.lit.ptr<uint8_t>(y)[x];
}

}  // namespace

inline float IrSynthesizer::PatternAt(float x, float y, float sigma) const {
  const int cols = pattern_levels_[0].cols - 2, rows = pattern_levels_[0].rows - 2;
  if (!(x > -1.f && y > -1.f && x < cols && y < rows)) return 0.f;  // off the pattern: dark
  int k;
  float w;
  pattern_table_.Find(sigma, &k, &w);
  // In the padded image, pixel (x, y) sits at (x + 1, y + 1); all four taps are inside.
  const float xs = x + 1.f, ys = y + 1.f;
  const int x0 = static_cast<int>(xs), y0 = static_cast<int>(ys);
  const float fx = xs - x0, fy = ys - y0;
  auto bilinear = [&](const cv::Mat& level) {
    const float* r0 = level.ptr<float>(y0) + x0;
    const float* r1 = level.ptr<float>(y0 + 1) + x0;
    return (1 - fy) * ((1 - fx) * r0[0] + fx * r0[1]) + fy * ((1 - fx) * r1[0] + fx * r1[1]);
  };
  const float value = bilinear(pattern_levels_[k]);
  return w > 0.f ? (1 - w) * value + w * bilinear(pattern_levels_[k + 1]) : value;
}

void IrSynthesizer::ShadeLayer(const Rig& rig, const GeometryLayer& layer, const std::vector<IrMaterial>& materials,
                               const GeometryLayer* base, const cv::Mat* base_electrons, cv::Mat* electrons) const {
  const Pose T_P_C = rig.T_C_P.inverse();
  const Eigen::Matrix3f R_P_C = T_P_C.linear().cast<float>();
  const Eigen::Vector3f t_P_C = T_P_C.translation().cast<float>();
  const Eigen::Vector3f c_P = rig.T_C_P.translation().cast<float>();  // projector centre in C
  const ProjectorModel& pr = rig.projector;
  const float exposure = static_cast<float>(rig.optics.exposure_s);
  const float projector_e = static_cast<float>(pr.brightness_e_per_s) * exposure;
  const float ambient_e = static_cast<float>(rig.optics.ambient_e_per_s) * exposure;
  const float footprint = static_cast<float>(pr.fx / rig.camera.fx) / std::sqrt(12.f);
  const float coc_scale = static_cast<float>(pr.fx * pr.aperture_m);
  const float inv_focus = static_cast<float>(1.0 / pr.focus_distance_m);
  const float pfx = static_cast<float>(pr.fx), pfy = static_cast<float>(pr.fy);
  const float pcx = static_cast<float>(pr.cx), pcy = static_cast<float>(pr.cy);
  const int n_materials = static_cast<int>(materials.size());
  ParallelRows(options_.threads, layer.p_C.rows, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      const cv::Vec3f* p_row = layer.p_C.ptr<cv::Vec3f>(y);
      const cv::Vec3f* n_row = layer.normal_C.ptr<cv::Vec3f>(y);
      const int* m_row = layer.material.ptr<int>(y);
      const uint8_t* lit_row = layer.lit.ptr<uint8_t>(y);
      float* out = electrons->ptr<float>(y);
      for (int x = 0; x < layer.p_C.cols; ++x) {
        const int m = m_row[x];
        if (base != nullptr && SameSample(*base, layer, y, x)) {
          out[x] += base_electrons->ptr<float>(y)[x];  // the same hit shades the same
          continue;
        }
        float e = 0.f;
        if (m >= 0 && m < n_materials && std::isfinite(p_row[x][2])) {
          const IrMaterial& mat = materials[m];
          e = ambient_e * mat.albedo;
          const Eigen::Vector3f p_C(p_row[x][0], p_row[x][1], p_row[x][2]);
          const Eigen::Vector3f p_P = R_P_C * p_C + t_P_C;
          if (lit_row[x] != 0 && projector_e > 0.f && p_P.z() > 0.f) {
            const float inv_z = 1.f / p_P.z();
            // Projector defocus (disk of diameter coc: sigma coc / 4) and the camera pixel's
            // footprint on the pattern, both in projector pixels.
            const float coc = coc_scale * std::abs(inv_z - inv_focus);
            const float fp = footprint * p_C.z() * inv_z;
            const float sigma = std::sqrt(kPixelBoxSigma * kPixelBoxSigma + fp * fp + 0.0625f * coc * coc);
            const float pattern = PatternAt(pfx * p_P.x() * inv_z + pcx, pfy * p_P.y() * inv_z + pcy, sigma);
            if (pattern > 0.f) {
              const Eigen::Vector3f n(n_row[x][0], n_row[x][1], n_row[x][2]);
              Eigen::Vector3f to_light = c_P - p_C;
              const float d2 = to_light.squaredNorm();
              to_light *= 1.f / std::sqrt(d2);
              const float cos_in = n.dot(to_light);
              if (cos_in > 0.f) {
                float brdf_pi = mat.albedo;  // pi * BRDF
                if (mat.specular > 0.f) {
                  const Eigen::Vector3f reflected = 2.f * cos_in * n - to_light;
                  const float cos_r = -reflected.dot(p_C) / p_C.norm();
                  if (cos_r > 0.f) brdf_pi += mat.specular * 0.5f * (mat.shininess + 2.f) * FastExp(mat.shininess * FastLog(cos_r));
                }
                e += projector_e * pattern * brdf_pi * cos_in / d2;
              }
            }
          }
        }
        out[x] = base != nullptr ? out[x] + e : e;
      }
    }
  });
}

void IrSynthesizer::Synthesize(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, cv::Mat* ir,
                               IrSynthesisStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  ROMUNECT_CHECK(ir != nullptr);
  ROMUNECT_CHECK(!geometry.layers.empty());
  const cv::Size size(rig.camera.width, rig.camera.height);
  for (const GeometryLayer& layer : geometry.layers) {
    ROMUNECT_CHECK(layer.p_C.size() == size && layer.p_C.type() == CV_32FC3);
    ROMUNECT_CHECK(layer.normal_C.size() == size && layer.normal_C.type() == CV_32FC3);
    ROMUNECT_CHECK(layer.material.size() == size && layer.material.type() == CV_32S);
    ROMUNECT_CHECK(layer.lit.size() == size && layer.lit.type() == CV_8U);
  }
  PreparePattern(rig);

  // Radiance summed over the layers (the quality mode's samples), then averaged. Samples that
  // repeat layer 0's hit (adaptive sampling away from edges) reuse its radiance.
  const size_t layer_count = geometry.layers.size();
  cv::Mat& first = layer_count > 1 ? layer0_electrons_ : electrons_;
  first.create(size, CV_32F);
  ShadeLayer(rig, geometry.layers[0], geometry.materials, nullptr, nullptr, &first);
  bool lens_sampled = !geometry.layers[0].lens_offset_m.isZero();
  if (layer_count > 1) {
    first.copyTo(electrons_);
    for (size_t i = 1; i < layer_count; ++i) {
      const GeometryLayer& layer = geometry.layers[i];
      lens_sampled = lens_sampled || !layer.lens_offset_m.isZero();
      ShadeLayer(rig, layer, geometry.materials, &geometry.layers[0], &first, &electrons_);
    }
    electrons_ *= 1.0 / layer_count;
  }

  // Camera blur: the focused lens' PSF everywhere, plus the defocus disk (sigma coc / 4) unless
  // the layers already sampled the aperture. Only the levels some pixel blends are blurred.
  const CameraOptics& optics = rig.optics;
  const float s0 = static_cast<float>(optics.psf_sigma_px);
  const bool defocus = options_.camera_defocus && !lens_sampled && optics.aperture_m > 0;
  float min_sigma = s0, max_sigma = s0;
  if (defocus) {
    sigma_map_.create(size, CV_32F);
    const float scale = static_cast<float>(rig.camera.fx * optics.aperture_m);
    const float inv_focus = static_cast<float>(1.0 / optics.focus_distance_m);
    const float psf2 = s0 * s0;
    const cv::Mat& p0 = geometry.layers[0].p_C;
    std::vector<float> row_min(size.height), row_max(size.height);
    ParallelRows(options_.threads, size.height, [&](int row_begin, int row_end) {
      for (int y = row_begin; y < row_end; ++y) {
        const cv::Vec3f* p = p0.ptr<cv::Vec3f>(y);
        float* s = sigma_map_.ptr<float>(y);
        float lo = std::numeric_limits<float>::max(), hi = 0.f;
        for (int x = 0; x < size.width; ++x) {
          const float z = p[x][2];
          const float coc = std::isfinite(z) && z > 0 ? scale * std::abs(1.f / z - inv_focus) : 0.f;
          s[x] = std::sqrt(psf2 + 0.0625f * coc * coc);
          lo = std::min(lo, s[x]);
          hi = std::max(hi, s[x]);
        }
        row_min[y] = lo;
        row_max[y] = hi;
      }
    });
    min_sigma = *std::min_element(row_min.begin(), row_min.end());
    max_sigma = std::max(s0, *std::max_element(row_max.begin(), row_max.end()));
  }
  const bool blend = defocus && max_sigma > s0 * 1.01f;
  std::vector<float> sigmas = blend ? LevelSigmas(std::max(s0, 0.25f), std::min(max_sigma, 30.f)) : std::vector<float>{s0};
  if (sigmas[0] != s0) sigmas.insert(sigmas.begin(), s0);
  camera_table_ = LevelTable(std::move(sigmas));
  const std::vector<float>& levels = camera_table_.sigmas;
  // Only the levels between those of the smallest and the largest sigma are blended.
  int k_first = 0, k_last = 0;
  if (levels.size() > 1) {
    float w;
    camera_table_.Find(min_sigma, &k_first, &w);
    camera_table_.Find(max_sigma, &k_last, &w);
    k_last += 1;
  }
  camera_levels_.resize(levels.size());
  for (int k = k_first; k <= k_last; ++k) {
    if (levels[k] <= 0.f) {
      electrons_.copyTo(camera_levels_[k]);
    } else {
      cv::GaussianBlur(electrons_, camera_levels_[k], cv::Size(0, 0), levels[k], levels[k], cv::BORDER_REPLICATE);
    }
  }

  // Blend, noise, full well, gain and quantization, row by row; noise from a hash of (seed,
  // pixel): the same bytes at any thread count.
  ir->create(size, CV_16U);
  blurred_.create(size, CV_32F);
  const float gain = static_cast<float>(optics.gain_dn_per_e);
  const float full_well = static_cast<float>(optics.full_well_e);
  const float read = static_cast<float>(optics.read_noise_e);
  const int max_dn = optics.MaxDn();
  const bool noise = options_.noise;
  const bool shot = optics.shot_noise;
  const uint64_t noise_seed = HashCounter(seed, 0x1234567ULL);
  ParallelRows(options_.threads, size.height, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      float* e_row = blurred_.ptr<float>(y);
      if (levels.size() == 1) {
        std::copy_n(camera_levels_[0].ptr<float>(y), size.width, e_row);
      } else {
        const float* s = sigma_map_.ptr<float>(y);
        for (int x = 0; x < size.width; ++x) {
          int k;
          float w;
          camera_table_.Find(s[x], &k, &w);
          const float a = camera_levels_[k].ptr<float>(y)[x];
          e_row[x] = w > 0.f ? (1 - w) * a + w * camera_levels_[k + 1].ptr<float>(y)[x] : a;
        }
      }
      uint16_t* out = ir->ptr<uint16_t>(y);
      for (int x = 0; x < size.width; ++x) {
        float e = e_row[x];
        if (noise) {
          float g1, g2;
          NormalPair(noise_seed, static_cast<uint64_t>(y) * size.width + x, &g1, &g2);
          e += (shot ? std::sqrt(std::max(e, 0.f)) * g1 : 0.f) + read * g2;
        }
        e = std::clamp(e, 0.f, full_well);
        out[x] = static_cast<uint16_t>(std::min(static_cast<int>(gain * e + 0.5f), max_dn));
      }
    }
  });

  if (stats != nullptr) {
    *stats = IrSynthesisStats{};
    const GeometryLayer& l0 = geometry.layers[0];
    const int saturated_dn = std::min(max_dn, static_cast<int>(gain * full_well + 0.5f));
    double sum = 0;
    for (int y = 0; y < size.height; ++y) {
      const int* m = l0.material.ptr<int>(y);
      const uint8_t* lit = l0.lit.ptr<uint8_t>(y);
      const uint16_t* v = ir->ptr<uint16_t>(y);
      for (int x = 0; x < size.width; ++x) {
        stats->pixels_hit += m[x] >= 0;
        stats->pixels_lit += m[x] >= 0 && lit[x] != 0;
        stats->pixels_saturated += v[x] >= saturated_dn;
        sum += v[x];
      }
    }
    stats->mean_dn = sum / size.area();
    stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  }
}

GeometryBuffer FrontoParallelPlane(const CameraModel& camera, double depth_m, const IrMaterial& material) {
  GeometryBuffer buffer;
  buffer.materials = {material};
  GeometryLayer layer;
  const cv::Size size(camera.width, camera.height);
  const cv::Mat rays = camera.RayTable();
  layer.p_C.create(size, CV_32FC3);
  layer.normal_C = cv::Mat(size, CV_32FC3, cv::Scalar(0, 0, -1));
  layer.material = cv::Mat(size, CV_32S, cv::Scalar(0));
  layer.object_id = cv::Mat(size, CV_32S, cv::Scalar(0));
  layer.lit = cv::Mat(size, CV_8U, cv::Scalar(1));
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const cv::Vec2f r = rays.at<cv::Vec2f>(y, x);
      layer.p_C.at<cv::Vec3f>(y, x) = cv::Vec3f(static_cast<float>(depth_m * r[0]), static_cast<float>(depth_m * r[1]),
                                                static_cast<float>(depth_m));
    }
  }
  buffer.layers.push_back(std::move(layer));
  return buffer;
}

}  // namespace romunect
