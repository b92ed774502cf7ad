#include "reference_matcher.h"

#include <cmath>
#include <cstdlib>
#include <limits>
#include <vector>

namespace romunect::testing {

uint16_t ReferenceMatchRaw(const DepthEngine& engine, const cv::Mat& n_obs, const cv::Mat& sigma,
                           const cv::Mat& n_ref, int x, int y) {
  const DepthEngineOptions& o = engine.options();
  const int r = o.window_px / 2, W = n_obs.cols, H = n_obs.rows;
  if (x < r || y < r || x >= W - r || y >= H - r) return kRawInvalid;
  if (sigma.at<float>(y, x) < static_cast<float>(o.min_texture)) return kRawInvalid;
  std::vector<int> cost(o.search_range_px);
  for (int j = 0; j < o.search_range_px; ++j) {
    const int s = o.min_shift_px + j;
    int sum = 0;
    for (int dy = -r; dy <= r; ++dy) {
      for (int dx = -r; dx <= r; ++dx) {
        const int xr = x + dx - s;
        const int a = n_obs.at<uint8_t>(y + dy, x + dx);
        sum += (xr >= 0 && xr < W) ? std::abs(a - n_ref.at<uint8_t>(y + dy, xr)) : 255;
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
  if (c0 > static_cast<float>(o.max_cost * o.window_px * o.window_px)) return kRawInvalid;
  if (second < c0 * (1.f + static_cast<float>(o.uniqueness))) return kRawInvalid;
  if (best_j == 0 || best_j == o.search_range_px - 1) return kRawInvalid;
  const float cm = static_cast<float>(cost[best_j - 1]), cp = static_cast<float>(cost[best_j + 1]);
  const float denom = 2.f * (cm + cp - 2.f * c0);
  const float delta = denom > 0.f ? (cm - cp) / denom : 0.f;
  const long s8 = static_cast<long>(std::floor(8.f * (static_cast<float>(o.min_shift_px + best_j) + delta) + 0.5f));
  const long raw = std::lround(engine.RawAtReference()) - s8;
  if (raw < 0 || raw >= kRawInvalid || raw >= o.chip.raw_offset) return kRawInvalid;
  return static_cast<uint16_t>(raw);
}

}  // namespace romunect::testing
