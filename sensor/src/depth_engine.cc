#include "romunect/sensor/depth_engine.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "parallel_rows.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/ir_synthesis.h"

namespace romunect {
namespace {

constexpr int kBandRows = 32;          // rows per cost slab (slab ~ 16 x range x width x 2 B)
constexpr float kSigmaFloorDn = 2.0f;  // keeps the normalization finite on flat windows
constexpr float kNormScale = 48.0f;    // one local standard deviation = 48 levels of 8 bits
constexpr uint8_t kOutsideReference = 255;  // difference where the reference has no column
// Window costs fit signed 16 bits (21 x 21 x 255 would not: window_px <= 11 is checked).
constexpr int16_t kMaxCost = 32767;

}  // namespace

// The cost slabs run on AVX2 where the CPU has it (twice the lanes), chosen at load time; the
// results are the same bytes either way (integer arithmetic, same order).
#if defined(__GNUC__) && !defined(__clang__) && defined(__x86_64__) && !defined(__SANITIZE_ADDRESS__)
#define ROMUNECT_SIMD_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define ROMUNECT_SIMD_CLONES
#endif

std::string DepthEngineStats::BriefReport() const {
  std::ostringstream s;
  s << "depth: " << valid << " valid, " << flat << " flat, " << weak << " weak, " << ambiguous << " ambiguous, "
    << out_of_range << " out of range, " << border << " border, " << seconds * 1e3 << " ms";
  return s.str();
}

cv::Mat ChipReferenceImage(const ChipGeometry& chip) {
  ROMUNECT_CHECK_MSG(chip.Problem().empty(), chip.Problem().c_str());
  Rig stock;
  stock.camera = chip.camera;
  stock.optics = CameraOptics{};
  stock.optics.aperture_m = 0.0;
  stock.optics.ambient_e_per_s = 0.0;
  stock.projector = chip.projector;
  stock.projector.aperture_m = 0.0;
  // Bright enough for ~2/3 of the range on a dot, whatever the stored brightness.
  const double z = chip.reference_distance_m;
  stock.projector.brightness_e_per_s = 0.66 * stock.optics.full_well_e * z * z / stock.optics.exposure_s / 0.6;
  stock.T_C_P = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(chip.baseline_m, 0, 0));
  stock.pattern = chip.pattern;
  stock.depth_engine.chip = chip;
  IrSynthesisOptions options;
  options.noise = false;
  IrSynthesizer synthesizer(options);
  cv::Mat ir;
  synthesizer.Synthesize(stock, FrontoParallelPlane(chip.camera, z, IrMaterial{1.0f, 0.0f, 50.0f}), 0, &ir, nullptr);
  return ir;
}

