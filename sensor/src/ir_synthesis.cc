#include "romunect/sensor/ir_synthesis.h"

#include <algorithm>
#include <cmath>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "ir_synthesis_kernel.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/parallel_rows.h"
#include "romunect/sensor/pattern.h"

namespace romunect {
namespace {

namespace internal = ir_synthesis_internal;

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

// The row kernels compiled in (ir_synthesis_kernel.h), narrowest first.
constexpr internal::Kernel kKernels[] = {
    {Isa::kScalar, &internal::ShadeRowScalar, &internal::FinishRowScalar, &internal::DefocusRowScalar},
#if ROMUNECT_IR_KERNEL_AVX2
    {Isa::kAvx2, &internal::ShadeRowAvx2, &internal::FinishRowAvx2, &internal::DefocusRowAvx2},
#endif
#if ROMUNECT_IR_KERNEL_AVX512
    {Isa::kAvx512, &internal::ShadeRowAvx512, &internal::FinishRowAvx512, &internal::DefocusRowAvx512},
#endif
};

// The kernels for `requested` (ResolveIsa over kKernels); null where they are not compiled in or
// the CPU lacks them.
const internal::Kernel* KernelFor(Isa requested) { return ResolveKernel(requested, kKernels); }

// A level table (IrSynthesizer::LevelTable) and its stacked levels (rows of `stride` floats,
// `plane` floats per level).
template <class LevelTable>
internal::LevelStack StackOf(const LevelTable& table, const float* pixels, size_t plane, int stride) {
  ROMUNECT_CHECK(plane * table.sigmas.size() < (size_t{1} << 31));  // lanes index with int32
  ROMUNECT_CHECK(table.sigmas.size() <= internal::kTableSize);      // 11 pattern levels, <= 14 camera levels
  internal::LevelStack stack;
  stack.pixels = pixels;
  stack.plane = static_cast<int>(plane);
  stack.stride = stride;
  std::copy(table.sigmas.begin(), table.sigmas.end(), stack.sigmas);
  stack.count = static_cast<int>(table.sigmas.size());
  stack.start = table.start.data();
  stack.start_count = static_cast<int>(table.start.size());
  stack.lut_per_px = LevelTable::kLutPerPx;
  return stack;
}

// The frame's counts (IrSynthesisStats, but the time) from layer 0 and the image.
IrSynthesisStats CountPixels(const GeometryLayer& l0, const cv::Mat& ir, const CameraOptics& optics) {
  IrSynthesisStats stats;
  const float gain = static_cast<float>(optics.gain_dn_per_e), full_well = static_cast<float>(optics.full_well_e);
  const int saturated_dn = std::min(optics.MaxDn(), static_cast<int>(gain * full_well + 0.5f));
  double sum = 0;
  for (int y = 0; y < ir.rows; ++y) {
    const int* m = l0.material.ptr<int>(y);
    const uint8_t* lit = l0.lit.ptr<uint8_t>(y);
    const uint16_t* v = ir.ptr<uint16_t>(y);
    for (int x = 0; x < ir.cols; ++x) {
      stats.pixels_hit += m[x] >= 0;
      stats.pixels_lit += m[x] >= 0 && lit[x] != 0;
      stats.pixels_saturated += v[x] >= saturated_dn;
      sum += v[x];
    }
  }
  stats.mean_dn = sum / (ir.rows * ir.cols);
  return stats;
}

}  // namespace

IrSynthesizer::LevelTable::LevelTable(std::vector<float> level_sigmas) : sigmas(std::move(level_sigmas)) {
  ROMUNECT_CHECK(!sigmas.empty());
  const int n = static_cast<int>(sigmas.size());
  start.resize(static_cast<size_t>(sigmas.back() * kLutPerPx) + 2);
  int i = 0;
  for (size_t b = 0; b < start.size(); ++b) {
    // The last level whose sigma is at most the bin's lower edge: FindLevel only walks upwards.
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
  s << "IR: " << pixels_hit << " hit, " << pixels_lit << " lit, " << pixels_saturated << " saturated, mean " << mean_dn
    << " DN, " << seconds * 1e3 << " ms";
  return s.str();
}

IrSynthesizer::IrSynthesizer(const IrSynthesisOptions& options) : options_(options), isa_(KernelFor(Isa::kAuto)->isa) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
}

void IrSynthesizer::set_isa(Isa isa) {
  const internal::Kernel* kernel = KernelFor(isa);
  ROMUNECT_CHECK_MSG(kernel != nullptr, ToString(isa));
  isa_ = kernel->isa;
}

void IrSynthesizer::Prepare(const Rig& rig) {
  if (!pattern_stack_.empty() && cached_pattern_ == rig.pattern && cached_H_ == rig.H_P_rec &&
      cached_projector_ == rig.projector) {
    return;
  }
  const cv::Mat displayed = ProjectorImage(rig);
  pattern_table_ = LevelTable(LevelSigmas(kPixelBoxSigma, kMaxPatternSigma));
  const int levels = static_cast<int>(pattern_table_.sigmas.size());
  const int padded_rows = displayed.rows + 2;
  pattern_stack_.create(levels * padded_rows, displayed.cols + 2, CV_32F);
  cv::Mat blurred;
  for (int k = 0; k < levels; ++k) {
    const float sigma = pattern_table_.sigmas[k];
    cv::GaussianBlur(displayed, blurred, cv::Size(0, 0), sigma, sigma, cv::BORDER_CONSTANT);
    // A zero border of one pixel: bilinear taps need no bounds checks.
    cv::Mat level = pattern_stack_.rowRange(k * padded_rows, (k + 1) * padded_rows);
    cv::copyMakeBorder(blurred, level, 1, 1, 1, 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  }
  cached_pattern_ = rig.pattern;
  cached_H_ = rig.H_P_rec;
  cached_projector_ = rig.projector;
}

void IrSynthesizer::ShadeLayer(const Rig& rig, const GeometryLayer& layer, const std::vector<IrMaterial>& materials,
                               const GeometryLayer* base, const cv::Mat* base_electrons, cv::Mat* electrons) const {
  const Pose T_P_C = rig.T_C_P.inverse();
  const Eigen::Matrix3f R_P_C = T_P_C.linear().cast<float>();
  const Eigen::Vector3f t_P_C = T_P_C.translation().cast<float>();
  const Eigen::Vector3f c_P = rig.T_C_P.translation().cast<float>();  // projector centre in C
  const ProjectorModel& pr = rig.projector;
  internal::ShadeArgs args;
  args.width = layer.p_C.cols;
  const size_t table_size = material_table_.size() / 3;
  args.albedo = material_table_.data();
  args.specular = args.albedo + table_size;
  args.shininess = args.specular + table_size;
  args.material_count = static_cast<int>(materials.size());
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) args.R_P_C[3 * r + c] = R_P_C(r, c);
    args.t_P_C[r] = t_P_C[r];
    args.c_P[r] = c_P[r];
  }
  const float exposure = static_cast<float>(rig.optics.exposure_s);
  args.projector_e = static_cast<float>(pr.brightness_e_per_s) * exposure;
  args.ambient_e = static_cast<float>(rig.optics.ambient_e_per_s) * exposure;
  args.footprint = static_cast<float>(pr.fx / rig.camera.fx) / std::sqrt(12.f);
  args.coc_scale = static_cast<float>(pr.fx * pr.aperture_m);
  args.inv_focus = static_cast<float>(1.0 / pr.focus_distance_m);
  args.box_sigma2 = kPixelBoxSigma * kPixelBoxSigma;
  args.pfx = static_cast<float>(pr.fx);
  args.pfy = static_cast<float>(pr.fy);
  args.pcx = static_cast<float>(pr.cx);
  args.pcy = static_cast<float>(pr.cy);
  const int levels = static_cast<int>(pattern_table_.sigmas.size());
  args.pattern_cols = pattern_stack_.cols - 2;
  args.pattern_rows = pattern_stack_.rows / levels - 2;
  args.pattern = StackOf(pattern_table_, pattern_stack_.ptr<float>(), pattern_stack_.total() / levels,
                         pattern_stack_.cols);
  const auto shade_row = KernelFor(isa_)->shade;
  ParallelRows(options_.threads, layer.p_C.rows, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      internal::ShadeRowData row;
      row.p_C = layer.p_C.ptr<float>(y);
      row.normal_C = layer.normal_C.ptr<float>(y);
      row.material = layer.material.ptr<int>(y);
      row.lit = layer.lit.ptr<uint8_t>(y);
      row.electrons = electrons->ptr<float>(y);
      if (base != nullptr) {
        row.base_p_C = base->p_C.ptr<float>(y);
        row.base_normal_C = base->normal_C.ptr<float>(y);
        row.base_material = base->material.ptr<int>(y);
        row.base_lit = base->lit.ptr<uint8_t>(y);
        row.base_electrons = base_electrons->ptr<float>(y);
      }
      shade_row(args, row);
    }
  });
}

