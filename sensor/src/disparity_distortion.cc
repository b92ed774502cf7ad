#include "romunect/sensor/disparity_distortion.h"

#include <cmath>
#include <sstream>

#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/pattern.h"

namespace romunect {
namespace {

FieldProblem Bad(const std::string& field, const std::string& rule, double value) {
  std::ostringstream s;
  s << rule << ", found " << value;
  return {field, s.str()};
}

// The random part: unit-RMS, zero-mean Gaussian noise smoothed to features of `scale_px`,
// drawn on a grid 4 x coarser than the image (the same field, 16 x cheaper) and resized.
cv::Mat RandomField(uint64_t seed, double scale_px, int width, int height) {
  constexpr int kCoarse = 4;
  const int w = width / kCoarse + 2, h = height / kCoarse + 2;
  cv::Mat noise(h, w, CV_32F);
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      // Box-Muller on two hashed uniforms: no dependence on the standard library's distributions.
      const uint64_t k = 2 * (static_cast<uint64_t>(y) * w + x);
      const double u1 = 1.0 - UniformFromHash(seed, k), u2 = UniformFromHash(seed, k + 1);
      noise.at<float>(y, x) = static_cast<float>(std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * M_PI * u2));
    }
  }
  const double sigma = scale_px / kCoarse;
  cv::Mat smooth, field;
  cv::GaussianBlur(noise, smooth, cv::Size(0, 0), sigma, sigma, cv::BORDER_REFLECT);
  cv::resize(smooth, field, cv::Size(width, height), 0, 0, cv::INTER_LINEAR);
  cv::Scalar mean, stddev;
  cv::meanStdDev(field, mean, stddev);
  if (stddev[0] > 0) field = (field - mean[0]) / stddev[0];
  return field;
}

// The radial part: r^6 (r = 1 in the corners) less its mean, scaled to 1 in the corners.
cv::Mat CornerField(int width, int height) {
  cv::Mat q(height, width, CV_32F);
  const double cx = 0.5 * (width - 1), cy = 0.5 * (height - 1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) {
      const double dx = cx > 0 ? (x - cx) / cx : 0.0, dy = cy > 0 ? (y - cy) / cy : 0.0;
      const double r2 = 0.5 * (dx * dx + dy * dy);
      q.at<float>(y, x) = static_cast<float>(r2 * r2 * r2);
    }
  }
  const double mean = cv::mean(q)[0];
  return (q - mean) / (1.0 - mean);
}

}  // namespace

double DisparityDistortion::WorstCaseCodes(double min_raw) const {
  // The factors are largest at the smallest raw value (alpha1, pattern_alpha1 >= 0).
  return 4.0 * std::abs(pattern_rms_codes) * std::exp(pattern_alpha0 - pattern_alpha1 * min_raw) +
         std::abs(corner_codes) * std::exp(alpha0 - alpha1 * min_raw);
}

FieldProblem DisparityDistortion::Check() const {
  if (!(std::isfinite(alpha0) && alpha0 >= -10 && alpha0 <= 10)) return Bad("alpha0", "must be in [-10, 10]", alpha0);
  // Published units decay by a few tenths of a percent per code; 0.02 would be 1e-18 at the far end.
  if (!(std::isfinite(alpha1) && alpha1 >= 0 && alpha1 <= 0.02)) {
    return Bad("alpha1", "must be in [0, 0.02] per raw code", alpha1);
  }
  if (!(std::isfinite(pattern_alpha0) && pattern_alpha0 >= -10 && pattern_alpha0 <= 10)) {
    return Bad("pattern_alpha0", "must be in [-10, 10]", pattern_alpha0);
  }
  if (!(std::isfinite(pattern_alpha1) && pattern_alpha1 >= 0 && pattern_alpha1 <= 0.02)) {
    return Bad("pattern_alpha1", "must be in [0, 0.02] per raw code", pattern_alpha1);
  }
  if (!(std::isfinite(pattern_rms_codes) && pattern_rms_codes >= 0 && pattern_rms_codes <= 16)) {
    return Bad("pattern_rms_codes", "must be in [0, 16] raw codes", pattern_rms_codes);
  }
  if (!(std::isfinite(pattern_scale_px) && pattern_scale_px >= 4 && pattern_scale_px <= 2000)) {
    return Bad("pattern_scale_px", "must be in [4, 2000] px", pattern_scale_px);
  }
  if (!(std::isfinite(corner_codes) && std::abs(corner_codes) <= 64)) {
    return Bad("corner_codes", "must be in [-64, 64] raw codes", corner_codes);
  }
  return {};
}

DisparityDistortion KinectV1DisparityDistortion() {
  DisparityDistortion d;
  d.seed = 1;
  // Both factors are 1 at raw 742 (1 m on the stock chip). The corners' halves by 3 m, as the
  // measured spreads do (2.1, 1.3 and 1.1 codes at 1, 2 and 3 m); the fine pattern's falls by a
  // fifth, as the centre of a real unit's planes keeps 0.4-0.6 codes of it from 1 to 3 m.
  d.alpha1 = 0.0028;
  d.alpha0 = d.alpha1 * 742.0;
  d.pattern_alpha1 = 0.0008;
  d.pattern_alpha0 = d.pattern_alpha1 * 742.0;
  d.pattern_rms_codes = 0.55;
  d.pattern_scale_px = 40.0;
  d.corner_codes = -4.8;
  return d;
}

DisparityDistortionMaps DisparityDistortionBeta(const DisparityDistortion& model, int width, int height) {
  ROMUNECT_CHECK(width > 0 && height > 0);
  ROMUNECT_CHECK_MSG(model.Problem().empty(), model.Problem().c_str());
  DisparityDistortionMaps beta{cv::Mat::zeros(height, width, CV_32F), cv::Mat::zeros(height, width, CV_32F)};
  if (model.pattern_rms_codes != 0.0) {
    beta.pattern = model.pattern_rms_codes * RandomField(model.seed, model.pattern_scale_px, width, height);
  }
  if (model.corner_codes != 0.0) beta.radial = model.corner_codes * CornerField(width, height);
  return beta;
}

double DisparityDistortionCodes(const DisparityDistortion& model, double radial_beta, double pattern_beta,
                                double raw) {
  return radial_beta * std::exp(model.alpha0 - model.alpha1 * raw) +
         pattern_beta * std::exp(model.pattern_alpha0 - model.pattern_alpha1 * raw);
}

}  // namespace romunect
