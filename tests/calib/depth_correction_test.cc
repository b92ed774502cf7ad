#include "romunect/calib/depth_correction.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

// The paper's single-scan accuracy: metric depth after correction, plane in focus.
constexpr double kGoalRmsM = 0.1e-3;
// Plane depth vs the slow reference: float storage of ~0.2 m depth.
constexpr double kPlaneDepthToleranceM = 1e-7;
// Depth steps per raw unit near 0.2 m are ~0.1 mm; raw noise 0.3 units on top of rounding.
constexpr double kRawNoise = 0.3;

CameraModel SmallCamera() { return testing::Scaled(testing::TruthCamera(), 0.25); }  // 160 x 120

// Planes from 0.19 to 0.21 m (the focused 2 cm range), tilted, seeded.
std::vector<PlaneCapture> Captures(const CameraModel& camera, const testing::RawDepthTruth& truth, int count,
                                   unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> tilt(-0.15, 0.15);
  std::vector<PlaneCapture> captures;
  for (int i = 0; i < count; ++i) {
    const Pose T_C_K = testing::PlaneAt(0.19 + 0.02 * i / (count - 1), tilt(rng), tilt(rng));
    captures.push_back({testing::RenderPlaneRaw(camera, truth, T_C_K, kRawNoise, &rng), T_C_K});
  }
  return captures;
}

TEST(DepthCorrectionTest, PlaneDepthMatchesSlowReference) {
  const CameraModel camera = SmallCamera();
  const Pose T_C_K = testing::PlaneAt(0.2, 0.2, -0.1);
  const cv::Mat depth = PlaneDepth(camera, T_C_K);
  const Pose T_K_C = T_C_K.inverse();
  for (int r = 0; r < camera.height; r += 7) {
    for (int c = 0; c < camera.width; c += 5) {
      // Bisection on depth until the unprojected point lies on z_K = 0.
      double lo = 0.05, hi = 1.0;
      for (int it = 0; it < 80; ++it) {
        const double mid = 0.5 * (lo + hi);
        const double z_K = (T_K_C * camera.Unproject(Eigen::Vector2d(c, r), mid)).z();
        const double z_K_lo = (T_K_C * camera.Unproject(Eigen::Vector2d(c, r), lo)).z();
        ((z_K > 0) == (z_K_lo > 0) ? lo : hi) = mid;
      }
      EXPECT_NEAR(depth.at<float>(r, c), 0.5 * (lo + hi), kPlaneDepthToleranceM) << r << " " << c;
    }
  }
}

TEST(DepthCorrectionTest, ExactModelMeetsGoalAndAffineModelLeavesMoreError) {
  const CameraModel camera = SmallCamera();
  const testing::RawDepthTruth truth;
  const DepthCorrectionResult fit = FitDepthCorrection(camera, Captures(camera, truth, 12, 3));
  EXPECT_EQ(fit.unfitted_pixels, 0);
  EXPECT_LE(fit.inverse_rms_m, kGoalRmsM) << fit.BriefReport();
  EXPECT_GT(fit.affine_rms_m, fit.inverse_rms_m) << fit.BriefReport();
  EXPECT_EQ(&fit.Best(), &fit.inverse);
  std::printf("%s\n", fit.BriefReport().c_str());

  // On fresh planes, not used by the fit, in the same range: held-out accuracy.
  const std::vector<PlaneCapture> fresh = Captures(camera, truth, 5, 99);
  double sum = 0.0;
  size_t n = 0;
  for (const PlaneCapture& capture : fresh) {
    const cv::Mat depth = ApplyDepthCorrection(fit.inverse, capture.raw, StockChipGeometry());
    const cv::Mat gt = PlaneDepth(camera, capture.T_C_K);
    for (int r = 0; r < camera.height; ++r) {
      for (int c = 0; c < camera.width; ++c) {
        if (depth.at<float>(r, c) == 0.0f) continue;
        const double e = depth.at<float>(r, c) - gt.at<float>(r, c);
        sum += e * e;
        ++n;
      }
    }
  }
  ASSERT_GT(n, 0.99 * fresh.size() * camera.width * camera.height);
  EXPECT_LE(std::sqrt(sum / n), kGoalRmsM);
}

