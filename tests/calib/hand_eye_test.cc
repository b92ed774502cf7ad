#include "romunect/calib/hand_eye.h"

#include <cmath>

#include <gtest/gtest.h>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

using testing::TruthCamera;

constexpr double kDeg = M_PI / 180.0;
constexpr double kNoisePx = 0.2;  // corner noise, as in the intrinsics tests
// The hand-eye goal (15 stations, intrinsics known): 0.02 deg and 0.15 mm.
constexpr double kGoalAngleRad = 0.02 * kDeg;
constexpr double kGoalTranslationM = 0.15e-3;
// A failed solve is off by degrees; a working initial estimate is within a few tenths.
constexpr double kInitialAngleRad = 1.0 * kDeg;
constexpr double kInitialTranslationM = 5e-3;
// The board pose is a by-product; its rotation is less constrained than the camera's.
constexpr double kBoardAngleRad = 0.06 * kDeg;
// Noise per coordinate sigma gives a 2-D reprojection RMS of sqrt(2) sigma.
const double kNoiseRmsPx = std::sqrt(2.0) * kNoisePx;

BoardSpec Board() { return {9, 6, 0.02}; }

TEST(HandEyeTest, RecoversCameraInHandWithinGoalFrom15Stations) {
  const CameraModel camera = TruthCamera();
  const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 15, kNoisePx, 0.5, 0.8, 7);
  const HandEyeResult result = CalibrateHandEye(rig.stations, camera, Board());
  EXPECT_TRUE(romunect::testing::PosesNear(result.T_H_C, rig.T_H_C, kGoalAngleRad, kGoalTranslationM))
      << result.BriefReport();
  EXPECT_TRUE(romunect::testing::PosesNear(result.T_B_K, rig.T_B_K, kBoardAngleRad, kGoalTranslationM));
  // The refined residual is the corner noise; the initial one is larger.
  EXPECT_NEAR(result.rms_px, kNoiseRmsPx, 0.02);
  EXPECT_GE(result.initial_rms_px, result.rms_px);
}

TEST(HandEyeTest, RefinementIsMoreAccurateThanOpenCvAlone) {
  const CameraModel camera = TruthCamera();
  double refined_sum = 0.0, opencv_sum = 0.0;
  for (unsigned seed = 1; seed <= 3; ++seed) {
    const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 15, kNoisePx, 0.5, 0.8, seed);
    const HandEyeResult result = CalibrateHandEye(rig.stations, camera, Board());
    refined_sum += ComparePoses(result.T_H_C, rig.T_H_C).translation_m;
    opencv_sum += ComparePoses(OpenCvHandEye(rig.stations, camera, Board(), HandEyeInitialMethod::kTsai), rig.T_H_C)
                      .translation_m;
  }
  // The refinement is typically 4-8x better; ask for 2x on three seeds so the test is not a coin toss.
  EXPECT_LT(2.0 * refined_sum, opencv_sum);
}

TEST(HandEyeTest, GuardSurvivesStationPairsRotatedPast120Degrees) {
  const CameraModel camera = TruthCamera();
  // Rolls up to +-150 deg about the optical axis: many pairs are rotated by more than 120 deg.
  const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 15, kNoisePx, 0.4, 150 * kDeg, 5);
  const HandEyeResult result = CalibrateHandEye(rig.stations, camera, Board());
  ASSERT_GT(result.max_pair_rotation_rad, 120 * kDeg);
  EXPECT_EQ(result.initial_method, "park");
  EXPECT_TRUE(romunect::testing::PosesNear(result.T_H_C_initial, rig.T_H_C, kInitialAngleRad, kInitialTranslationM));
  EXPECT_TRUE(romunect::testing::PosesNear(result.T_H_C, rig.T_H_C, kGoalAngleRad, kGoalTranslationM))
      << result.BriefReport();
  // The failure the guard exists for: OpenCV 4.6's Tsai alone on these stations is off by tens
  // of degrees (fixed upstream after 4.6: if this fails, the guard may be relaxed).
  const PoseError tsai = ComparePoses(OpenCvHandEye(rig.stations, camera, Board(), HandEyeInitialMethod::kTsai),
                                      rig.T_H_C);
  EXPECT_GT(tsai.angle_rad, 10 * kDeg);
  // And forcing Tsai through our pipeline shows the same failure before refinement.
  HandEyeOptions tsai_only;
  tsai_only.initial = HandEyeInitialMethod::kTsai;
  tsai_only.refine = false;
  EXPECT_GT(ComparePoses(CalibrateHandEye(rig.stations, camera, Board(), tsai_only).T_H_C, rig.T_H_C).angle_rad,
            10 * kDeg);
}

TEST(HandEyeTest, PureTranslationIsAClearError) {
  const CameraModel camera = TruthCamera();
  testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 6, kNoisePx, 0.3, 0.3, 2);
  // Same orientation at every station, only the position changes.
  for (size_t i = 0; i < rig.stations.size(); ++i) {
    Pose T_B_H = rig.stations[0].T_B_H;
    T_B_H.translation() += Eigen::Vector3d(0.01 * i, -0.005 * i, 0.003 * i);
    rig.stations[i].T_B_H = T_B_H;
  }
  try {
    CalibrateHandEye(rig.stations, camera, Board());
    FAIL() << "pure translation accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("pure translation"), std::string::npos) << e.what();
  }
}

TEST(HandEyeTest, RotationAboutOneAxisIsAClearError) {
  const CameraModel camera = TruthCamera();
  testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 6, kNoisePx, 0.3, 0.3, 2);
  for (size_t i = 0; i < rig.stations.size(); ++i) {
    Pose T_B_H = rig.stations[0].T_B_H;
    T_B_H.linear() = T_B_H.linear() * Eigen::AngleAxisd(0.1 * i, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    rig.stations[i].T_B_H = T_B_H;
  }
  try {
    CalibrateHandEye(rig.stations, camera, Board());
    FAIL() << "single-axis rotation accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("about one axis"), std::string::npos) << e.what();
  }
}

TEST(HandEyeTest, TooFewStationsIsAClearError) {
  const CameraModel camera = TruthCamera();
  const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, Board(), 2, kNoisePx, 0.3, 0.3, 2);
  EXPECT_THROW(CalibrateHandEye(rig.stations, camera, Board()), InputError);
}

}  // namespace
}  // namespace romunect::calib
