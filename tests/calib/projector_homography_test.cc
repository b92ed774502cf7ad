#include "romunect/calib/projector_homography.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "romunect/calib/depth_correction.h"
#include "romunect/sensor/errors.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

// The calibration goal (docs/calibrate.md): homography residual within 0.1 px after at most 5 captures.
constexpr double kGoalPx = 0.1;
constexpr int kGoalCaptures = 5;
constexpr double kDetectionNoisePx = 0.2;  // projected dots detected like board corners

using testing::ProjectorScene;

TEST(ProjectorHomographyTest, LoopConvergesWithinFiveCapturesToGoal) {
  const ProjectorScene scene;
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, kDetectionNoisePx);
  auto observe = [&](const Eigen::Matrix3d& H) {
    std::vector<cv::Point2f> detected;
    for (const Eigen::Vector2d& x_P : scene.pattern_P) {
      const Eigen::Vector2d u = scene.Map((H * x_P.homogeneous()).hnormalized());
      detected.emplace_back(static_cast<float>(u.x() + noise(rng)), static_cast<float>(u.y() + noise(rng)));
    }
    return detected;
  };
  const Eigen::Matrix3d identity = Eigen::Matrix3d::Identity();
  ASSERT_GT(scene.TrueResidualPx(identity), 20.0);  // far off before the step
  const ProjectorHomographyResult result = CalibrateProjectorHomography(scene.pattern_P, scene.target_C, scene.camera,
                                                                        identity, observe);
  EXPECT_LE(result.captures, kGoalCaptures);
  EXPECT_TRUE(result.converged) << result.BriefReport();
  EXPECT_LE(scene.TrueResidualPx(result.H_P_rec), kGoalPx) << result.BriefReport();
  // The observed residual of the last capture is detection noise on top of the true residual.
  EXPECT_LT(result.observed_rms_px.back(), result.observed_rms_px.front());
}

TEST(ProjectorHomographyTest, NoiseFreeStepIsExact) {
  const ProjectorScene scene;
  ProjectorCapture capture;
  for (const Eigen::Vector2d& x_P : scene.pattern_P) {
    const Eigen::Vector2d u = scene.Map(x_P);
    capture.detected_px.emplace_back(static_cast<float>(u.x()), static_cast<float>(u.y()));
  }
  const ProjectorHomographyStep step = SolveProjectorHomography(scene.pattern_P, scene.target_C, {capture},
                                                                scene.camera);
  // Float detections (1e-4 px at 640) limit the exactness.
  EXPECT_LT(scene.TrueResidualPx(step.H_P_rec), 2e-3);
  EXPECT_LT(step.mapping_fit_rms_px, 1e-3);
  EXPECT_DOUBLE_EQ(step.H_P_rec(2, 2), 1.0);
}

TEST(ProjectorHomographyTest, MismatchedOrMissingDetectionsAreClearErrors) {
  const ProjectorScene scene;
  ProjectorCapture capture;
  capture.detected_px.assign(3, cv::Point2f(1, 1));
  EXPECT_THROW(SolveProjectorHomography(scene.pattern_P, scene.target_C, {capture}, scene.camera), InputError);
  capture.detected_px.assign(scene.pattern_P.size(), cv::Point2f(NAN, NAN));
  try {
    SolveProjectorHomography(scene.pattern_P, scene.target_C, {capture}, scene.camera);
    FAIL() << "no detections accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("0 detected features"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace romunect::calib
