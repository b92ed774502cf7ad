#include "romunect/calib/projector_homography.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>

#include "romunect/calib/depth_correction.h"
#include "romunect/sensor/errors.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

// The goal: homography residual within 0.1 px after at most 5 captures.
constexpr double kGoalPx = 0.1;
constexpr int kGoalCaptures = 5;
constexpr double kDetectionNoisePx = 0.2;  // projected dots detected like board corners

// A projector (1280 x 800 pixels, f 1400 px) 75 mm beside the camera, both seeing a tilted
// plane at 0.2 m. Truth F_img: projector pixel -> ray -> plane -> camera pixel (distorted).
struct Scene {
  CameraModel camera = testing::TruthCamera();
  CameraModel projector = [] {
    CameraModel p;
    p.width = 1280;
    p.height = 800;
    p.fx = p.fy = 1400.0;
    p.cx = 639.5;
    p.cy = 399.5;
    return p;
  }();
  Pose T_C_P = MakePose(Eigen::AngleAxisd(0.06, Eigen::Vector3d(0.1, 1, 0.05).normalized()).toRotationMatrix(),
                        Eigen::Vector3d(0.075, 0.002, -0.001));
  Pose T_C_K = testing::PlaneAt(0.2, 0.05, -0.08);

  Eigen::Vector2d Map(const Eigen::Vector2d& q_P) const {
    const Eigen::Vector3d ray_C = T_C_P.linear() * projector.Ray(q_P);
    const Eigen::Vector3d o_C = T_C_P.translation();
    const Eigen::Vector3d n = T_C_K.linear().col(2);
    const double s = n.dot(T_C_K.translation() - o_C) / n.dot(ray_C);
    return *camera.Project(o_C + s * ray_C);
  }
};

struct Pattern {
  std::vector<Eigen::Vector2d> pattern_P, target_C;
};

// A 12 x 8 grid of dots over the projector image; targets: a rectangular grid in the ideal
// camera image, distorted (what the chip expects to see), reachable by a homography.
Pattern MakePattern(const Scene& scene) {
  Pattern p;
  for (int r = 0; r < 8; ++r) {
    for (int c = 0; c < 12; ++c) {
      const Eigen::Vector2d x_P(100 + c * 98.0, 80 + r * 90.0);
      p.pattern_P.push_back(x_P);
      const Eigen::Vector2d ideal(60 + c * 47.0, 50 + r * 52.0);
      const Eigen::Vector3d ray((ideal.x() - scene.camera.cx) / scene.camera.fx,
                                (ideal.y() - scene.camera.cy) / scene.camera.fy, 1.0);
      p.target_C.push_back(*scene.camera.Project(ray));
    }
  }
  return p;
}

double TrueResidualPx(const Scene& scene, const Pattern& pattern, const Eigen::Matrix3d& H) {
  double sum = 0.0;
  for (size_t i = 0; i < pattern.pattern_P.size(); ++i) {
    const Eigen::Vector2d q = (H * pattern.pattern_P[i].homogeneous()).hnormalized();
    sum += (scene.Map(q) - pattern.target_C[i]).squaredNorm();
  }
  return std::sqrt(sum / pattern.pattern_P.size());
}

TEST(ProjectorHomographyTest, LoopConvergesWithinFiveCapturesToGoal) {
  const Scene scene;
  const Pattern pattern = MakePattern(scene);
  std::mt19937 rng(4);
  std::normal_distribution<double> noise(0.0, kDetectionNoisePx);
  auto observe = [&](const Eigen::Matrix3d& H) {
    std::vector<cv::Point2f> detected;
    for (const Eigen::Vector2d& x_P : pattern.pattern_P) {
      const Eigen::Vector2d u = scene.Map((H * x_P.homogeneous()).hnormalized());
      detected.emplace_back(static_cast<float>(u.x() + noise(rng)), static_cast<float>(u.y() + noise(rng)));
    }
    return detected;
  };
  const Eigen::Matrix3d identity = Eigen::Matrix3d::Identity();
  ASSERT_GT(TrueResidualPx(scene, pattern, identity), 20.0);  // far off before the step
  const ProjectorHomographyResult result =
      CalibrateProjectorHomography(pattern.pattern_P, pattern.target_C, scene.camera, identity, observe);
  EXPECT_LE(result.captures, kGoalCaptures);
  EXPECT_TRUE(result.converged) << result.BriefReport();
  EXPECT_LE(TrueResidualPx(scene, pattern, result.H_P_rec), kGoalPx) << result.BriefReport();
  // The observed residual of the last capture is detection noise on top of the true residual.
  EXPECT_LT(result.observed_rms_px.back(), result.observed_rms_px.front());
}

TEST(ProjectorHomographyTest, NoiseFreeStepIsExact) {
  const Scene scene;
  const Pattern pattern = MakePattern(scene);
  ProjectorCapture capture;
  for (const Eigen::Vector2d& x_P : pattern.pattern_P) {
    const Eigen::Vector2d u = scene.Map(x_P);
    capture.detected_px.emplace_back(static_cast<float>(u.x()), static_cast<float>(u.y()));
  }
  const ProjectorHomographyStep step =
      SolveProjectorHomography(pattern.pattern_P, pattern.target_C, {capture}, scene.camera);
  // Float detections (1e-4 px at 640) limit the exactness.
  EXPECT_LT(TrueResidualPx(scene, pattern, step.H_P_rec), 2e-3);
  EXPECT_LT(step.mapping_fit_rms_px, 1e-3);
  EXPECT_DOUBLE_EQ(step.H_P_rec(2, 2), 1.0);
}

TEST(ProjectorHomographyTest, MismatchedOrMissingDetectionsAreClearErrors) {
  const Scene scene;
  const Pattern pattern = MakePattern(scene);
  ProjectorCapture capture;
  capture.detected_px.assign(3, cv::Point2f(1, 1));
  EXPECT_THROW(SolveProjectorHomography(pattern.pattern_P, pattern.target_C, {capture}, scene.camera), InputError);
  capture.detected_px.assign(pattern.pattern_P.size(), cv::Point2f(NAN, NAN));
  try {
    SolveProjectorHomography(pattern.pattern_P, pattern.target_C, {capture}, scene.camera);
    FAIL() << "no detections accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("0 detected features"), std::string::npos) << e.what();
  }
}

}  // namespace
}  // namespace romunect::calib