bool IrSynthesizer::ShadeLayers(const Rig& rig, const GeometryBuffer& geometry) {
  const std::vector<IrMaterial>& materials = geometry.materials;
  const size_t table_size = std::max<size_t>(materials.size(), internal::kTableSize);
  material_table_.assign(3 * table_size, 0.f);
  for (size_t m = 0; m < materials.size(); ++m) {
    material_table_[m] = materials[m].albedo;
    material_table_[table_size + m] = materials[m].specular;
    material_table_[2 * table_size + m] = materials[m].shininess;
  }
  // Radiance summed over the layers (the quality mode's samples), then averaged. Samples that
  // repeat layer 0's hit (adaptive sampling away from edges) reuse its radiance.
  const size_t layer_count = geometry.layers.size();
  cv::Mat& first = layer_count > 1 ? layer0_electrons_ : electrons_;
  first.create(geometry.layers[0].p_C.size(), CV_32F);
  ShadeLayer(rig, geometry.layers[0], materials, nullptr, nullptr, &first);
  bool lens_sampled = !geometry.layers[0].lens_offset_m.isZero();
  if (layer_count > 1) {
    first.copyTo(electrons_);
    for (size_t i = 1; i < layer_count; ++i) {
      const GeometryLayer& layer = geometry.layers[i];
      lens_sampled = lens_sampled || !layer.lens_offset_m.isZero();
      ShadeLayer(rig, layer, materials, &geometry.layers[0], &first, &electrons_);
    }
    electrons_ *= 1.0 / layer_count;
  }
  return lens_sampled;
}

