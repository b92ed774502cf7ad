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

// Float rounding of a fitted map (the calibration file stores CV_32F), kept as CV_64F.
cv::Mat RoundToFloat(const cv::Mat& m) {
  cv::Mat f, d;
  m.convertTo(f, CV_32F);
  f.convertTo(d, CV_64F);
  return d;
}

}  // namespace

ChipGeometry StockChipGeometry() { return RigPreset("kinect-v1").depth_engine.chip; }

std::string DepthCorrectionOptions::Problem() const {
  if (min_planes < 2) return "min_planes is " + std::to_string(min_planes) + "; a line needs at least 2";
  if (!(min_plane_coverage >= 0.0 && min_plane_coverage <= 1.0)) return "min_plane_coverage must be in [0, 1]";
  if (!(min_depth_spread_m >= 0.0)) return "min_depth_spread_m must be >= 0";
  if (!(std::isfinite(chip.FocalTimesBaseline()) && chip.FocalTimesBaseline() > 0.0 &&
        std::isfinite(chip.raw_offset))) {
    return "chip needs a positive finite focal length times baseline and a finite raw_offset";
  }
  return "";
}

std::string DepthCorrectionResult::BriefReport() const {
  char line[300];
  std::snprintf(line, sizeof(line),
                "depth correction: %d pixels fitted (%d not); exact model (1/Z affine in raw) RMS "
                "%.4f mm, max %.4f mm; paper's affine model RMS %.4f mm, max %.4f mm",
                fitted_pixels, unfitted_pixels, inverse_rms_m * 1e3, inverse_max_m * 1e3, affine_rms_m * 1e3,
                affine_max_m * 1e3);
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

namespace {

// The ground truth depth of every capture's plane, after checking that each capture fits the
// camera and covers enough of the image with valid depth.
std::vector<cv::Mat> TruthDepths(const CameraModel& camera, const std::vector<PlaneCapture>& captures,
                                 const DepthCorrectionOptions& options) {
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
        valid += truth[i].at<float>(r, c) > 0.0f && raw.at<uint16_t>(r, c) != kRawInvalid;
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
  return truth;
}

// The chip's depth of every raw value, once per capture (the affine model's input).
std::vector<cv::Mat> ChipDepths(const std::vector<PlaneCapture>& captures, const ChipGeometry& chip) {
  std::vector<double> chip_lut(kRawInvalid + 1);
  for (int v = 0; v <= kRawInvalid; ++v) chip_lut[v] = ChipDepthM(chip, v);
  std::vector<cv::Mat> chip_depth(captures.size());
  for (size_t i = 0; i < captures.size(); ++i) {
    const cv::Mat& raw_image = captures[i].raw;
    chip_depth[i] = cv::Mat(raw_image.rows, raw_image.cols, CV_32FC1);
    for (int r = 0; r < raw_image.rows; ++r) {
      const uint16_t* raw = raw_image.ptr<uint16_t>(r);
      float* out = chip_depth[i].ptr<float>(r);
      for (int c = 0; c < raw_image.cols; ++c) {
        out[c] = raw[c] <= kRawInvalid ? static_cast<float>(chip_lut[raw[c]]) : 0.0f;
      }
    }
  }
  return chip_depth;
}

// Both models through the sensor model's one per-pixel fit, rounded to float as a file stores
// them; a pixel is fitted in both models or in neither.
void FitBothModels(const std::vector<PlaneCapture>& captures, const std::vector<cv::Mat>& chip_depth,
                   const std::vector<cv::Mat>& truth, const DepthCorrectionOptions& options,
                   DepthCorrectionResult* result) {
  std::vector<cv::Mat> raws(captures.size());
  for (size_t i = 0; i < captures.size(); ++i) raws[i] = captures[i].raw;
  DepthFitOptions fit;
  fit.min_samples = options.min_planes;
  fit.min_depth_spread_m = options.min_depth_spread_m;
  result->inverse = FitDepthCorrection(DepthCorrectionModel::kInverseAffineInRaw, raws, chip_depth, truth, fit);
  result->affine = FitDepthCorrection(DepthCorrectionModel::kAffineInChipDepth, raws, chip_depth, truth, fit);
  for (DepthCorrection* m : {&result->inverse, &result->affine}) {
    m->a = RoundToFloat(m->a);
    m->b = RoundToFloat(m->b);
  }
  for (int r = 0; r < result->inverse.a.rows; ++r) {
    for (int c = 0; c < result->inverse.a.cols; ++c) {
      double& ia = result->inverse.a.at<double>(r, c);
      double& aa = result->affine.a.at<double>(r, c);
      if (std::isfinite(ia) && std::isfinite(aa)) {
        ++result->fitted_pixels;
        continue;
      }
      ++result->unfitted_pixels;
      ia = result->inverse.b.at<double>(r, c) = kNaN;
      aa = result->affine.b.at<double>(r, c) = kNaN;
    }
  }
}

// Residuals of both models in depth, over every fitted sample, after float rounding of the maps
// (what a loaded file gives): overall RMS and maximum, and per pixel RMS.
void ComputeResiduals(const std::vector<PlaneCapture>& captures, const std::vector<cv::Mat>& chip_depth,
                      const std::vector<cv::Mat>& truth, int w, int h, DepthCorrectionResult* result) {
  const size_t n_px = static_cast<size_t>(w) * h;
  std::vector<double> sq_inverse(n_px, 0.0), sq_affine(n_px, 0.0);
  std::vector<int> count(n_px, 0);
  double sum_inverse = 0.0, sum_affine = 0.0;
  size_t samples = 0;
  for (size_t i = 0; i < captures.size(); ++i) {
    for (int r = 0; r < h; ++r) {
      const uint16_t* raw = captures[i].raw.ptr<uint16_t>(r);
      const float* z = truth[i].ptr<float>(r);
      const float* chip = chip_depth[i].ptr<float>(r);
      const double* fitted = result->inverse.a.ptr<double>(r);
      for (int c = 0; c < w; ++c) {
        const size_t k = static_cast<size_t>(r) * w + c;
        if (!std::isfinite(fitted[c]) || !(z[c] > 0.0f) || raw[c] == kRawInvalid || !(chip[c] > 0.0f)) continue;
        const double e1 = ApplyDepthCorrectionPixel(result->inverse, r, c, raw[c], chip[c]) - z[c];
        const double e2 = ApplyDepthCorrectionPixel(result->affine, r, c, raw[c], chip[c]) - z[c];
        sq_inverse[k] += e1 * e1;
        sq_affine[k] += e2 * e2;
        sum_inverse += e1 * e1;
        sum_affine += e2 * e2;
        result->inverse_max_m = std::max(result->inverse_max_m, std::abs(e1));
        result->affine_max_m = std::max(result->affine_max_m, std::abs(e2));
        ++count[k];
        ++samples;
      }
    }
  }
  if (samples > 0) {
    result->inverse_rms_m = std::sqrt(sum_inverse / samples);
    result->affine_rms_m = std::sqrt(sum_affine / samples);
  }
  result->inverse_residual_rms_m = cv::Mat(h, w, CV_32FC1, kNaN);
  result->affine_residual_rms_m = cv::Mat(h, w, CV_32FC1, kNaN);
  for (int r = 0; r < h; ++r) {
    for (int c = 0; c < w; ++c) {
      const size_t k = static_cast<size_t>(r) * w + c;
      if (count[k] == 0) continue;
      result->inverse_residual_rms_m.at<float>(r, c) = static_cast<float>(std::sqrt(sq_inverse[k] / count[k]));
      result->affine_residual_rms_m.at<float>(r, c) = static_cast<float>(std::sqrt(sq_affine[k] / count[k]));
    }
  }
}

}  // namespace

DepthCorrectionResult FitDepthCorrection(const CameraModel& camera, const std::vector<PlaneCapture>& captures,
                                         const DepthCorrectionOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  if (const std::string p = camera.Problem(); !p.empty()) throw InputError(kSource, "camera", p);
  if (static_cast<int>(captures.size()) < options.min_planes) {
    throw InputError(kSource, "captures",
                     std::to_string(captures.size()) + " plane captures; need at least " +
                         std::to_string(options.min_planes) + " at different distances over the measuring range");
  }
  const std::vector<cv::Mat> truth = TruthDepths(camera, captures, options);
  const std::vector<cv::Mat> chip_depth = ChipDepths(captures, options.chip);
  DepthCorrectionResult result;
  FitBothModels(captures, chip_depth, truth, options, &result);
  ComputeResiduals(captures, chip_depth, truth, camera.width, camera.height, &result);
  if (result.fitted_pixels == 0) {
    throw InputError(kSource, "captures",
                     "no pixel has " + std::to_string(options.min_planes) + " valid samples spread over " +
                         std::to_string(options.min_depth_spread_m * 1e3) +
                         " mm of depth; capture the plane at more distinct distances");
  }
  return result;
}

}  // namespace romunect::calib
