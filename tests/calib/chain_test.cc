// The chain's own pieces that need no hardware: the chip's reference positions (eq. 1's
// targets) agree with the sensor model's ideal pre-warp, and projected dots are found where
// they are. The chain itself runs in the loop in tests/sim/calibration_rig_test.cc.
#include "romunect/calib/chain.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/pattern.h"

namespace romunect::calib {
namespace {

// IdealPrewarp and ChipReferencePx are the same geometry written twice: double rounding only.
constexpr double kGeometryTolPx = 1e-6;
// Dots of radius 8 px blurred by 0.7 px with 3 DN noise on 800 DN: centroids of ~200 pixels.
constexpr double kDotTolPx = 0.03;

TEST(ChainTest, ChipReferenceIsWhereTheIdealPrewarpPutsThePattern) {
  const Rig rig = RigPreset("romunect");
  const Eigen::Matrix3d H = IdealPrewarp(rig, 0.2);
  const Pose T_C_K = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, 0.2));  // plane z = 0.2 in C
  PatternSpec spec;
  spec.kind = PatternKind::kFeatureGrid;
  spec.pitch_px = 64;
  int checked = 0;
  for (const Eigen::Vector2d& x : PatternFeaturePoints(spec)) {
    const auto u = ProjectorPixelToCamera(rig, rig.camera, T_C_K, (H * x.homogeneous()).hnormalized());
    ASSERT_TRUE(u.has_value());
    EXPECT_NEAR((*u - ChipReferencePx(rig.depth_engine.chip, x)).norm(), 0.0, kGeometryTolPx);
    ++checked;
  }
  EXPECT_GT(checked, 50);
}

TEST(ChainTest, FindsProjectedDotsAtSubPixelPositions) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> frac(-0.5, 0.5);
  std::normal_distribution<double> noise(0.0, 3.0);
  constexpr double kRadiusPx = 8.0;
  constexpr int kSuper = 8;  // supersampled disks: the truth is the disk's centre
  cv::Mat big(480 * kSuper, 640 * kSuper, CV_32F, cv::Scalar(60.0));
  std::vector<Eigen::Vector2d> truth, predicted;
  for (int y = 60; y < 440; y += 60) {
    for (int x = 60; x < 600; x += 60) {
      const Eigen::Vector2d c(x + frac(rng), y + frac(rng));
      truth.push_back(c);
      predicted.push_back(c + Eigen::Vector2d(6.0 * frac(rng), 6.0 * frac(rng)));  // a rough prediction
      cv::circle(big,
                 cv::Point(static_cast<int>(std::lround(((c.x() + 0.5) * kSuper - 0.5) * 16)),
                           static_cast<int>(std::lround(((c.y() + 0.5) * kSuper - 0.5) * 16))),
                 static_cast<int>(kRadiusPx * kSuper * 16), cv::Scalar(800.0), cv::FILLED, cv::LINE_8, 4);
    }
  }
  cv::Mat small, blurred;
  cv::resize(big, small, cv::Size(640, 480), 0, 0, cv::INTER_AREA);
  cv::GaussianBlur(small, blurred, cv::Size(0, 0), 0.7);
  cv::Mat ir(480, 640, CV_16U);
  for (int y = 0; y < ir.rows; ++y) {
    for (int x = 0; x < ir.cols; ++x) {
      ir.at<uint16_t>(y, x) = cv::saturate_cast<uint16_t>(blurred.at<float>(y, x) + noise(rng));
    }
  }
  // a prediction far from any dot finds nothing; an off-image one is skipped
  predicted.emplace_back(30.0, 30.0);
  predicted.emplace_back(std::nan(""), std::nan(""));
  const std::vector<cv::Point2f> found = DetectProjectedDots(ir, predicted, kRadiusPx, 0.35 * 60);
  ASSERT_EQ(found.size(), predicted.size());
  for (size_t i = 0; i < truth.size(); ++i) {
    ASSERT_TRUE(std::isfinite(found[i].x)) << i;
    EXPECT_NEAR(found[i].x, truth[i].x(), kDotTolPx) << i;
    EXPECT_NEAR(found[i].y, truth[i].y(), kDotTolPx) << i;
  }
  EXPECT_FALSE(std::isfinite(found[truth.size()].x));
  EXPECT_FALSE(std::isfinite(found[truth.size() + 1].x));
}

TEST(ChainTest, OptionsNameTheBrokenField) {
  ChainOptions options;
  EXPECT_EQ(options.Problem(), "");
  options.depth_far_m = options.depth_near_m;
  EXPECT_NE(options.Problem().find("depth_near_m"), std::string::npos);
  options = {};
  options.feature_pattern.kind = PatternKind::kUniform;
  EXPECT_NE(options.Problem().find("feature_pattern.kind"), std::string::npos);
}

}  // namespace
}  // namespace romunect::calib
