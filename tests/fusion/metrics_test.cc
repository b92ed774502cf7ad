#include "romunect/fusion/metrics.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace romunect::fusion {
namespace {

constexpr double kExact = 1e-9;  // sums of a handful of floats: only rounding

TEST(MetricsTest, CompletenessAndErrorsOnAHandMadeMap) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  // errors: +0.5 mm, -2 mm, 0 (GT empty -> not compared), empty fused cell
  const cv::Mat fused = (cv::Mat_<float>(1, 4) << 0.0105f, 0.008f, 0.02f, nan);
  const cv::Mat gt = (cv::Mat_<float>(1, 4) << 0.010f, 0.010f, nan, 0.01f);
  const HeightMapMetrics m = CompareHeightMaps(fused, gt);
  EXPECT_EQ(m.cells, 4u);
  EXPECT_EQ(m.valued_cells, 3u);
  EXPECT_EQ(m.compared_cells, 2u);
  EXPECT_NEAR(m.completeness, 0.75, kExact);
  EXPECT_NEAR(m.mae_mm, (0.5 + 2.0) / 2, 1e-4);  // float inputs: 1e-4 mm of rounding
  EXPECT_NEAR(m.rmse_mm, std::sqrt((0.25 + 4.0) / 2), 1e-4);
  EXPECT_NEAR(m.within_1mm, 0.5, kExact);
  EXPECT_NEAR(Completeness(fused), 0.75, kExact);
}

TEST(MetricsTest, NothingToCompareIsNoErrorRatherThanAZeroOne) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const cv::Mat fused = (cv::Mat_<float>(1, 3) << 0.01f, 0.02f, nan);
  const cv::Mat gt = (cv::Mat_<float>(1, 3) << nan, nan, 0.01f);
  const HeightMapMetrics m = CompareHeightMaps(fused, gt);
  EXPECT_EQ(m.valued_cells, 2u);
  EXPECT_EQ(m.compared_cells, 0u);
  EXPECT_TRUE(std::isnan(m.rmse_mm));
  EXPECT_TRUE(std::isnan(m.mae_mm));
  EXPECT_TRUE(std::isnan(m.within_1mm));
}

TEST(MetricsTest, QuantileIsNearestRank) {
  EXPECT_EQ(Quantile({}, 0.5), 0.0);
  EXPECT_EQ(Quantile({4, 1, 3, 2}, 0.5), 2.0);
  EXPECT_EQ(Quantile({4, 1, 3, 2}, 0.9), 4.0);
  EXPECT_EQ(Quantile({4, 1, 3, 2}, 0.0), 1.0);
  EXPECT_GT(PeakRssMb(), 0.0);  // Linux: /proc/self/status is there
}

}  // namespace
}  // namespace romunect::fusion
