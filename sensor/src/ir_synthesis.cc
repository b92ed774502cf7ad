#include "romunect/sensor/ir_synthesis.h"

#include <algorithm>
#include <chrono>
#include <cmath>
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

// Index and weight of sigma between levels: value = (1-w) level[k] + w level[k+1].
inline void LevelOf(const std::vector<float>& sigmas, float sigma, int* k, float* w) {
  const int n = static_cast<int>(sigmas.size());
  if (sigma <= sigmas[0] || n == 1) {
    *k = 0;
    *w = 0.f;
    return;
  }
  if (sigma >= sigmas[n - 1]) {
    *k = n - 2;
    *w = 1.f;
    return;
  }
  int i = static_cast<int>(std::log(sigma / sigmas[0]) / std::log(kLevelRatio));
  i = std::clamp(i, 0, n - 2);
  while (i > 0 && sigma < sigmas[i]) --i;
  while (i < n - 2 && sigma > sigmas[i + 1]) ++i;
  *k = i;
  *w = (sigma - sigmas[i]) / (sigmas[i + 1] - sigmas[i]);
}

inline float Bilinear(const cv::Mat& image, float x, float y) {
  if (!(x > -1.f && y > -1.f && x < image.cols && y < image.rows)) return 0.f;
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const float fx = x - x0, fy = y - y0;
  auto at = [&](int yy, int xx) -> float {
    if (xx < 0 || yy < 0 || xx >= image.cols || yy >= image.rows) return 0.f;
    return image.ptr<float>(yy)[xx];
  };
  return (1 - fy) * ((1 - fx) * at(y0, x0) + fx * at(y0, x0 + 1)) +
         fy * ((1 - fx) * at(y0 + 1, x0) + fx * at(y0 + 1, x0 + 1));
}

}  // namespace

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
  pattern_sigmas_ = LevelSigmas(kPixelBoxSigma, kMaxPatternSigma);
  pattern_levels_.assign(pattern_sigmas_.size(), cv::Mat());
  for (size_t k = 0; k < pattern_sigmas_.size(); ++k) {
    cv::GaussianBlur(displayed, pattern_levels_[k], cv::Size(0, 0), pattern_sigmas_[k], pattern_sigmas_[k],
                     cv::BORDER_CONSTANT);
  }
  cached_pattern_ = rig.pattern;
  cached_H_ = rig.H_P_rec;
  cached_projector_ = rig.projector;
}

