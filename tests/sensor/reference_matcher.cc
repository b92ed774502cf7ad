#include "reference_matcher.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <limits>
#include <vector>

#include <opencv2/imgproc.hpp>

namespace romunect::testing {

void ReferencePrefilter(const cv::Mat& ir, int window_px, cv::Mat* normalized, cv::Mat* local_sigma) {
  cv::Mat f, mean, mean2;
  ir.convertTo(f, CV_32F);
  const cv::Size k(window_px, window_px);
  cv::boxFilter(f, mean, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  cv::boxFilter(f.mul(f), mean2, CV_32F, k, cv::Point(-1, -1), true, cv::BORDER_REFLECT);
  local_sigma->create(ir.size(), CV_32F);
  normalized->create(ir.size(), CV_8U);
  for (int y = 0; y < ir.rows; ++y) {
    for (int x = 0; x < ir.cols; ++x) {
      const float m = mean.at<float>(y, x);
      const float sigma = std::sqrt(std::max(mean2.at<float>(y, x) - m * m, 0.f));
      local_sigma->at<float>(y, x) = sigma;
      // The engine's constants: 48 levels per standard deviation, sigma floored at 2 DN.
      const float value = 128.f + 48.f * (f.at<float>(y, x) - m) / std::max(sigma, 2.f);
      normalized->at<uint8_t>(y, x) = static_cast<uint8_t>(std::clamp(value, 0.f, 255.f) + 0.5f);
    }
  }
}

uint16_t ReferenceMatchRaw(const DepthEngine& engine, const cv::Mat& n_obs, const cv::Mat& sigma, const cv::Mat& n_ref,
                           int x, int y) {
  const DepthEngineOptions& o = engine.options();
  const int r = o.window_px / 2, W = n_obs.cols, H = n_obs.rows;
  // The reference's column 0 is the camera's -left (0 for a reference cropped to the image).
  const int left = n_ref.cols == W ? 0 : ReferenceMarginsPx(o).first;
  // The chip's right-hand columns report nothing.
  if (x >= W - kChipBorderColumns) return kRawInvalid;
  if (sigma.at<float>(y, x) < static_cast<float>(o.min_texture)) return kRawInvalid;
  // The window's columns inside the image; its rows reflected at the top and bottom, in both
  // images alike.
  const int x_first = std::max(x - r, 0), x_last = std::min(x + r, W - 1);
  std::vector<int> cost(o.search_range_px);
  for (int j = 0; j < o.search_range_px; ++j) {
    const int s = o.min_shift_px + j;
    int sum = 0;
    for (int dy = -r; dy <= r; ++dy) {
      const int row = cv::borderInterpolate(y + dy, H, cv::BORDER_REFLECT);
      for (int xx = x_first; xx <= x_last; ++xx) {
        const int xr = xx - s + left;
        const int a = n_obs.at<uint8_t>(row, xx);
        sum += (xr >= 0 && xr < n_ref.cols) ? std::abs(a - n_ref.at<uint8_t>(row, xr)) : 255;
      }
    }
    cost[j] = sum;
  }
  int best_j = 0;
  for (int j = 1; j < o.search_range_px; ++j) {
    if (cost[j] < cost[best_j]) best_j = j;
  }
  int second = std::numeric_limits<int>::max();
  for (int j = 0; j < o.search_range_px; ++j) {
    if (std::abs(j - best_j) > 1 && cost[j] < second) second = cost[j];
  }
  const float c0 = static_cast<float>(cost[best_j]);
  if (c0 > std::floor(static_cast<float>(o.max_cost * o.window_px * (x_last - x_first + 1)))) return kRawInvalid;
  if (second < c0 * (1.f + static_cast<float>(o.uniqueness))) return kRawInvalid;
  if (best_j == 0 || best_j == o.search_range_px - 1) return kRawInvalid;
  const float cm = static_cast<float>(cost[best_j - 1]), cp = static_cast<float>(cost[best_j + 1]);
  // Sub-pixel: the equiangular (V) and the parabolic fit, weighted; the V's weight falls with
  // c0 / a, the best cost over its rise to the higher neighbour.
  const float a = std::max(cm, cp) - c0, b = cm + cp - 2.f * c0;
  const float w2a = std::clamp(2.f * a * static_cast<float>(o.subpixel_equiangular_weight) -
                                   static_cast<float>(o.subpixel_rounding_slope) * (2.f * c0),
                               0.f, 2.f * a);  // the weight times 2a
  // V: (cm - cp) / 2a; parabola: (cm - cp) / 2b; blended over one denominator, 2a 2ab.
  const float d =
      a > 0.f && b > 0.f ? (cm - cp) * (w2a * b + (2.f * a - w2a) * a) / (2.f * a * (2.f * a) * b) : 0.f;
  // The quarter-pixel correction on the offset from the nearest half pixel.
  const float u = d - 0.5f * std::round(2.f * d);
  const float e = d - static_cast<float>(o.subpixel_quarter_correction) * u * (1.f - 16.f * u * u);
  // The eighth-pixel correction on the offset from the nearest quarter pixel.
  const float v = e - 0.25f * std::round(4.f * e);
  const float delta = e - static_cast<float>(o.subpixel_eighth_correction) * v * (1.f - 64.f * v * v);
  const long s8 = static_cast<long>(std::floor(8.f * (static_cast<float>(o.min_shift_px + best_j) + delta) + 0.5f));
  const long raw = std::lround(engine.RawAtReference()) - s8;
  if (raw < 0 || raw >= kRawInvalid || raw >= o.chip.raw_offset) return kRawInvalid;
  return static_cast<uint16_t>(raw);
}

}  // namespace romunect::testing
