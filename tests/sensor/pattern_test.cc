#include "romunect/sensor/pattern.h"

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

TEST(PatternTest, KinectDotsAreSeededTiledAndHaveBrightCentres) {
  PatternSpec spec;  // 792 x 594 Kinect dots
  const cv::Mat a = MakePattern(spec);
  EXPECT_TRUE(testing::ImagesBitEqual(a, MakePattern(spec)));
  PatternSpec other = spec;
  other.seed = 2;
  EXPECT_GT(cv::norm(a, MakePattern(other), cv::NORM_L1), 0.0);
  const int tw = spec.width / 3, th = spec.height / 3;
  const cv::Mat tile = a(cv::Rect(0, 0, tw, th));
  for (int ty = 0; ty < 3; ++ty) {
    for (int tx = 0; tx < 3; ++tx) {
      EXPECT_TRUE(testing::ImagesBitEqual(tile, a(cv::Rect(tx * tw, ty * th, tw, th)).clone()));
    }
  }
  EXPECT_FLOAT_EQ(tile.at<float>(th / 2, tw / 2), static_cast<float>(spec.centre_spot_level));
  // Share of lit pixels: binomial over 52k pixels, 3 sigma is about 0.004.
  constexpr double kFillTolerance = 0.005;
  EXPECT_NEAR(cv::countNonZero(tile) / static_cast<double>(tile.total()), spec.dot_fill, kFillTolerance);
}

TEST(PatternTest, CalibrationPatternsHaveTheirFeatures) {
  PatternSpec spec;
  spec.kind = PatternKind::kFeatureGrid;
  spec.width = 64;
  spec.height = 48;
  spec.pitch_px = 12;
  const cv::Mat grid = MakePattern(spec);
  const auto points = PatternFeaturePoints(spec);
  ASSERT_EQ(points.size(), 4u * 3u);  // x in 12..48, y in 12..36
  for (const auto& p : points) EXPECT_EQ(grid.at<float>(static_cast<int>(p.y()), static_cast<int>(p.x())), 1.0f);
  EXPECT_EQ(grid.at<float>(18, 18), 0.0f);
  spec.kind = PatternKind::kCheckerboard;
  const cv::Mat board = MakePattern(spec);
  EXPECT_EQ(board.at<float>(0, 0), 1.0f);
  EXPECT_EQ(board.at<float>(0, 12), 0.0f);
  EXPECT_EQ(board.at<float>(12, 12), 1.0f);
  EXPECT_EQ(PatternFeaturePoints(spec).front(), Eigen::Vector2d(11.5, 11.5));
  spec.kind = PatternKind::kUniform;
  EXPECT_EQ(cv::countNonZero(MakePattern(spec)), 64 * 48);
  spec.kind = PatternKind::kOff;
  EXPECT_EQ(cv::countNonZero(MakePattern(spec)), 0);
  spec.kind = PatternKind::kDotGrid;
  spec.min_level = 0.3;
  const cv::Mat dots = MakePattern(spec);
  EXPECT_GE(dots.at<float>(6, 6), 0.3f);
  EXPECT_LE(dots.at<float>(6, 6), 1.0f);
}

TEST(PatternTest, PrewarpMovesThePatternByTheHomography) {
  PatternSpec spec;
  spec.kind = PatternKind::kFeatureGrid;
  spec.width = 60;
  spec.height = 60;
  spec.pitch_px = 12;
  ProjectorModel projector;
  projector.width = 80;
  projector.height = 70;
  const cv::Mat pattern = MakePattern(spec);
  Eigen::Matrix3d H = Eigen::Matrix3d::Identity();
  H(0, 2) = 7;  // shift right by 7 px and down by 3 px
  H(1, 2) = 3;
  const cv::Mat shown = PrewarpPattern(pattern, H, projector);
  ASSERT_EQ(shown.cols, 80);
  ASSERT_EQ(shown.rows, 70);
  for (const auto& p : PatternFeaturePoints(spec)) {
    EXPECT_FLOAT_EQ(shown.at<float>(static_cast<int>(p.y()) + 3, static_cast<int>(p.x()) + 7), 1.0f);
  }
  EXPECT_EQ(shown.at<float>(1, 1), 0.0f);  // outside the pattern: dark
}

TEST(PatternTest, HashIsUniform) {
  double sum = 0;
  constexpr int kN = 100000;
  for (int i = 0; i < kN; ++i) sum += UniformFromHash(42, i);
  // Mean of kN uniforms: sigma = 1/sqrt(12 kN) ~ 0.0009; 5 sigma.
  EXPECT_NEAR(sum / kN, 0.5, 0.0045);
}

}  // namespace
}  // namespace romunect
