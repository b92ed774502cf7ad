#include "romunect/calib/depth_correction.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect::calib {
namespace {

constexpr const char* kSource = "depth correction";
constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// Weighted least squares of y = a x + b, accumulated sample by sample. x is shifted by the
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

double ChipDepthModel::DepthM(double raw) const {
  if (raw == invalid_raw) return 0.0;
  const double inv = c0_per_m + c1_per_m * raw;
  return inv > 0.0 ? 1.0 / inv : 0.0;
}

ChipDepthModel ChipDepthModel::FromChip(double focal_times_baseline_px_m, double raw_offset) {
  ChipDepthModel chip;
  chip.c0_per_m = raw_offset / (8.0 * focal_times_baseline_px_m);
  chip.c1_per_m = -1.0 / (8.0 * focal_times_baseline_px_m);
  return chip;
}

const char* DepthModelKindName(DepthModelKind kind) {
  switch (kind) {
    case DepthModelKind::kNone: return "none";
    case DepthModelKind::kAffineDepth: return "affine_depth";
    case DepthModelKind::kInverseDepthRaw: return "inverse_depth_raw";
  }
  return "none";
}

double DepthModel::ApplyPixel(int row, int col, double raw) const {
  if (raw == chip.invalid_raw) return 0.0;
  if (kind == DepthModelKind::kNone) return chip.DepthM(raw);
  const double pa = a.at<float>(row, col), pb = b.at<float>(row, col);
  if (!std::isfinite(pa) || !std::isfinite(pb)) return 0.0;
  if (kind == DepthModelKind::kInverseDepthRaw) {
    const double inv = pa * raw + pb;
    return inv > 0.0 ? 1.0 / inv : 0.0;
  }
  const double d = chip.DepthM(raw);
  if (d <= 0.0) return 0.0;
  const double z = pa * d + pb;
  return z > 0.0 ? z : 0.0;
}

cv::Mat DepthModel::Apply(const cv::Mat& raw) const {
  ROMUNECT_CHECK(raw.type() == CV_16UC1);
  if (kind != DepthModelKind::kNone) {
    ROMUNECT_CHECK(a.type() == CV_32FC1 && b.type() == CV_32FC1);
    ROMUNECT_CHECK(raw.size() == a.size() && raw.size() == b.size());
  }
  cv::Mat depth_m(raw.size(), CV_32FC1);
  for (int r = 0; r < raw.rows; ++r) {
    const uint16_t* in = raw.ptr<uint16_t>(r);
    float* out = depth_m.ptr<float>(r);
    for (int c = 0; c < raw.cols; ++c) out[c] = static_cast<float>(ApplyPixel(r, c, in[c]));
  }
  return depth_m;
}

std::string DepthCorrectionOptions::Problem() const {
  if (min_planes < 2) return "min_planes is " + std::to_string(min_planes) + "; a line needs at least 2";
  if (!(min_plane_coverage >= 0.0 && min_plane_coverage <= 1.0)) return "min_plane_coverage must be in [0, 1]";
  if (!(min_depth_spread_m >= 0.0)) return "min_depth_spread_m must be >= 0";
  if (!(std::isfinite(chip.c0_per_m) && std::isfinite(chip.c1_per_m) && chip.c1_per_m != 0.0)) {
    return "chip model needs finite c0 and a non-zero c1";
  }
  return "";
}

std::string DepthCorrectionResult::BriefReport() const {
  char line[300];
  std::snprintf(line, sizeof(line),
                "depth correction: %d pixels fitted (%d not); exact model (1/Z affine in raw) RMS "
                "%.4f mm, max %.4f mm; paper's affine model RMS %.4f mm, max %.4f mm",
                fitted_pixels, unfitted_pixels, inverse_rms_m * 1e3, inverse_max_m * 1e3,
                affine_rms_m * 1e3, affine_max_m * 1e3);
  return line;
}

namespace {

// PlaneDepth over a precomputed ray table (CV_32FC2 of (x_n, y_n)), so a fit over many planes
// undistorts every pixel once.
cv::Mat PlaneDepthFromRays(const cv::Mat& rays, const Pose& T_C_K) {
  const Eigen::Vector3d n = T_C_K.linear().col(2);
  const double n_dot_t = n.dot(T_C_K.translation());
  cv::Mat depth_m(rays.rows, rays.cols, CV_32FC1);
  for (int r = 0; r < rays.rows; ++r) {
    const cv::Vec2f* ray = rays.ptr<cv::Vec2f>(r);
    float* out = depth_m.ptr<float>(r);
    for (int c = 0; c < rays.cols; ++c) {
      const double n_dot_ray = n.x() * ray[c][0] + n.y() * ray[c][1] + n.z();
      const double z = std::abs(n_dot_ray) > 1e-9 ? n_dot_t / n_dot_ray : 0.0;
      out[c] = z > 0.0 ? static_cast<float>(z) : 0.0f;
    }
  }
  return depth_m;
}

}  // namespace

cv::Mat PlaneDepth(const CameraModel& camera, const Pose& T_C_K) {
  return PlaneDepthFromRays(camera.RayTable(), T_C_K);
}

DepthCorrectionResult FitDepthCorrection(const CameraModel& camera, const std::vector<PlaneCapture>& captures,
                                         const DepthCorrectionOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  if (const std::string p = camera.Problem(); !p.empty()) throw InputError(kSource, "camera", p);
  if (static_cast<int>(captures.size()) < options.min_planes) {
    throw InputError(kSource, "captures",
                     std::to_string(captures.size()) + " plane captures; need at least " +
                         std::to_string(options.min_planes) +
                         " at different distances over the measuring range");
  }
  const int w = camera.width, h = camera.height;
  const size_t n_px = static_cast<size_t>(w) * h;
  std::vector<cv::Mat> truth(captures.size());
  const cv::Mat rays = camera.RayTable();
  for (size_t i = 0; i < captures.size(); ++i) {
    const std::string field = "captures[" + std::to_string(i) + "]";
    const cv::Mat& raw = captures[i].raw;
    if (raw.type() != CV_16UC1 || raw.cols != w || raw.rows != h) {
      throw InputError(kSource, field + ".raw",
                       "raw depth must be CV_16U " + std::to_string(w) + "x" + std::to_string(h) +
                           " (the camera's size); got " + cv::typeToString(raw.type()) + " " +
                           std::to_string(raw.cols) + "x" + std::to_string(raw.rows));
    }
    truth[i] = PlaneDepthFromRays(rays, captures[i].T_C_K);
    size_t valid = 0;
    for (int r = 0; r < h; ++r) {
      for (int c = 0; c < w; ++c) {
        valid += truth[i].at<float>(r, c) > 0.0f && raw.at<uint16_t>(r, c) != options.chip.invalid_raw;
      }
    }
    const double coverage = static_cast<double>(valid) / n_px;
    if (coverage < options.min_plane_coverage) {
      char text[300];
      std::snprintf(text, sizeof(text),
                    "the plane covers %.1f %% of the image with valid depth; need %.1f %%: place the "
                    "camera so that the reference plane fills the whole view",
                    100.0 * coverage, 100.0 * options.min_plane_coverage);
      throw InputError(kSource, field, text);
    }
  }

  std::vector<LineFit> inverse_fit(n_px), affine_fit(n_px);
  std::vector<float> z_lo(n_px, std::numeric_limits<float>::infinity()), z_hi(n_px, 0.0f);
  std::vector<int> count(n_px, 0);
  for (size_t i = 0; i < captures.size(); ++i) {
    for (int r = 0; r < h; ++r) {
      const uint16_t* raw = captures[i].raw.ptr<uint16_t>(r);
      const float* z = truth[i].ptr<float>(r);
      for (int c = 0; c < w; ++c) {
        const double d_chip = options.chip.DepthM(raw[c]);
        if (!(z[c] > 0.0f) || raw[c] == options.chip.invalid_raw || d_chip <= 0.0) continue;
        const size_t k = static_cast<size_t>(r) * w + c;
        const double z_m = z[c];
        // Weight Z^4: an error e in 1/Z is an error Z^2 e in depth, so this fits depth.
        inverse_fit[k].Add(raw[c], 1.0 / z_m, z_m * z_m * z_m * z_m);
        affine_fit[k].Add(d_chip, z_m, 1.0);
        z_lo[k] = std::min(z_lo[k], z[c]);
        z_hi[k] = std::max(z_hi[k], z[c]);
        ++count[k];
      }
    }
  }

  DepthCorrectionResult result;
  result.inverse = {DepthModelKind::kInverseDepthRaw, cv::Mat(h, w, CV_32FC1, kNaN), cv::Mat(h, w, CV_32FC1, kNaN), options.chip};
  result.affine = {DepthModelKind::kAffineDepth, cv::Mat(h, w, CV_32FC1, kNaN), cv::Mat(h, w, CV_32FC1, kNaN), options.chip};
  for (int r = 0; r < h; ++r) {
    for (int c = 0; c < w; ++c) {
      const size_t k = static_cast<size_t>(r) * w + c;
      double a1, b1, a2, b2;
      if (count[k] < options.min_planes || z_hi[k] - z_lo[k] < options.min_depth_spread_m ||
          !inverse_fit[k].Solve(&a1, &b1) || !affine_fit[k].Solve(&a2, &b2)) {
        ++result.unfitted_pixels;
        continue;
      }
      result.inverse.a.at<float>(r, c) = static_cast<float>(a1);
      result.inverse.b.at<float>(r, c) = static_cast<float>(b1);
      result.affine.a.at<float>(r, c) = static_cast<float>(a2);
      result.affine.b.at<float>(r, c) = static_cast<float>(b2);
      ++result.fitted_pixels;
    }
  }

  // Residuals of both models in depth, over every fitted sample, after float rounding of the
  // maps (what a loaded file gives).
  std::vector<double> sq_inverse(n_px, 0.0), sq_affine(n_px, 0.0);
  double sum_inverse = 0.0, sum_affine = 0.0;
  size_t samples = 0;
  for (size_t i = 0; i < captures.size(); ++i) {
    for (int r = 0; r < h; ++r) {
      const uint16_t* raw = captures[i].raw.ptr<uint16_t>(r);
      const float* z = truth[i].ptr<float>(r);
      for (int c = 0; c < w; ++c) {
        const size_t k = static_cast<size_t>(r) * w + c;
        if (!std::isfinite(result.inverse.a.at<float>(r, c)) || !(z[c] > 0.0f) ||
            raw[c] == options.chip.invalid_raw || options.chip.DepthM(raw[c]) <= 0.0) {
          continue;
        }
        const double e1 = result.inverse.ApplyPixel(r, c, raw[c]) - z[c];
        const double e2 = result.affine.ApplyPixel(r, c, raw[c]) - z[c];
        sq_inverse[k] += e1 * e1;
        sq_affine[k] += e2 * e2;
        sum_inverse += e1 * e1;
        sum_affine += e2 * e2;
        result.inverse_max_m = std::max(result.inverse_max_m, std::abs(e1));
        result.affine_max_m = std::max(result.affine_max_m, std::abs(e2));
        ++samples;
      }
    }
  }
  if (samples > 0) {
    result.inverse_rms_m = std::sqrt(sum_inverse / samples);
    result.affine_rms_m = std::sqrt(sum_affine / samples);
  }
  result.inverse_residual_rms_m = cv::Mat(h, w, CV_32FC1, kNaN);
  result.affine_residual_rms_m = cv::Mat(h, w, CV_32FC1, kNaN);
  for (int r = 0; r < h; ++r) {
    for (int c = 0; c < w; ++c) {
      const size_t k = static_cast<size_t>(r) * w + c;
      if (!std::isfinite(result.inverse.a.at<float>(r, c)) || count[k] == 0) continue;
      result.inverse_residual_rms_m.at<float>(r, c) = static_cast<float>(std::sqrt(sq_inverse[k] / count[k]));
      result.affine_residual_rms_m.at<float>(r, c) = static_cast<float>(std::sqrt(sq_affine[k] / count[k]));
    }
  }
  if (result.fitted_pixels == 0) {
    throw InputError(kSource, "captures",
                     "no pixel has " + std::to_string(options.min_planes) + " valid samples spread over " +
                         std::to_string(options.min_depth_spread_m * 1e3) +
                         " mm of depth; capture the plane at more distinct distances");
  }
  return result;
}

}  // namespace romunect::calib
