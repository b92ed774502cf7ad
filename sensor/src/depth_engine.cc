#include "romunect/sensor/depth_engine.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "depth_engine_kernel.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/clock.h"
#include "romunect/sensor/cpu_features.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/keep_or_zero.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/sensor/parallel_rows.h"

namespace romunect {
namespace {

namespace internal = depth_engine_internal;

constexpr float kSigmaFloorDn = 2.0f;  // keeps the normalization finite on flat windows
constexpr float kNormScale = 48.0f;    // one local standard deviation = 48 levels of 8 bits
static_assert(internal::kRawNone == kRawInvalid);

// The search kernels compiled in (depth_engine_kernel.h), narrowest first.
constexpr internal::Kernel kKernels[] = {
    {Isa::kScalar, &internal::MatchRowsScalar},
#if ROMUNECT_DEPTH_KERNEL_SSE2
    {Isa::kSse2, &internal::MatchRowsSse2},
#endif
#if ROMUNECT_DEPTH_KERNEL_AVX2
    {Isa::kAvx2, &internal::MatchRowsAvx2},
#endif
#if ROMUNECT_DEPTH_KERNEL_AVX512
    {Isa::kAvx512, &internal::MatchRowsAvx512},
#endif
};

// The kernel for `requested` (ResolveIsa over kKernels); null where it is not compiled in or
// the CPU lacks it.
const internal::Kernel* KernelFor(Isa requested) { return ResolveKernel(requested, kKernels); }

}  // namespace

std::string DepthEngineStats::BriefReport() const {
  std::ostringstream s;
  s << "depth: " << valid << " valid, " << flat << " flat, " << weak << " weak, " << ambiguous << " ambiguous, "
    << out_of_range << " out of range, " << border << " border, " << seconds * 1e3 << " ms";
  return s.str();
}

std::pair<int, int> ReferenceMarginsPx(const DepthEngineOptions& options) {
  // Pixel x at shift s reads reference column x - s, s in [min_shift, min_shift + range).
  return {std::max(0, options.min_shift_px + options.search_range_px - 1), std::max(0, -options.min_shift_px)};
}

cv::Mat ChipReferenceImage(const DepthEngineOptions& options) {
  const ChipGeometry& chip = options.chip;
  ROMUNECT_CHECK_MSG(chip.Problem().empty(), chip.Problem().c_str());
  const auto [left, right] = ReferenceMarginsPx(options);
  Rig stock;
  stock.camera = chip.camera;
  stock.camera.width += left + right;
  stock.camera.cx += left;
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
  stock.depth_engine.chip.camera = stock.camera;
  IrSynthesisOptions quiet;
  quiet.noise = false;
  IrSynthesizer synthesizer(quiet);
  cv::Mat ir;
  synthesizer.Synthesize(stock, FrontoParallelPlane(stock.camera, z, IrMaterial{1.0f, 0.0f, 50.0f}), 0, &ir, nullptr);
  return ir;
}

namespace {

// Box sums are exact integers (squares rounded to float first, as a float image's are), slid
// down the image by columns and along each row, so the means are the bytes cv::boxFilter gives
// on float images (its sums run in double, exact for these integers): float(sum * (1.0 / area)).
// Borders reflect (cv::BORDER_REFLECT). The float arithmetic per pixel runs in a loop of its own
// so that it vectorizes.
// Rows [y_begin, y_end) of DepthEngine::Prefilter, into allocated outputs: row bands give the
// same bytes as the whole image (exact sums), so threads can split it. Sums of squares per
// column in SqColumn, per window in SqWindow (see PrefilterRows).
template <typename SqColumn, typename SqWindow>
void PrefilterRowsIn(const cv::Mat& ir, int window_px, int y_begin, int y_end, cv::Mat* normalized,
                     cv::Mat* local_sigma) {
  const int W = ir.cols, H = ir.rows, r = window_px / 2;
  const double inv_area = 1.0 / (window_px * window_px);
  // Per column, the sums over the window's rows; r reflected columns added on each side.
  std::vector<int32_t> sum(W + 2 * r, 0);
  std::vector<SqColumn> sum_sq(W + 2 * r, 0);
  std::vector<float> mean(W), mean_sq(W);
  auto add_row = [&](int y, bool add) {
    const uint16_t* v = ir.ptr<uint16_t>(cv::borderInterpolate(y, H, cv::BORDER_REFLECT));
    int32_t* s = sum.data() + r;
    SqColumn* q = sum_sq.data() + r;
    for (int x = 0; x < W; ++x) {
      const float f = v[x];
      const SqColumn f2 = static_cast<SqColumn>(f * f);
      s[x] += add ? v[x] : -v[x];
      q[x] += add ? f2 : -f2;
    }
  };
  for (int dy = -r; dy <= r; ++dy) add_row(y_begin + dy, true);
  for (int y = y_begin; y < y_end; ++y) {
    if (y > y_begin) {
      add_row(y + r, true);
      add_row(y - r - 1, false);
    }
    for (int k = 0; k < r; ++k) {
      const int left = r + cv::borderInterpolate(k - r, W, cv::BORDER_REFLECT);
      const int right = r + cv::borderInterpolate(W + k, W, cv::BORDER_REFLECT);
      sum[k] = sum[left];
      sum_sq[k] = sum_sq[left];
      sum[r + W + k] = sum[right];
      sum_sq[r + W + k] = sum_sq[right];
    }
    int32_t window = 0;
    SqWindow window_sq = 0;
    for (int k = 0; k < 2 * r; ++k) {
      window += sum[k];
      window_sq += static_cast<SqWindow>(sum_sq[k]);
    }
    for (int x = 0; x < W; ++x) {
      window += sum[x + 2 * r];
      window_sq += static_cast<SqWindow>(sum_sq[x + 2 * r]);
      mean[x] = static_cast<float>(window * inv_area);
      mean_sq[x] = static_cast<float>(static_cast<double>(window_sq) * inv_area);
      window -= sum[x];
      window_sq -= static_cast<SqWindow>(sum_sq[x]);
    }
    const uint16_t* v = ir.ptr<uint16_t>(y);
    float* sigma_row = local_sigma->ptr<float>(y);
    uint8_t* n = normalized->ptr<uint8_t>(y);
    for (int x = 0; x < W; ++x) sigma_row[x] = std::max(mean_sq[x] - mean[x] * mean[x], 0.f);
    cv::Mat sigma_mat(1, W, CV_32F, sigma_row);
    cv::sqrt(sigma_mat, sigma_mat);  // SIMD, correctly rounded (std::sqrt's errno path is not)
    for (int x = 0; x < W; ++x) {
      const float value = 128.f +
                          kNormScale * (static_cast<float>(v[x]) - mean[x]) / std::max(sigma_row[x], kSigmaFloorDn);
      // Clamped to [0, 255], rounded half up; written so that GCC vectorizes it (the same
      // floats as clamp(value, 0, 255) + 0.5).
      n[x] = static_cast<uint8_t>(static_cast<int32_t>(std::min(std::max(value + 0.5f, 0.5f), 255.5f)));
    }
  }
}

// Whether PrefilterRows may sum squares in 32 bits: values below 2^12 (10-bit IR) square
// exactly in float, and a window of at most 11 x 11 of them sums below 2^31.
bool SquaresFit32Bits(const cv::Mat& ir, int window_px) {
  double max_value = 0.0;
  cv::minMaxLoc(ir, nullptr, &max_value);
  return max_value < 4096.0 && window_px <= 11;
}

void PrefilterRows(const cv::Mat& ir, int window_px, bool squares_fit_32_bits, int y_begin, int y_end,
                   cv::Mat* normalized, cv::Mat* local_sigma) {
  if (squares_fit_32_bits) {
    PrefilterRowsIn<int32_t, int32_t>(ir, window_px, y_begin, y_end, normalized, local_sigma);
  } else {
    // Float-rounded squares of 16-bit values: integers below 2^53, exact in double and int64.
    PrefilterRowsIn<double, int64_t>(ir, window_px, y_begin, y_end, normalized, local_sigma);
  }
}

}  // namespace

void DepthEngine::Prefilter(const cv::Mat& ir, int window_px, cv::Mat* normalized, cv::Mat* local_sigma) {
  ROMUNECT_CHECK(ir.type() == CV_16UC1);
  local_sigma->create(ir.size(), CV_32F);
  normalized->create(ir.size(), CV_8U);
  PrefilterRows(ir, window_px, SquaresFit32Bits(ir, window_px), 0, ir.rows, normalized, local_sigma);
}

DepthEngine::DepthEngine(const DepthEngineOptions& options) : DepthEngine(options, ChipReferenceImage(options)) {}

DepthEngine::DepthEngine(const DepthEngineOptions& options, const cv::Mat& reference_ir)
    : options_(options), isa_(KernelFor(Isa::kAuto)->isa) {
  ROMUNECT_CHECK_MSG(options.Problem().empty(), options.Problem().c_str());
  ROMUNECT_CHECK(reference_ir.type() == CV_16U);
  const auto [margin_left, margin_right] = ReferenceMarginsPx(options);
  const bool cropped = reference_ir.cols == options.chip.camera.width;
  ROMUNECT_CHECK(cropped || reference_ir.cols == options.chip.camera.width + margin_left + margin_right);
  ROMUNECT_CHECK(reference_ir.rows == options.chip.camera.height);
  const int left = cropped ? 0 : margin_left;
  reference_ir_ = reference_ir.clone();
  cv::Mat reference_norm, sigma;
  Prefilter(reference_ir_, options_.prefilter_px, &reference_norm, &sigma);
  raw_at_reference_rounded_ = static_cast<int>(std::lround(RawAtReference()));
  chip_depth_lut_.resize(kRawInvalid + 1);
  for (int raw = 0; raw <= kRawInvalid; ++raw) chip_depth_lut_[raw] = static_cast<float>(ChipDepthM(raw));

  // Search tables (depth_engine_kernel.h): padded index p holds the camera's column
  // W - 1 - min_shift - p (reference column + left), so that pixel x's shifts j read
  // p = W - 1 - x + j, ascending in j.
  const int W = options.chip.camera.width, D = options_.search_range_px;
  const int blocks = (D + internal::kLanesPerBlock - 1) / internal::kLanesPerBlock;
  ROMUNECT_CHECK(blocks <= internal::kMaxBlocks);
  search_lanes_ = blocks * internal::kLanesPerBlock;
  // Rows: the window's radius of reflected rows above and below, as the frame's (KernelArgs).
  const int H = reference_ir.rows, r = options_.window_px / 2;
  reference_row_length_ = W + search_lanes_;
  reference_reversed_.assign(static_cast<size_t>(H + 2 * r) * reference_row_length_, 0);
  reference_outside_.assign(reference_row_length_, 0xFF);
  for (int p = 0; p < reference_row_length_; ++p) {
    const int col = W - 1 - options_.min_shift_px - p + left;
    if (col < 0 || col >= reference_ir.cols) continue;
    reference_outside_[p] = 0;
    for (int stored = 0; stored < H + 2 * r; ++stored) {
      const int y = cv::borderInterpolate(stored - r, H, cv::BORDER_REFLECT);
      reference_reversed_[static_cast<size_t>(stored) * reference_row_length_ + p] = reference_norm.at<uint8_t>(y, col);
    }
  }
  // The decision rules on integer window costs, in the float arithmetic of depth_engine.h: a
  // best cost c0 is weak when float(c0) > max_cost x area (a window clipped to n of its columns
  // at the image's sides: window x n), ambiguous when another cost is below c0 (1 + uniqueness),
  // i.e. below ceil of it (costs are integers; all are below kCostMax).
  max_best_cost_of_columns_.resize(options_.window_px + 1);
  for (int n = 0; n <= options_.window_px; ++n) {
    max_best_cost_of_columns_[n] = static_cast<int>(std::min(
        std::floor(static_cast<float>(options_.max_cost * options_.window_px * n)), float{internal::kCostMax}));
  }
  const int max_best_cost = max_best_cost_of_columns_.back();  // the whole window
  const float uniqueness = static_cast<float>(options_.uniqueness);
  ambiguous_below_.resize(max_best_cost + 1);
  for (int c0 = 0; c0 <= max_best_cost; ++c0) {
    const float t = static_cast<float>(c0) * (1.f + uniqueness);
    ambiguous_below_[c0] = static_cast<int16_t>(std::ceil(std::min(t, float{internal::kCostMax})));
  }
  // Columns x whose shifts j < D all read a reference column (an interval).
  auto clean = [&](int x) {
    for (int j = 0; j < D; ++j) {
      if (reference_outside_[W - 1 - x + j] != 0) return false;
    }
    return true;
  };
  if (options_.disparity_distortion.Active()) {
    distortion_beta_ = DisparityDistortionBeta(options_.disparity_distortion, W, reference_ir.rows);
  }
  clean_begin_ = 0;
  while (clean_begin_ < W && !clean(clean_begin_)) ++clean_begin_;
  clean_end_ = clean_begin_;
  while (clean_end_ < W && clean(clean_end_)) ++clean_end_;
}

void DepthEngine::set_isa(Isa isa) {
  const internal::Kernel* kernel = KernelFor(isa);
  ROMUNECT_CHECK_MSG(kernel != nullptr, ToString(isa));
  isa_ = kernel->isa;
}

double DepthEngine::RawAtReference() const {
  const ChipGeometry& c = options_.chip;
  return c.raw_offset - 8.0 * c.FocalTimesBaseline() / c.reference_distance_m;
}

double DepthEngine::ChipDepthM(int raw) const { return romunect::ChipDepthM(options_.chip, raw); }

double DepthEngine::ShiftOfRaw(int raw) const { return (raw_at_reference_rounded_ - raw) / 8.0; }

void DepthEngine::Compute(const cv::Mat& ir, DepthEngineOutput* out) {
  const Stopwatch stopwatch;
  ROMUNECT_CHECK(out != nullptr);
  const CameraModel& cam = options_.chip.camera;
  if (ir.type() != CV_16UC1) {
    throw InputError("depth engine", "ir",
                     "expected a 16-bit single-channel image (CV_16U), found type " + std::to_string(ir.type()));
  }
  if (ir.cols != cam.width || ir.rows != cam.height) {
    throw InputError("depth engine", "ir",
                     "image is " + std::to_string(ir.cols) + " x " + std::to_string(ir.rows) + ", the chip takes " +
                         std::to_string(cam.width) + " x " + std::to_string(cam.height));
  }
  const int W = ir.cols, H = ir.rows, r = options_.window_px / 2;
  const int threads = std::clamp(options_.threads, 1, H);
  // Thread t of ParallelRows' split of n rows: the one whose block starts at `begin`.
  auto thread_of = [threads](int begin, int n) {
    int t = 0;
    while (t + 1 < threads && n * (t + 1) / threads <= begin) ++t;
    return t;
  };
  std::vector<double> thread_cpu_s(threads, 0.0);
  // The prefiltered frame with r reflected rows above and below (KernelArgs), as the reference.
  frame_norm_.create(H + 2 * r, W, CV_8U);
  frame_sigma_.create(ir.size(), CV_32F);
  cv::Mat frame_norm_rows = frame_norm_.rowRange(r, r + H);
  const bool squares_fit_32_bits = SquaresFit32Bits(ir, options_.prefilter_px);
  ParallelRows(threads, H, [&](int row_begin, int row_end) {
    const double cpu_start = ThreadCpuSeconds();
    PrefilterRows(ir, options_.prefilter_px, squares_fit_32_bits, row_begin, row_end, &frame_norm_rows,
                  &frame_sigma_);
    thread_cpu_s[thread_of(row_begin, H)] += ThreadCpuSeconds() - cpu_start;
  });
  for (int k = 0; k < r; ++k) {
    frame_norm_rows.row(cv::borderInterpolate(k - r, H, cv::BORDER_REFLECT)).copyTo(frame_norm_.row(k));
    frame_norm_rows.row(cv::borderInterpolate(H + k, H, cv::BORDER_REFLECT)).copyTo(frame_norm_.row(r + H + k));
  }
  out->raw.create(ir.size(), CV_16U);
  out->depth_m.create(ir.size(), CV_32F);
  out->shift_px.create(ir.size(), CV_32F);
  internal::KernelArgs args;
  args.width = W;
  args.radius = r;
  args.searched_width = std::max(0, W - kChipBorderColumns);
  args.range = options_.search_range_px;
  args.blocks = search_lanes_ / internal::kLanesPerBlock;
  args.min_shift_px = options_.min_shift_px;
  args.obs = frame_norm_.ptr<uint8_t>();
  args.obs_step = frame_norm_.step1();
  args.sigma = frame_sigma_.ptr<float>();
  args.sigma_step = frame_sigma_.step1();
  args.ref_rev = reference_reversed_.data();
  args.ref_step = reference_row_length_;
  args.outside = reference_outside_.data();
  args.clean_begin = clean_begin_;
  args.clean_end = clean_end_;
  args.min_texture = static_cast<float>(options_.min_texture);
  args.max_best_cost_of_columns = max_best_cost_of_columns_.data();
  args.ambiguous_below = ambiguous_below_.data();
  args.raw_at_reference = raw_at_reference_rounded_;
  args.equiangular_weight = static_cast<float>(options_.subpixel_equiangular_weight);
  args.rounding_slope = static_cast<float>(options_.subpixel_rounding_slope);
  args.quarter_correction = static_cast<float>(options_.subpixel_quarter_correction);
  args.eighth_correction = static_cast<float>(options_.subpixel_eighth_correction);
  // raw < raw_offset (a double) and below kRawInvalid.
  args.raw_limit = static_cast<int>(std::clamp(std::ceil(options_.chip.raw_offset), 0.0, double{kRawInvalid}));
  args.chip_depth_lut = chip_depth_lut_.data();
  args.raw = out->raw.ptr<uint16_t>();
  args.raw_step = out->raw.step1();
  args.depth_m = out->depth_m.ptr<float>();
  args.shift_px = out->shift_px.ptr<float>();
  args.float_step = out->depth_m.step1();
  ROMUNECT_CHECK(out->shift_px.step1() == args.float_step);
  if (!distortion_beta_.radial.empty()) {
    for (const cv::Mat* m : {&distortion_beta_.radial, &distortion_beta_.pattern}) {
      ROMUNECT_CHECK(m->isContinuous() && m->step1() == args.float_step);
    }
    const DisparityDistortion& d = options_.disparity_distortion;
    args.distortion_radial = distortion_beta_.radial.ptr<float>();
    args.distortion_pattern = distortion_beta_.pattern.ptr<float>();
    args.distortion_alpha0 = static_cast<float>(d.alpha0);
    args.distortion_alpha1 = static_cast<float>(d.alpha1);
    args.distortion_pattern_alpha0 = static_cast<float>(d.pattern_alpha0);
    args.distortion_pattern_alpha1 = static_cast<float>(d.pattern_alpha1);
  }
  const internal::MatchRowsFn match_rows = KernelFor(isa_)->match_rows;
  std::vector<internal::KernelStats> thread_stats(threads);
  ParallelRows(threads, H, [&](int row_begin, int row_end) {
    const double cpu_start = ThreadCpuSeconds();
    const int t = thread_of(row_begin, H);
    std::vector<int16_t> scratch(internal::KernelScratchSize(W, args.blocks));
    internal::KernelArgs band = args;
    band.scratch = scratch.data();
    band.y_begin = row_begin;
    band.y_end = row_end;
    match_rows(band, &thread_stats[t]);
    thread_cpu_s[t] += ThreadCpuSeconds() - cpu_start;
  });
  out->stats = DepthEngineStats{};
  for (const internal::KernelStats& s : thread_stats) {
    out->stats.valid += s.valid;
    out->stats.flat += s.flat;
    out->stats.weak += s.weak;
    out->stats.ambiguous += s.ambiguous;
    out->stats.out_of_range += s.out_of_range;
    out->stats.border += s.border;
  }
  out->stats.busiest_thread_cpu_s = *std::max_element(thread_cpu_s.begin(), thread_cpu_s.end());
  out->stats.seconds = stopwatch.seconds();
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
  cv::Mat depth(raw.size(), CV_32F);
  for (int y = 0; y < depth.rows; ++y) {
    const uint16_t* in = raw.ptr<uint16_t>(y);
    float* out = depth.ptr<float>(y);
    if (correction.model == DepthCorrectionModel::kInverseAffineInRaw) {
      // ApplyDepthCorrectionPixel's exact model (the same double operations, so the same
      // floats) in a form GCC vectorizes: every value computed, the pixel kept by KeepOrZero. A
      // non-finite a or b makes inv NaN or infinite, so "inv finite and > 0" is the per-pixel
      // test of a, b and inv.
      const double* a = correction.a.ptr<double>(y);
      const double* b = correction.b.ptr<double>(y);
      for (int x = 0; x < depth.cols; ++x) {
        const double inv = a[x] * in[x] + b[x];
        const float z = static_cast<float>(1.0 / inv);
        const bool ok = (in[x] != kRawInvalid) & (inv > 0.0) & (inv <= std::numeric_limits<double>::max());
        out[x] = KeepOrZero(ok, z);
      }
      continue;
    }
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
                                   const std::vector<cv::Mat>& chip_depth_m, const std::vector<cv::Mat>& truth_depth_m,
                                   const DepthFitOptions& options) {
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
      if (count[k] < options.min_samples || z_hi[k] - z_lo[k] < options.min_depth_spread_m || !fit[k].Solve(&a, &b)) {
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
