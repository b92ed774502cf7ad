#include "romunect/calib/intrinsics.h"

#include <cmath>
#include <random>

#include <gtest/gtest.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

using testing::TruthCamera;

// Corner noise of the synthetic views: typical sub-pixel detection on a sharp IR image.
constexpr double kNoisePx = 0.2;
// The calibration goal for 20 planned views: full-image mapping error vs truth.
constexpr double kMappingGoalPx = 0.25;
// Detection on a clean rendered image (bilinear warp, no noise): cornerSubPix is within this.
constexpr double kDetectionTolerancePx = 0.1;
constexpr double kBlurTiltRad = 0.9;
constexpr double kBlurSigmaPx = 3.5;

BoardSpec Board() { return {9, 6, 0.025}; }
// Noise per coordinate sigma gives a 2-D reprojection RMS of sqrt(2) sigma.
const double kNoiseRmsPx = std::sqrt(2.0) * kNoisePx;

std::vector<BoardView> ObserveAll(const CameraModel& camera, const BoardSpec& board, const std::vector<Pose>& T_C_K,
                                  std::mt19937* rng) {
  std::vector<BoardView> views;
  for (const Pose& T : T_C_K) {
    auto v = testing::ObserveBoard(camera, board, T, kNoisePx, rng);
    EXPECT_TRUE(v.has_value());
    if (v) views.push_back(*v);
  }
  return views;
}

std::vector<Pose> Inverted(const std::vector<Pose>& poses) {
  std::vector<Pose> out;
  for (const Pose& T : poses) out.push_back(T.inverse());
  return out;
}

// Largest distance of detected corners from the true projections (infinite when the board is
// not wholly in view). OpenCV may start from the opposite corner: a 180-degree turn of the grid
// is the same board, so the better of both orders counts.
double MaxCornerErrorPx(const std::vector<cv::Point2f>& corners, const CameraModel& camera, const BoardSpec& board,
                        const Pose& T_C_K) {
  std::vector<cv::Point2f> truth;
  if (!ProjectBoard(camera, board, T_C_K, &truth) || truth.size() != corners.size()) return INFINITY;
  double max_error = 0.0, max_error_reversed = 0.0;
  for (size_t i = 0; i < truth.size(); ++i) {
    max_error = std::max(max_error, cv::norm(corners[i] - truth[i]));
    max_error_reversed = std::max(max_error_reversed, cv::norm(corners[truth.size() - 1 - i] - truth[i]));
  }
  return std::min(max_error, max_error_reversed);
}

TEST(IntrinsicsTest, DetectsCornersOfRenderedBoardWithinSubpixel) {
  CameraModel camera = TruthCamera();
  camera.distortion = {};
  const BoardSpec board = Board();
  const Pose T_C_K = MakePose(Eigen::AngleAxisd(0.3, Eigen::Vector3d(1, 0.5, 0).normalized()).toRotationMatrix(),
                              Eigen::Vector3d(-0.08, -0.05, 0.32));
  const cv::Mat image = testing::RenderBoardImage(camera, board, T_C_K);
  std::string reason;
  const auto corners = DetectBoard(image, board, &reason);
  ASSERT_TRUE(corners.has_value()) << reason;
  EXPECT_LT(MaxCornerErrorPx(*corners, camera, board, T_C_K), kDetectionTolerancePx);
}

// A strongly tilted, defocused view (as the rig's strongest tilts): the plain detector misses
// it, the sector-based fallback finds it, and the shared refinement keeps sub-pixel accuracy.
// Blur moves corners of a tilted board by its asymmetry: twice the sharp tolerance (0.08 measured).
constexpr double kBlurredDetectionTolerancePx = 0.2;

TEST(IntrinsicsTest, DetectsBlurredTiltedBoardThePlainDetectorMisses) {
  CameraModel camera = TruthCamera();
  camera.distortion = {};
  const BoardSpec board = Board();
  const Pose T_C_K =
      MakePose(Eigen::AngleAxisd(kBlurTiltRad, Eigen::Vector3d(1, 0.3, 0).normalized()).toRotationMatrix(),
               Eigen::Vector3d(-0.1, -0.06, 0.34));
  cv::Mat image = testing::RenderBoardImage(camera, board, T_C_K);
  cv::GaussianBlur(image, image, cv::Size(), kBlurSigmaPx);
  ASSERT_EQ(image.type(), CV_8U);
  std::vector<cv::Point2f> plain;
  ASSERT_FALSE(cv::findChessboardCorners(image, {board.cols, board.rows}, plain,
                                         cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK))
      << "the view no longer exercises the fallback";
  std::string reason;
  const auto corners = DetectBoard(image, board, &reason);
  ASSERT_TRUE(corners.has_value()) << reason;
  EXPECT_LT(MaxCornerErrorPx(*corners, camera, board, T_C_K), kBlurredDetectionTolerancePx);
}

TEST(IntrinsicsTest, RejectsImageWithoutBoardWithReason) {
  const cv::Mat blank(240, 320, CV_16U, cv::Scalar(300));
  std::string reason;
  EXPECT_FALSE(DetectBoard(blank, Board(), &reason).has_value());
  EXPECT_NE(reason.find("not found"), std::string::npos) << reason;
}