TEST(DepthCorrectionTest, ApplyConvertsRawToMetresAndKeepsInvalidAsZero) {
  const CameraModel camera = SmallCamera();
  DepthCorrection model;
  model.model = DepthCorrectionModel::kInverseAffineInRaw;
  model.a = cv::Mat(camera.height, camera.width, CV_64F, cv::Scalar(-0.001));
  model.b = cv::Mat(camera.height, camera.width, CV_64F, cv::Scalar(5.7));
  model.a.at<double>(0, 1) = std::numeric_limits<double>::quiet_NaN();
  cv::Mat raw(camera.height, camera.width, CV_16U, cv::Scalar(700));
  raw.at<uint16_t>(0, 0) = 2047;
  const ChipGeometry chip = StockChipGeometry();
  const cv::Mat depth = ApplyDepthCorrection(model, raw, chip);
  ASSERT_EQ(depth.type(), CV_32FC1);
  EXPECT_FLOAT_EQ(depth.at<float>(1, 1), 1.0f / (5.7f - 0.7f));  // 0.2 m
  EXPECT_EQ(depth.at<float>(0, 0), 0.0f);                        // invalid raw
  EXPECT_EQ(depth.at<float>(0, 1), 0.0f);                        // unfitted pixel
  model.model = DepthCorrectionModel::kAffineInChipDepth;
  model.a.setTo(2.0);
  model.b.setTo(-0.1);
  const double chip_m = ChipDepthM(chip, 700);
  EXPECT_NEAR(ApplyDepthCorrection(model, raw, chip).at<float>(3, 3), 2.0 * chip_m - 0.1, 1e-6);
}

TEST(DepthCorrectionTest, PlaneNotCoveringTheImageIsAClearError) {
  const CameraModel camera = SmallCamera();
  std::vector<PlaneCapture> captures = Captures(camera, testing::RawDepthTruth(), 4, 1);
  captures[2].raw(cv::Rect(0, 0, camera.width / 2, camera.height)).setTo(2047);
  try {
    FitDepthCorrection(camera, captures);
    FAIL() << "half-covered plane accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "captures[2]");
    EXPECT_NE(std::string(e.what()).find("fills the whole view"), std::string::npos) << e.what();
  }
}

TEST(DepthCorrectionTest, TooFewPlanesAndWrongSizesAreClearErrors) {
  const CameraModel camera = SmallCamera();
  std::vector<PlaneCapture> captures = Captures(camera, testing::RawDepthTruth(), 3, 1);
  EXPECT_THROW(FitDepthCorrection(camera, {captures[0], captures[1]}), InputError);
  captures[1].raw = cv::Mat(10, 10, CV_16U, cv::Scalar(700));
  try {
    FitDepthCorrection(camera, captures);
    FAIL() << "wrong raw size accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "captures[1].raw");
  }
}

}  // namespace
}  // namespace romunect::calib

namespace romunect::calib {
namespace {

TEST(DepthCorrectionTest, ChipModelMatchesRigFormula) {
  // rig.h: Z = 8 f b / (raw_offset - raw); the stock chip is f 580, b 0.075, 1090.
  const double fb = 580.0 * 0.075;
  const ChipGeometry chip = StockChipGeometry();
  EXPECT_EQ(chip.FocalTimesBaseline(), fb);
  EXPECT_EQ(chip.raw_offset, 1090.0);
  for (const double raw : {100.0, 700.0, 1000.0}) {
    EXPECT_NEAR(ChipDepthM(chip, raw), 8.0 * fb / (1090.0 - raw), 1e-12);
  }
  EXPECT_EQ(ChipDepthM(chip, 2047), 0.0);  // invalid
  EXPECT_EQ(ChipDepthM(chip, 1095), 0.0);  // beyond infinity: no depth
}

}  // namespace
}  // namespace romunect::calib
