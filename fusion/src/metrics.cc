#include "romunect/fusion/metrics.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <limits>
#include <string>

#include "romunect/sensor/check.h"

namespace romunect::fusion {
namespace {

double StatusFieldMb(const char* key) {
  std::ifstream in("/proc/self/status");
  std::string line;
  const std::string prefix = std::string(key) + ":";
  while (std::getline(in, line)) {
    if (line.rfind(prefix, 0) == 0) return std::stod(line.substr(prefix.size())) * 1024.0 / 1e6;  // kB
  }
  return 0.0;
}

}  // namespace

double Completeness(const cv::Mat& height_m) {
  ROMUNECT_CHECK(height_m.type() == CV_32FC1);
  if (height_m.empty()) return 0.0;
  size_t valued = 0;
  for (int r = 0; r < height_m.rows; ++r) {
    const float* row = height_m.ptr<float>(r);
    for (int c = 0; c < height_m.cols; ++c) valued += std::isfinite(row[c]);
  }
  return static_cast<double>(valued) / height_m.total();
}

HeightMapMetrics CompareHeightMaps(const cv::Mat& fused_m, const cv::Mat& ground_truth_m) {
  ROMUNECT_CHECK(fused_m.type() == CV_32FC1 && ground_truth_m.type() == CV_32FC1);
  ROMUNECT_CHECK(fused_m.size() == ground_truth_m.size());
  HeightMapMetrics m;
  m.cells = fused_m.total();
  double sum_sq = 0.0, sum_abs = 0.0;
  size_t within = 0;
  for (int r = 0; r < fused_m.rows; ++r) {
    const float* f = fused_m.ptr<float>(r);
    const float* g = ground_truth_m.ptr<float>(r);
    for (int c = 0; c < fused_m.cols; ++c) {
      if (!std::isfinite(f[c])) continue;
      ++m.valued_cells;
      if (!std::isfinite(g[c])) continue;
      ++m.compared_cells;
      const double error_mm = (static_cast<double>(f[c]) - g[c]) * 1e3;
      sum_sq += error_mm * error_mm;
      sum_abs += std::abs(error_mm);
      within += std::abs(error_mm) <= 1.0;
    }
  }
  if (m.cells > 0) m.completeness = static_cast<double>(m.valued_cells) / m.cells;
  if (m.compared_cells > 0) {
    m.rmse_mm = std::sqrt(sum_sq / m.compared_cells);
    m.mae_mm = sum_abs / m.compared_cells;
    m.within_1mm = static_cast<double>(within) / m.compared_cells;
  } else {
    m.rmse_mm = m.mae_mm = m.within_1mm = std::numeric_limits<double>::quiet_NaN();
  }
  return m;
}

double Quantile(std::vector<double> values, double q) {
  if (values.empty()) return 0.0;
  const size_t k = std::min(values.size() - 1, static_cast<size_t>(std::ceil(q * values.size())) - (q > 0));
  std::nth_element(values.begin(), values.begin() + k, values.end());
  return values[k];
}

double PeakRssMb() { return StatusFieldMb("VmHWM"); }
double CurrentRssMb() { return StatusFieldMb("VmRSS"); }

}  // namespace romunect::fusion