void DepthEngine::Prefilter(const cv::Mat& ir, int window_px, cv::Mat* normalized, cv::Mat* local_sigma) {
  cv::Mat f, mean, mean2;
  ir.convertTo(f, CV_32F);
  const cv::Size k(window_px, window_px);
  cv::boxFilter(f, mean, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::boxFilter(f.mul(f), mean2, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  local_sigma->create(ir.size(), CV_32F);
  normalized->create(ir.size(), CV_8U);
  for (int y = 0; y < ir.rows; ++y) {
    const float* v = f.ptr<float>(y);
    const float* m = mean.ptr<float>(y);
    const float* m2 = mean2.ptr<float>(y);
    float* s = local_sigma->ptr<float>(y);
    uint8_t* n = normalized->ptr<uint8_t>(y);
    for (int x = 0; x < ir.cols; ++x) {
      const float sigma = std::sqrt(std::max(m2[x] - m[x] * m[x], 0.f));
      s[x] = sigma;
      const float value = 128.f + kNormScale * (v[x] - m[x]) / std::max(sigma, kSigmaFloorDn);
      n[x] = static_cast<uint8_t>(std::clamp(value, 0.f, 255.f) + 0.5f);  // round half up
    }
  }
}

DepthEngine::DepthEngine(const DepthEngineOptions& options)
    : DepthEngine(options, ChipReferenceImage(options.chip)) {}

DepthEngine::DepthEngine(const DepthEngineOptions& options, const cv::Mat& reference_ir) : options_(options) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  ROMUNECT_CHECK(reference_ir.type() == CV_16U);
  ROMUNECT_CHECK(reference_ir.cols == options.chip.camera.width && reference_ir.rows == options.chip.camera.height);
  reference_ir_ = reference_ir.clone();
  cv::Mat sigma;
  Prefilter(reference_ir_, options_.prefilter_px, &reference_norm_, &sigma);
  raw_at_reference_rounded_ = static_cast<int>(std::lround(RawAtReference()));
  chip_depth_lut_.resize(kRawInvalid + 1);
  for (int raw = 0; raw <= kRawInvalid; ++raw) chip_depth_lut_[raw] = static_cast<float>(ChipDepthM(raw));
}

double DepthEngine::RawAtReference() const {
  const ChipGeometry& c = options_.chip;
  return c.raw_offset - 8.0 * c.FocalTimesBaseline() / c.reference_distance_m;
}

double DepthEngine::ChipDepthM(int raw) const { return romunect::ChipDepthM(options_.chip, raw); }

double DepthEngine::ShiftOfRaw(int raw) const { return (raw_at_reference_rounded_ - raw) / 8.0; }

ROMUNECT_SIMD_CLONES void DepthEngine::ComputeBand(int y_begin, int y_end, std::vector<int16_t>* slab_storage, DepthEngineOutput* out,
                              DepthEngineStats* stats) const {
  const int W = reference_norm_.cols, H = reference_norm_.rows;
  const int r = options_.window_px / 2;
  const int D = options_.search_range_px;
  const int rows = y_end - y_begin;
  slab_storage->resize(static_cast<size_t>(rows) * D * W);
  int16_t* slab = slab_storage->data();
  // Horizontal window sums of one row's absolute differences, for rows y_begin-r .. y_end+r-1.
  const int hrows = rows + 2 * r;
  std::vector<int16_t> hsum(static_cast<size_t>(hrows) * W);
  std::vector<uint8_t> ad(W);
  std::vector<int16_t> h3_(W);
  std::vector<int16_t> band_best(static_cast<size_t>(rows) * W, kMaxCost), band_best_j(static_cast<size_t>(rows) * W, 0);

  for (int j = 0; j < D; ++j) {
    const int s = options_.min_shift_px + j;
    for (int h = 0; h < hrows; ++h) {
      const int y = y_begin - r + h;
      int16_t* __restrict hs = &hsum[static_cast<size_t>(h) * W];
      if (y < 0 || y >= H) {
        std::fill(hs, hs + W, 0);
        continue;
      }
      const uint8_t* obs = frame_norm_.ptr<uint8_t>(y);
      const uint8_t* ref = reference_norm_.ptr<uint8_t>(y);
      // Reference column x - s exists for x in [s, W + s).
      const int x_lo = std::clamp(s, 0, W), x_hi = std::clamp(W + s, 0, W);
      uint8_t* __restrict adp = ad.data();
      for (int x = 0; x < x_lo; ++x) adp[x] = kOutsideReference;
      {
        const uint8_t* __restrict o = obs + x_lo;
        const uint8_t* __restrict q = ref + x_lo - s;
        uint8_t* __restrict a = adp + x_lo;
        const int n = x_hi - x_lo;
        for (int x = 0; x < n; ++x) {
          const uint8_t hi = std::max(o[x], q[x]), lo = std::min(o[x], q[x]);
          a[x] = static_cast<uint8_t>(hi - lo);
        }
      }
      for (int x = x_hi; x < W; ++x) adp[x] = kOutsideReference;
      // Window sum along the row in two separable steps of 3 (window 9) or directly.
      int16_t* __restrict h3 = h3_.data();
      std::fill(hs, hs + r, 0);
      std::fill(hs + W - r, hs + W, 0);
      if (r == 4) {
        for (int x = 1; x < W - 1; ++x) h3[x] = static_cast<int16_t>(adp[x - 1] + adp[x] + adp[x + 1]);
        for (int x = 4; x < W - 4; ++x) hs[x] = static_cast<int16_t>(h3[x - 3] + h3[x] + h3[x + 3]);
      } else {
        for (int x = r; x < W - r; ++x) {
          int16_t sum = 0;
          for (int k = -r; k <= r; ++k) sum = static_cast<int16_t>(sum + adp[x + k]);
          hs[x] = sum;
        }
      }
    }
    // Vertical running sums down the band, straight into the slab.
    int16_t* __restrict first = slab + static_cast<size_t>(j) * W;
    std::fill(first, first + W, 0);
    for (int h = 0; h < 2 * r + 1; ++h) {
      const int16_t* __restrict hs = &hsum[static_cast<size_t>(h) * W];
      for (int x = 0; x < W; ++x) first[x] = static_cast<int16_t>(first[x] + hs[x]);
    }
    for (int i = 1; i < rows; ++i) {
      const int16_t* __restrict prev = slab + (static_cast<size_t>(i - 1) * D + j) * W;
      int16_t* __restrict cost = slab + (static_cast<size_t>(i) * D + j) * W;
      const int16_t* __restrict add = &hsum[static_cast<size_t>(i + 2 * r) * W];
      const int16_t* __restrict sub = &hsum[static_cast<size_t>(i - 1) * W];
      for (int x = 0; x < W; ++x) cost[x] = static_cast<int16_t>(prev[x] + add[x] - sub[x]);
    }
    // The best shift so far, per pixel of the band, while the rows are hot in cache.
    const int16_t jj = static_cast<int16_t>(j);
    for (int i = 0; i < rows; ++i) {
      const int16_t* __restrict c = slab + (static_cast<size_t>(i) * D + j) * W;
      int16_t* __restrict bc = &band_best[static_cast<size_t>(i) * W];
      int16_t* __restrict bj = &band_best_j[static_cast<size_t>(i) * W];
      for (int x = 0; x < W; ++x) {
        const bool better = c[x] < bc[x];
        bc[x] = better ? c[x] : bc[x];
        bj[x] = better ? jj : bj[x];
      }
    }
  }

  // Decisions, vectorizable over x: best, then best outside +-1 of it.
  std::vector<int16_t> second(W);
  const int window_area = (2 * r + 1) * (2 * r + 1);
  const float max_cost_sum = static_cast<float>(options_.max_cost * window_area);
  const float min_texture = static_cast<float>(options_.min_texture);
  const float uniqueness = static_cast<float>(options_.uniqueness);
  for (int i = 0; i < rows; ++i) {
    const int y = y_begin + i;
    const int16_t* costs = slab + static_cast<size_t>(i) * D * W;
    const int16_t* __restrict bc = &band_best[static_cast<size_t>(i) * W];
    const int16_t* __restrict bj = &band_best_j[static_cast<size_t>(i) * W];
    int16_t* __restrict sc = second.data();
    std::fill(sc, sc + W, kMaxCost);
    for (int j = 0; j < D; ++j) {
      const int16_t* __restrict c = costs + static_cast<size_t>(j) * W;
      const int16_t jp1 = static_cast<int16_t>(j + 1);
      for (int x = 0; x < W; ++x) {
        // |j - best_j| > 1 in signed 16 bits, so that it vectorizes (SSE2 has signed compares).
        const int16_t t = static_cast<int16_t>(jp1 - bj[x]);
        const int16_t near_mask = static_cast<int16_t>(-((t >= 0) & (t < 3)));
        const int16_t candidate = static_cast<int16_t>(c[x] | (near_mask & kMaxCost));
        sc[x] = std::min(candidate, sc[x]);
      }
    }
    uint16_t* raw_row = out->raw.ptr<uint16_t>(y);
    float* depth_row = out->depth_m.ptr<float>(y);
    float* shift_row = out->shift_px.ptr<float>(y);
    const float* sigma_row = frame_sigma_.ptr<float>(y);
    for (int x = 0; x < W; ++x) {
      raw_row[x] = kRawInvalid;
      depth_row[x] = 0.f;
      shift_row[x] = std::numeric_limits<float>::quiet_NaN();
      if (y < r || y >= H - r || x < r || x >= W - r) {
        ++stats->border;
        continue;
      }
      if (sigma_row[x] < min_texture) {
        ++stats->flat;
        continue;
      }
      const int j = bj[x];
      const float c0 = bc[x];
      if (c0 > max_cost_sum) {
        ++stats->weak;
        continue;
      }
      if (second[x] < c0 * (1.f + uniqueness)) {
        ++stats->ambiguous;
        continue;
      }
      if (j == 0 || j == D - 1) {
        ++stats->out_of_range;
        continue;
      }
      const float cm = costs[static_cast<size_t>(j - 1) * W + x];
      const float cp = costs[static_cast<size_t>(j + 1) * W + x];
      const float denom = 2.f * (cm + cp - 2.f * c0);
      const float delta = denom > 0.f ? (cm - cp) / denom : 0.f;
      const long s8 = static_cast<long>(std::floor(8.f * (static_cast<float>(options_.min_shift_px + j) + delta) + 0.5f));
      const long raw = raw_at_reference_rounded_ - s8;
      if (raw < 0 || raw >= kRawInvalid || raw >= options_.chip.raw_offset) {
        ++stats->out_of_range;
        continue;
      }
      ++stats->valid;
      raw_row[x] = static_cast<uint16_t>(raw);
      shift_row[x] = static_cast<float>(s8) / 8.f;
      depth_row[x] = chip_depth_lut_[raw];
    }
  }
}

void DepthEngine::Compute(const cv::Mat& ir, DepthEngineOutput* out) {
  const auto start = std::chrono::steady_clock::now();
  ROMUNECT_CHECK(out != nullptr);
  const CameraModel& cam = options_.chip.camera;
  if (ir.type() != CV_16UC1) {
    throw InputError("depth engine", "ir", "expected a 16-bit single-channel image (CV_16U), found type " +
                                               std::to_string(ir.type()));
  }
  if (ir.cols != cam.width || ir.rows != cam.height) {
    throw InputError("depth engine", "ir",
                     "image is " + std::to_string(ir.cols) + " x " + std::to_string(ir.rows) + ", the chip takes " +
                         std::to_string(cam.width) + " x " + std::to_string(cam.height));
  }
  Prefilter(ir, options_.prefilter_px, &frame_norm_, &frame_sigma_);
  out->raw.create(ir.size(), CV_16U);
  out->depth_m.create(ir.size(), CV_32F);
  out->shift_px.create(ir.size(), CV_32F);
  const int bands = (ir.rows + kBandRows - 1) / kBandRows;
  const int threads = std::min(options_.threads, bands);
  std::vector<DepthEngineStats> band_stats(threads);
  ParallelRows(threads, bands, [&](int band_begin, int band_end) {
    // Which thread: the block that starts at band_begin.
    int t = 0;
    while (t + 1 < threads && bands * (t + 1) / threads <= band_begin) ++t;
    std::vector<int16_t> slab;
    for (int b = band_begin; b < band_end; ++b) {
      ComputeBand(b * kBandRows, std::min(ir.rows, (b + 1) * kBandRows), &slab, out, &band_stats[t]);
    }
  });
  out->stats = DepthEngineStats{};
  for (const DepthEngineStats& s : band_stats) {
    out->stats.valid += s.valid;
    out->stats.flat += s.flat;
    out->stats.weak += s.weak;
    out->stats.ambiguous += s.ambiguous;
    out->stats.out_of_range += s.out_of_range;
    out->stats.border += s.border;
  }
  out->stats.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// ---------------------------------------------------------------- metric correction

const char* DepthCorrectionModelName(DepthCorrectionModel model) {
  return model == DepthCorrectionModel::kAffineInChipDepth ? "affine_in_chip_depth" : "inverse_affine_in_raw";
}

double ChipDepthM(const ChipGeometry& chip, double raw) {
  if (raw == kRawInvalid || raw >= chip.raw_offset) return 0.0;
  return 8.0 * chip.FocalTimesBaseline() / (chip.raw_offset - raw);
}

double ApplyDepthCorrectionPixel(const DepthCorrection& correction, int row, int col, uint16_t raw,
                                 double chip_depth_m) {
  if (raw == kRawInvalid) return 0.0;
  const double a = correction.a.at<double>(row, col), b = correction.b.at<double>(row, col);
  if (!std::isfinite(a) || !std::isfinite(b)) return 0.0;
  double z = 0.0;
  if (correction.model == DepthCorrectionModel::kAffineInChipDepth) {
    if (!(chip_depth_m > 0.0)) return 0.0;
    z = a * chip_depth_m + b;
  } else {
    const double inv = a * raw + b;
    z = inv > 0.0 ? 1.0 / inv : 0.0;
  }
  return z > 0.0 ? z : 0.0;
}

namespace {

// Shared by both ApplyDepthCorrection overloads: chip_depth(raw, x, y) gives Z_chip.
template <typename ChipDepth>
cv::Mat ApplyRows(const DepthCorrection& correction, const cv::Mat& raw, ChipDepth chip_depth) {
  ROMUNECT_CHECK(raw.type() == CV_16UC1);
  ROMUNECT_CHECK(correction.a.type() == CV_64FC1 && correction.b.type() == CV_64FC1);
  ROMUNECT_CHECK(correction.a.size() == raw.size() && correction.b.size() == raw.size());
  cv::Mat depth(raw.size(), CV_32F, cv::Scalar(0));
  for (int y = 0; y < depth.rows; ++y) {
    const uint16_t* in = raw.ptr<uint16_t>(y);
    float* out = depth.ptr<float>(y);
    for (int x = 0; x < depth.cols; ++x) {
      out[x] = static_cast<float>(ApplyDepthCorrectionPixel(correction, y, x, in[x], chip_depth(in[x], x, y)));
    }
  }
  return depth;
}

// y = a x + b by weighted least squares, accumulated sample by sample. x is shifted by the
// first sample so raw values near 700 keep the normal equations well conditioned.
struct LineFit {
  double x0 = 0.0;
  double w = 0, wx = 0, wy = 0, wxx = 0, wxy = 0;
  void Add(double x, double y, double weight) {
    if (w == 0.0) x0 = x;
    x -= x0;
    w += weight;
    wx += weight * x;
    wy += weight * y;
    wxx += weight * x * x;
    wxy += weight * x * y;
  }
  bool Solve(double* a, double* b) const {
    const double det = w * wxx - wx * wx;
    if (!(w > 0.0) || !(std::abs(det) > 1e-12 * w * w * std::max(1.0, wxx / w))) return false;
    *a = (w * wxy - wx * wy) / det;
    *b = (wy - *a * wx) / w - *a * x0;
    return std::isfinite(*a) && std::isfinite(*b);
  }
};

}  // namespace

cv::Mat ApplyDepthCorrection(const DepthCorrection& correction, const DepthEngineOutput& output) {
  ROMUNECT_CHECK(output.depth_m.type() == CV_32FC1 && output.depth_m.size() == output.raw.size());
  return ApplyRows(correction, output.raw, [&](uint16_t, int x, int y) { return output.depth_m.at<float>(y, x); });
}

cv::Mat ApplyDepthCorrection(const DepthCorrection& correction, const cv::Mat& raw, const ChipGeometry& chip) {
  if (correction.model == DepthCorrectionModel::kInverseAffineInRaw) {
    return ApplyRows(correction, raw, [](uint16_t, int, int) { return 0.0; });
  }
  std::vector<double> lut(kRawInvalid + 1);
  for (int r = 0; r <= kRawInvalid; ++r) lut[r] = ChipDepthM(chip, r);
  return ApplyRows(correction, raw, [&](uint16_t v, int, int) { return v <= kRawInvalid ? lut[v] : 0.0; });
}

DepthCorrection FitDepthCorrection(DepthCorrectionModel model, const std::vector<cv::Mat>& raw,
                                   const std::vector<cv::Mat>& chip_depth_m,
                                   const std::vector<cv::Mat>& truth_depth_m, const DepthFitOptions& options) {
  ROMUNECT_CHECK(!raw.empty() && raw.size() == chip_depth_m.size() && raw.size() == truth_depth_m.size());
  const cv::Size size = raw[0].size();
  for (size_t i = 0; i < raw.size(); ++i) {
    ROMUNECT_CHECK(raw[i].type() == CV_16UC1 && raw[i].size() == size);
    ROMUNECT_CHECK(chip_depth_m[i].type() == CV_32FC1 && chip_depth_m[i].size() == size);
    ROMUNECT_CHECK(truth_depth_m[i].type() == CV_32FC1 && truth_depth_m[i].size() == size);
  }
  const bool affine = model == DepthCorrectionModel::kAffineInChipDepth;
  const size_t n_px = static_cast<size_t>(size.area());
  std::vector<LineFit> fit(n_px);
  std::vector<float> z_lo(n_px, std::numeric_limits<float>::infinity()), z_hi(n_px, 0.0f);
  std::vector<int> count(n_px, 0);
  // Image by image, row by row: each image is read once, in memory order.
  for (size_t i = 0; i < raw.size(); ++i) {
    for (int y = 0; y < size.height; ++y) {
      const uint16_t* r = raw[i].ptr<uint16_t>(y);
      const float* chip = chip_depth_m[i].ptr<float>(y);
      const float* z = truth_depth_m[i].ptr<float>(y);
      for (int x = 0; x < size.width; ++x) {
        if (!(z[x] > 0.0f) || r[x] == kRawInvalid || !(chip[x] > 0.0f)) continue;
        const size_t k = static_cast<size_t>(y) * size.width + x;
        const double z_m = z[x];
        if (affine) {
          fit[k].Add(chip[x], z_m, 1.0);
        } else {
          // Weight Z^4: an error e in 1/Z is an error Z^2 e in depth, so this fits depth.
          fit[k].Add(r[x], 1.0 / z_m, z_m * z_m * z_m * z_m);
        }
        z_lo[k] = std::min(z_lo[k], z[x]);
        z_hi[k] = std::max(z_hi[k], z[x]);
        ++count[k];
      }
    }
  }
  DepthCorrection c;
  c.model = model;
  c.a = cv::Mat(size, CV_64F, cv::Scalar(std::numeric_limits<double>::quiet_NaN()));
  c.b = c.a.clone();
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const size_t k = static_cast<size_t>(y) * size.width + x;
      double a, b;
      if (count[k] < options.min_samples || z_hi[k] - z_lo[k] < options.min_depth_spread_m ||
          !fit[k].Solve(&a, &b)) {
        continue;
      }
      c.a.at<double>(y, x) = a;
      c.b.at<double>(y, x) = b;
    }
  }
  return c;
}

DepthCorrection FitDepthCorrection(DepthCorrectionModel model, const std::vector<DepthEngineOutput>& outputs,
                                   const std::vector<cv::Mat>& truth_depth_m, int min_samples) {
  ROMUNECT_CHECK(outputs.size() == truth_depth_m.size() && !outputs.empty());
  std::vector<cv::Mat> raw, chip;
  for (const DepthEngineOutput& o : outputs) {
    raw.push_back(o.raw);
    chip.push_back(o.depth_m);
  }
  DepthFitOptions options;
  options.min_samples = min_samples;
  return FitDepthCorrection(model, raw, chip, truth_depth_m, options);
}

}  // namespace romunect