float IrSynthesizer::DefocusSigmas(const Rig& rig, const GeometryLayer& layer0) {
  const CameraOptics& optics = rig.optics;
  const float s0 = static_cast<float>(optics.psf_sigma_px);
  const cv::Size size = layer0.p_C.size();
  sigma_map_.create(size, CV_32F);
  internal::DefocusArgs args;
  args.width = size.width;
  args.scale = static_cast<float>(rig.camera.fx * optics.aperture_m);
  args.inv_focus = static_cast<float>(1.0 / optics.focus_distance_m);
  args.psf2 = s0 * s0;
  row_sigma_min_.resize(size.height);
  row_sigma_max_.resize(size.height);
  const auto defocus_row = KernelFor(isa_)->defocus;
  ParallelRows(options_.threads, size.height, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      defocus_row(args, {layer0.p_C.ptr<float>(y), sigma_map_.ptr<float>(y), &row_sigma_min_[y], &row_sigma_max_[y]});
    }
  });
  return std::max(s0, *std::max_element(row_sigma_max_.begin(), row_sigma_max_.end()));
}

void IrSynthesizer::BlurCameraLevels(float s0, float max_sigma, bool defocus) {
  const cv::Size size = electrons_.size();
  const bool blend = defocus && max_sigma > s0 * 1.01f;
  std::vector<float> sigmas = blend ? LevelSigmas(std::max(s0, 0.25f), std::min(max_sigma, 30.f))
                                    : std::vector<float>{s0};
  if (sigmas[0] != s0) sigmas.insert(sigmas.begin(), s0);
  camera_table_ = LevelTable(std::move(sigmas));
  const std::vector<float>& levels = camera_table_.sigmas;
  // The levels in one stack (one level: blurred_ itself, read in place by the last pass).
  blurred_.create(size, CV_32F);
  const int count = static_cast<int>(levels.size());
  if (count > 1) camera_stack_.create(count * size.height, size.width, CV_32F);
  camera_levels_.resize(count);
  for (int k = 0; k < count; ++k) {
    camera_levels_[k] = count > 1 ? camera_stack_.rowRange(k * size.height, (k + 1) * size.height) : blurred_;
  }
  // A row reads the levels of its pixels' sigmas and their blend partners (FinishPixels), so each
  // level is blurred over the bands of rows that read it: a band blurs to the bytes the whole
  // image has there (OpenCV takes the rows around a band for its border; tested).
  // Several levels come only from defocus, which measured every row's sigmas.
  std::vector<int> row_k_lo(size.height, 0), row_k_hi(size.height, 0);
  if (count > 1) {
    ROMUNECT_CHECK(defocus && static_cast<int>(row_sigma_min_.size()) == size.height);
    const internal::LevelStack table = StackOf(camera_table_, nullptr, size.area(), size.width);
    float w;
    for (int y = 0; y < size.height; ++y) {
      internal::FindLevelScalar(table, row_sigma_min_[y], &row_k_lo[y], &w);
      internal::FindLevelScalar(table, row_sigma_max_[y], &row_k_hi[y], &w);
      row_k_hi[y] += 1;
    }
  }
  const int k_first = *std::min_element(row_k_lo.begin(), row_k_lo.end());
  const int k_last = std::min(count - 1, *std::max_element(row_k_hi.begin(), row_k_hi.end()));
  for (int k = k_first; k <= k_last; ++k) {
    for (int y0 = 0; y0 < size.height;) {
      if (k < row_k_lo[y0] || k > row_k_hi[y0]) {
        ++y0;
        continue;
      }
      int y1 = y0 + 1;
      while (y1 < size.height && k >= row_k_lo[y1] && k <= row_k_hi[y1]) ++y1;
      cv::Mat band = camera_levels_[k].rowRange(y0, y1);
      if (levels[k] <= 0.f) {
        electrons_.rowRange(y0, y1).copyTo(band);
      } else {
        cv::GaussianBlur(electrons_.rowRange(y0, y1), band, cv::Size(0, 0), levels[k], levels[k], cv::BORDER_REPLICATE);
      }
      y0 = y1;
    }
  }
}