void IrSynthesizer::ShadeLayer(const Rig& rig, const GeometryLayer& layer, const std::vector<IrMaterial>& materials,
                               cv::Mat* electrons) const {
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
        if (m < 0 || m >= n_materials || !std::isfinite(p_row[x][2])) {
          out[x] = 0.f;
          continue;
        }
        const IrMaterial& mat = materials[m];
        float e = ambient_e * mat.albedo;
        if (lit_row[x] != 0 && projector_e > 0.f) {
          const Eigen::Vector3f p_C(p_row[x][0], p_row[x][1], p_row[x][2]);
          const Eigen::Vector3f p_P = R_P_C * p_C + t_P_C;
          if (p_P.z() > 0.f) {
            const float xp = static_cast<float>(pr.fx) * p_P.x() / p_P.z() + static_cast<float>(pr.cx);
            const float yp = static_cast<float>(pr.fy) * p_P.y() / p_P.z() + static_cast<float>(pr.cy);
            // Projector defocus (disk of diameter coc: sigma coc / 4) and the camera pixel's
            // footprint on the pattern, both in projector pixels.
            const float coc = coc_scale * std::abs(1.f / p_P.z() - inv_focus);
            const float fp = footprint * p_C.z() / p_P.z();
            const float sigma = std::sqrt(kPixelBoxSigma * kPixelBoxSigma + fp * fp + 0.0625f * coc * coc);
            int k;
            float w;
            LevelOf(pattern_sigmas_, sigma, &k, &w);
            float pattern = Bilinear(pattern_levels_[k], xp, yp);
            if (w > 0.f) pattern = (1 - w) * pattern + w * Bilinear(pattern_levels_[k + 1], xp, yp);
            if (pattern > 0.f) {
              const Eigen::Vector3f n(n_row[x][0], n_row[x][1], n_row[x][2]);
              Eigen::Vector3f to_light = c_P - p_C;
              const float d2 = to_light.squaredNorm();
              to_light /= std::sqrt(d2);
              const float cos_in = n.dot(to_light);
              if (cos_in > 0.f) {
                float brdf_pi = mat.albedo;  // pi * BRDF
                if (mat.specular > 0.f) {
                  const Eigen::Vector3f reflected = 2.f * cos_in * n - to_light;
                  const float cos_r = -reflected.dot(p_C.normalized());
                  if (cos_r > 0.f) brdf_pi += mat.specular * 0.5f * (mat.shininess + 2.f) * std::pow(cos_r, mat.shininess);
                }
                e += projector_e * pattern * brdf_pi * cos_in / d2;
              }
            }
          }
        }
        out[x] = e;
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

  // Radiance averaged over the layers (the quality mode's samples).
  electrons_.create(size, CV_32F);
  bool lens_sampled = false;
  for (size_t i = 0; i < geometry.layers.size(); ++i) {
    const GeometryLayer& layer = geometry.layers[i];
    lens_sampled = lens_sampled || !layer.lens_offset_m.isZero();
    if (i == 0) {
      ShadeLayer(rig, layer, geometry.materials, &electrons_);
    } else {
      layer_electrons_.create(size, CV_32F);
      ShadeLayer(rig, layer, geometry.materials, &layer_electrons_);
      electrons_ += layer_electrons_;
    }
  }
  if (geometry.layers.size() > 1) electrons_ *= 1.0 / geometry.layers.size();

  // Camera blur: the focused lens' PSF everywhere, plus the defocus disk (sigma coc / 4) unless
  // the layers already sampled the aperture.
  const CameraOptics& optics = rig.optics;
  const cv::Mat& p0 = geometry.layers[0].p_C;
  float max_sigma = static_cast<float>(optics.psf_sigma_px);
  cv::Mat sigma_map;
  const bool defocus = options_.camera_defocus && !lens_sampled && optics.aperture_m > 0;
  if (defocus) {
    sigma_map.create(size, CV_32F);
    const float scale = static_cast<float>(rig.camera.fx * optics.aperture_m);
    const float inv_focus = static_cast<float>(1.0 / optics.focus_distance_m);
    const float psf2 = static_cast<float>(optics.psf_sigma_px * optics.psf_sigma_px);
    for (int y = 0; y < size.height; ++y) {
      const cv::Vec3f* p = p0.ptr<cv::Vec3f>(y);
      float* s = sigma_map.ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        const float z = p[x][2];
        const float coc = std::isfinite(z) && z > 0 ? scale * std::abs(1.f / z - inv_focus) : 0.f;
        s[x] = std::sqrt(psf2 + 0.0625f * coc * coc);
        max_sigma = std::max(max_sigma, s[x]);
      }
    }
  }
  const float s0 = static_cast<float>(optics.psf_sigma_px);
  std::vector<float> sigmas = (defocus && max_sigma > s0 * 1.01f)
                                  ? LevelSigmas(std::max(s0, 0.25f), std::min(max_sigma, 30.f))
                                  : std::vector<float>{s0};
  if (sigmas[0] != s0) sigmas.insert(sigmas.begin(), s0);
  camera_levels_.resize(sigmas.size());
  for (size_t k = 0; k < sigmas.size(); ++k) {
    if (sigmas[k] <= 0.f) {
      electrons_.copyTo(camera_levels_[k]);
    } else {
      cv::GaussianBlur(electrons_, camera_levels_[k], cv::Size(0, 0), sigmas[k], sigmas[k], cv::BORDER_REPLICATE);
    }
  }
  if (sigmas.size() == 1) {
    camera_levels_[0].copyTo(blurred_);
  } else {
    blurred_.create(size, CV_32F);
    for (int y = 0; y < size.height; ++y) {
      const float* s = sigma_map.ptr<float>(y);
      float* out = blurred_.ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        int k;
        float w;
        LevelOf(sigmas, s[x], &k, &w);
        out[x] = (1 - w) * camera_levels_[k].ptr<float>(y)[x] + w * camera_levels_[k + 1].ptr<float>(y)[x];
      }
    }
  }

  // Noise, full well, gain and quantization; counter-based noise per pixel.
  ir->create(size, CV_16U);
  const float gain = static_cast<float>(optics.gain_dn_per_e);
  const float full_well = static_cast<float>(optics.full_well_e);
  const float read = static_cast<float>(optics.read_noise_e);
  const int max_dn = optics.MaxDn();
  const bool noise = options_.noise;
  const bool shot = optics.shot_noise;
  const uint64_t noise_seed = HashCounter(seed, 0x1234567ULL);
  ParallelRows(options_.threads, size.height, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      const float* in = blurred_.ptr<float>(y);
      uint16_t* out = ir->ptr<uint16_t>(y);
      for (int x = 0; x < size.width; ++x) {
        float e = in[x];
        if (noise) {
          const uint64_t i = static_cast<uint64_t>(y) * size.width + x;
          const double u1 = UniformFromHash(noise_seed, 2 * i) + 1e-300;
          const double u2 = UniformFromHash(noise_seed, 2 * i + 1);
          const double r = std::sqrt(-2.0 * std::log(u1));
          const float g1 = static_cast<float>(r * std::cos(2 * M_PI * u2));
          const float g2 = static_cast<float>(r * std::sin(2 * M_PI * u2));
          e += (shot ? std::sqrt(std::max(e, 0.f)) * g1 : 0.f) + read * g2;
        }
        e = std::clamp(e, 0.f, full_well);
        out[x] = static_cast<uint16_t>(std::min<long>(std::lround(gain * e), max_dn));
      }
    }
  });

  if (stats != nullptr) {
    *stats = IrSynthesisStats{};
    const GeometryLayer& l0 = geometry.layers[0];
    double sum = 0;
    for (int y = 0; y < size.height; ++y) {
      const int* m = l0.material.ptr<int>(y);
      const uint8_t* lit = l0.lit.ptr<uint8_t>(y);
      const uint16_t* v = ir->ptr<uint16_t>(y);
      for (int x = 0; x < size.width; ++x) {
        stats->pixels_hit += m[x] >= 0;
        stats->pixels_lit += m[x] >= 0 && lit[x] != 0;
        stats->pixels_saturated += v[x] >= std::min<long>(max_dn, std::lround(gain * full_well));
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
