// Metrics of a fused height map (voting_grid.h: CV_32F, world z in metres, NaN = empty) against
// a ground-truth height map over the same box and cells, and process figures for reports.
#pragma once

#include <cstddef>
#include <vector>

#include <opencv2/core.hpp>

namespace romunect::fusion {

struct HeightMapMetrics {
  size_t cells = 0;           // all cells of the region
  size_t valued_cells = 0;    // cells of the fused map with a value
  size_t compared_cells = 0;  // valued cells where the ground truth has a value too
  double completeness = 0.0;  // valued_cells / cells
  // Over compared cells; NaN when there are none (JSON null: no error, not a zero one).
  double rmse_mm = 0.0;
  double mae_mm = 0.0;
  double within_1mm = 0.0;  // share of compared cells with |error| <= 1 mm
};

// Share of cells with a (finite) value.
double Completeness(const cv::Mat& height_m);

// Compares a fused map with ground truth (same size, CV_32F; NaN in either = no value there).
HeightMapMetrics CompareHeightMaps(const cv::Mat& fused_m, const cv::Mat& ground_truth_m);

// Order statistic of a sample (q in [0, 1], nearest rank); 0 for an empty sample.
double Quantile(std::vector<double> values, double q);

// The process's peak resident memory (VmHWM), megabytes; 0 where unknown.
double PeakRssMb();
// The process's current resident memory (VmRSS), megabytes; 0 where unknown.
double CurrentRssMb();

}  // namespace romunect::fusion