void IrSynthesizer::FinishImage(const Rig& rig, uint64_t seed, cv::Mat* ir) {
  // Row by row; noise from a hash of (seed, pixel): the same bytes at any thread count.
  const CameraOptics& optics = rig.optics;
  const cv::Size size = blurred_.size();
  const int count = static_cast<int>(camera_table_.sigmas.size());
  ir->create(size, CV_16U);
  internal::FinishArgs args;
  args.width = size.width;
  args.camera = StackOf(camera_table_, camera_levels_[0].ptr<float>(), size.area(), size.width);
  args.noise = options_.noise;
  args.shot = optics.shot_noise;
  args.noise_seed = HashCounter(seed, 0x1234567ULL);
  args.gain = static_cast<float>(optics.gain_dn_per_e);
  args.full_well = static_cast<float>(optics.full_well_e);
  args.read = static_cast<float>(optics.read_noise_e);
  args.speckle2 = static_cast<float>(optics.speckle_contrast * optics.speckle_contrast);
  args.max_dn = optics.MaxDn();
  const auto finish_row = KernelFor(isa_)->finish;
  ParallelRows(options_.threads, size.height, [&](int row_begin, int row_end) {
    for (int y = row_begin; y < row_end; ++y) {
      internal::FinishRowData row;
      row.y = y;
      row.sigma = count > 1 ? sigma_map_.ptr<float>(y) : nullptr;
      row.camera_levels = camera_levels_[0].ptr<float>(y);
      row.electrons = blurred_.ptr<float>(y);
      row.ir = ir->ptr<uint16_t>(y);
      finish_row(args, row);
    }
  });
}

void IrSynthesizer::Synthesize(const Rig& rig, const GeometryBuffer& geometry, uint64_t seed, cv::Mat* ir,
                               IrSynthesisStats* stats) {
  const Stopwatch stopwatch;
  ROMUNECT_CHECK(ir != nullptr);
  ROMUNECT_CHECK(!geometry.layers.empty());
  const cv::Size size(rig.camera.width, rig.camera.height);
  for (const GeometryLayer& layer : geometry.layers) {
    ROMUNECT_CHECK(layer.p_C.size() == size && layer.p_C.type() == CV_32FC3);
    ROMUNECT_CHECK(layer.normal_C.size() == size && layer.normal_C.type() == CV_32FC3);
    ROMUNECT_CHECK(layer.material.size() == size && layer.material.type() == CV_32S);
    ROMUNECT_CHECK(layer.lit.size() == size && layer.lit.type() == CV_8U);
  }
  Prepare(rig);
  const bool lens_sampled = ShadeLayers(rig, geometry);
  // Camera blur: the focused lens' PSF everywhere, plus the defocus disk (sigma coc / 4) unless
  // the layers already sampled the aperture. Only the levels some pixel blends are blurred.
  const float s0 = static_cast<float>(rig.optics.psf_sigma_px);
  const bool defocus = options_.camera_defocus && !lens_sampled && rig.optics.aperture_m > 0;
  const float max_sigma = defocus ? DefocusSigmas(rig, geometry.layers[0]) : s0;
  BlurCameraLevels(s0, max_sigma, defocus);
  FinishImage(rig, seed, ir);
  if (stats != nullptr) {
    *stats = CountPixels(geometry.layers[0], *ir, rig.optics);
    stats->seconds = stopwatch.seconds();
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