TEST(IntrinsicsTest, FolderDetectionListsRejectedViewsAndRefusesMixedSizes) {
  romunect::testing::ScratchDir dir("views");
  CameraModel camera = TruthCamera();
  camera.distortion = {};
  const BoardSpec board = Board();
  const Pose T_C_K = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(-0.08, -0.05, 0.3));
  cv::imwrite((dir / "a.png").string(), testing::RenderBoardImage(camera, board, T_C_K));
  cv::imwrite((dir / "b.png").string(), cv::Mat(camera.height, camera.width, CV_8U, cv::Scalar(90)));
  const DetectedViews views = DetectBoardInFolder(dir.path(), board);
  ASSERT_EQ(views.views.size(), 1u);
  EXPECT_EQ(views.views[0].name, "a.png");
  ASSERT_EQ(views.rejected.size(), 1u);
  EXPECT_EQ(views.rejected[0].first, "b.png");
  cv::imwrite((dir / "c.png").string(), cv::Mat(100, 100, CV_8U, cv::Scalar(90)));
  try {
    DetectBoardInFolder(dir.path(), board);
    FAIL() << "mixed sizes accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("c.png"), std::string::npos) << e.what();
  }
}

TEST(IntrinsicsTest, PlannedViewsCoverWholeImageAndTilts) {
  const CameraModel camera = TruthCamera();
  const BoardSpec board = Board();
  ViewPlanOptions options;
  options.distance_m = 0.3;
  const std::vector<Pose> plan = PlanViews(camera, board, options);
  ASSERT_EQ(plan.size(), 20u);
  std::mt19937 rng(3);
  const std::vector<Pose> T_C_K = Inverted(plan);
  const std::vector<BoardView> views = ObserveAll(camera, board, T_C_K, &rng);  // every view fits
  const Coverage coverage = MeasureCoverage(views, T_C_K, {camera.width, camera.height}, 8, 6);
  // Coverage goals: nearly every cell (the corner cells included) and tilts both ways.
  EXPECT_GE(coverage.cell_fraction, 0.9);
  EXPECT_GE(coverage.tilt_x_spread_rad, 0.6);
  EXPECT_GE(coverage.tilt_y_spread_rad, 0.6);
}

TEST(IntrinsicsTest, PlannedViewsMeetMappingGoalAndBeatWeakCoverage) {
  const CameraModel truth = TruthCamera();
  const BoardSpec board = Board();
  ViewPlanOptions plan_options;
  plan_options.distance_m = 0.3;
  std::mt19937 rng(11);
  const std::vector<BoardView> planned = ObserveAll(truth, board, Inverted(PlanViews(truth, board, plan_options)),
                                                    &rng);
  const IntrinsicsResult good = CalibrateIntrinsics(planned, board, {truth.width, truth.height});
  const MappingError good_error = FullImageMappingError(good.camera, truth);
  EXPECT_LE(good_error.rms_px, kMappingGoalPx) << good.BriefReport();
  // The RMS is the corner noise (less ~2 % for the fitted parameters); held out slightly more.
  EXPECT_NEAR(good.rms_px, kNoiseRmsPx, 0.02);
  EXPECT_NEAR(good.holdout_rms_px, kNoiseRmsPx, 0.03);
  EXPECT_GT(good.holdout_rms_px, good.rms_px);
  ASSERT_EQ(good.per_view_rms_px.size(), planned.size());

  const std::vector<BoardView> central = ObserveAll(truth, board, testing::CentralViews(truth, board, 20, 0.3, &rng),
                                                    &rng);
  const IntrinsicsResult weak = CalibrateIntrinsics(central, board, {truth.width, truth.height});
  const MappingError weak_error = FullImageMappingError(weak.camera, truth);
  // Same noise, similar RMS, but weak coverage: the error away from the centre is larger.
  EXPECT_NEAR(weak.rms_px, good.rms_px, 0.03);
  EXPECT_GT(weak_error.rms_px, 1.5 * good_error.rms_px) << weak.BriefReport();
  EXPECT_LT(weak.coverage.cell_fraction, good.coverage.cell_fraction);
}

TEST(IntrinsicsTest, MappingErrorIsZeroForTruthAndMatchesFocalError) {
  const CameraModel truth = TruthCamera();
  EXPECT_LT(FullImageMappingError(truth, truth).max_px, 1e-6);
  CameraModel wrong = truth;
  wrong.fx += 1.0;
  // A focal error of 1 px moves a pixel at horizontal distance x by x / fx (undistorted).
  const double far_x = std::max(truth.cx, truth.width - 1 - truth.cx);
  const double max_px = FullImageMappingError(wrong, truth, 1).max_px;
  EXPECT_GT(max_px, 0.8 * far_x / truth.fx);
  EXPECT_LT(max_px, 1.2 * far_x / truth.fx);
}

TEST(IntrinsicsTest, TooFewViewsIsAClearError) {
  const CameraModel truth = TruthCamera();
  std::mt19937 rng(1);
  const std::vector<BoardView> views = ObserveAll(truth, Board(), testing::CentralViews(truth, Board(), 2, 0.3, &rng),
                                                  &rng);
  try {
    CalibrateIntrinsics(views, Board(), {truth.width, truth.height});
    FAIL() << "two views accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("need at least 4"), std::string::npos) << e.what();
  }
}

TEST(IntrinsicsTest, PlannerRefusesBoardLargerThanImage) {
  ViewPlanOptions options;
  options.distance_m = 0.05;
  EXPECT_THROW(PlanViews(TruthCamera(), Board(), options), InputError);
}

}  // namespace
}  // namespace romunect::calib
