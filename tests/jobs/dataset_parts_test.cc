// The dataset job's parts against plain references: its PNG encoder against OpenCV's decoder,
// the symmetry search on meshes whose symmetries are known, the depth PNG's rounding, and the
// BOP pose fields.
#include <random>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "dataset_png.h"
#include "dataset_scene.h"
#include "romunect/sim/objects.h"
#include "romunect/testing/test_support.h"

namespace romunect::jobs::dataset {
namespace {
using testing::ImagesBitEqual;
using testing::ScratchDir;

TEST(DatasetPng, EveryKindDecodesToTheSameBytes) {
  ScratchDir dir("dataset_png");
  std::mt19937 rng(3);
  cv::Mat noisy(31, 45, CV_16U), smooth(31, 45, CV_16U), mask(31, 45, CV_8U, cv::Scalar(0));
  for (int v = 0; v < noisy.rows; ++v) {
    for (int u = 0; u < noisy.cols; ++u) {
      noisy.at<uint16_t>(v, u) = static_cast<uint16_t>(rng());  // every bit pattern, both bytes
      smooth.at<uint16_t>(v, u) = static_cast<uint16_t>(2000 + 3 * u + v);
    }
  }
  cv::circle(mask, {20, 15}, 9, cv::Scalar(255), -1);
  const std::vector<std::pair<cv::Mat, PngKind>> cases = {
      {noisy, PngKind::kNoisy}, {noisy, PngKind::kDepth}, {smooth, PngKind::kDepth}, {mask, PngKind::kMask}};
  int n = 0;
  for (const auto& [image, kind] : cases) {
    const auto file = dir / (std::to_string(n++) + ".png");
    WritePng(file, image, kind);
    EXPECT_TRUE(ImagesBitEqual(cv::imread(file.string(), cv::IMREAD_UNCHANGED), image)) << file;
  }
}

TEST(DatasetDepth, PngUnitsAreATenthOfAMillimetreRounded) {
  cv::Mat depth_m = (cv::Mat_<float>(1, 5) << 0.0f, 0.2f, 0.20004f, 0.20006f, 7.0f);
  const cv::Mat units = DepthToPng16(depth_m);
  EXPECT_EQ(units.at<uint16_t>(0), 0);     // no measurement stays 0
  EXPECT_EQ(units.at<uint16_t>(1), 2000);  // 200 mm
  EXPECT_EQ(units.at<uint16_t>(2), 2000);  // 200.04 mm rounds down
  EXPECT_EQ(units.at<uint16_t>(3), 2001);  // 200.06 mm rounds up
  EXPECT_EQ(units.at<uint16_t>(4), 0);     // beyond 6.5535 m: no value rather than a wrong one
}

Model FromMesh(const sim::Mesh& mesh) {
  Model m;
  m.vertices_O = mesh.vertices;
  m.triangles = mesh.triangles;
  return m;
}

TEST(DatasetSymmetries, ABoxHasItsThreeHalfTurnsAndAPrismItsTurns) {
  // an off-centre box: half turns about x, y and z through its centre
  const auto box = DiscreteSymmetries(FromMesh(sim::Box({0.01, 0.02, 0.003}, {0.02, 0.011, 0.008})));
  EXPECT_EQ(box.size(), 3u);
  for (const auto& T : box) {
    ASSERT_EQ(T.size(), 16u);
    // the centre (10, 20, 3) mm is fixed: R c + t = c
    const Eigen::Vector3d c(10, 20, 3);
    Eigen::Matrix3d R;
    Eigen::Vector3d t;
    for (int i = 0; i < 3; ++i) {
      for (int j = 0; j < 3; ++j) R(i, j) = T[4 * i + j];
      t(i) = T[4 * i + 3];
    }
    EXPECT_LT((R * c + t - c).norm(), 1e-6);
  }
  // a regular 12-gon prism about z: 11 turns about z and 2 half turns
  const auto prism = DiscreteSymmetries(FromMesh(sim::Cylinder(0, 0, 0.01, 0, 0.004, 12)));
  EXPECT_EQ(prism.size(), 13u);
  // an L-shaped outline has none
  const auto l_shape = DiscreteSymmetries(
      FromMesh(sim::ConvexPrism({{0, 0}, {0.03, 0}, {0.03, 0.01}, {0, 0.02}}, 0, 0.005)));
  EXPECT_EQ(l_shape.size(), 0u);
}

TEST(DatasetPoses, RotationsAreRowMajorAndTranslationsMillimetres) {
  Pose T = Pose::Identity();
  T.linear() = Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  T.translation() = Eigen::Vector3d(0.1, -0.02, 0.2);
  const auto R = RotationRowMajor(T);
  EXPECT_DOUBLE_EQ(R[1].get<double>(), T.linear()(0, 1));  // row 0, column 1
  EXPECT_DOUBLE_EQ(R[3].get<double>(), T.linear()(1, 0));
  const auto t = TranslationMm(T);
  EXPECT_DOUBLE_EQ(t[0].get<double>(), 100.0);
  EXPECT_DOUBLE_EQ(t[2].get<double>(), 200.0);
  EXPECT_EQ(Id6(42), "000042");
}

}  // namespace
}  // namespace romunect::jobs::dataset
