#include "romunect/sensor/depth_engine.h"

#include <cmath>

#include <gtest/gtest.h>

#include "analytic_geometry.h"
#include "reference_matcher.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

// One engine per preset for the whole suite: rendering the reference takes a while.
DepthEngine& Engine(const std::string& preset) {
  static DepthEngine kinect(RigPreset("kinect-v1").depth_engine);
  static DepthEngine romunect(RigPreset("romunect").depth_engine);
  return preset == "kinect-v1" ? kinect : romunect;
}

cv::Mat RenderIr(const Rig& rig, const testing::AnalyticScene& scene, uint64_t seed, GeometryBuffer* geometry) {
  *geometry = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
  IrSynthesizer synth;
  cv::Mat ir;
  synth.Synthesize(rig, *geometry, seed, &ir, nullptr);
  return ir;
}

TEST(DepthEngineTest, RawFormulaMatchesTheKinectLiterature) {
  const DepthEngine& engine = Engine("kinect-v1");
  // Konolige and Mihelich: Z = 8 b f / (doff - raw), b = 7.5 cm, f = 580 px, doff = 1090.
  EXPECT_DOUBLE_EQ(engine.ChipDepthM(742), 8 * 0.075 * 580 / (1090.0 - 742));
  EXPECT_NEAR(engine.ChipDepthM(742), 1.0, 1e-12);  // the reference plane
  EXPECT_EQ(engine.ChipDepthM(kRawInvalid), 0.0);
  EXPECT_DOUBLE_EQ(engine.ShiftOfRaw(742 - 8), 1.0);
  // Step per raw unit: Z^2 / (8 f b), 0.72 mm at 0.5 m.
  const double z = 0.5;
  const int raw = static_cast<int>(std::lround(1090 - 8 * 0.075 * 580 / z));
  EXPECT_NEAR(engine.ChipDepthM(raw + 1) - engine.ChipDepthM(raw), z * z / (8 * 580 * 0.075), 0.01e-3);
}

TEST(DepthEngineTest, FastPathEqualsTheFullSearchReference) {
  const Rig rig = RigPreset("kinect-v1");
  DepthEngine& engine = Engine("kinect-v1");
  // A tilted plane with a sphere in front: edges, shadows and a range of shifts.
  testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(1.3, 0.4);
  scene.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 0.8), 0.12, 0, 2});
  GeometryBuffer g;
  const cv::Mat ir = RenderIr(rig, scene, 3, &g);
  DepthEngineOutput out;
  engine.Compute(ir, &out);
  cv::Mat n_obs, sigma, n_ref, ref_sigma;
  DepthEngine::Prefilter(ir, engine.options().prefilter_px, &n_obs, &sigma);
  DepthEngine::Prefilter(engine.reference_ir(), engine.options().prefilter_px, &n_ref, &ref_sigma);
  int compared = 0, valid = 0;
  for (int y = 0; y < ir.rows; y += 5) {
    for (int x = 0; x < ir.cols; x += 7) {
      const uint16_t expected = testing::ReferenceMatchRaw(engine, n_obs, sigma, n_ref, x, y);
      ASSERT_EQ(out.raw.at<uint16_t>(y, x), expected) << "pixel " << x << ", " << y;
      ++compared;
      valid += expected != kRawInvalid;
    }
  }
  EXPECT_GT(valid, compared / 2);  // the comparison covers real matches, not just rejections
}

TEST(DepthEngineTest, StockDeviceMeasuresAPlaneWithinQuantization) {
  const Rig rig = RigPreset("kinect-v1");
  DepthEngine& engine = Engine("kinect-v1");
  GeometryBuffer g;
  const double z = 1.0;
  const cv::Mat ir = RenderIr(rig, testing::AnalyticScene::TiltedPlane(z, 0.35), 5, &g);
  DepthEngineOutput out;
  engine.Compute(ir, &out);
  const cv::Mat truth = testing::TruthDepth(g);
  int n = 0, within = 0;
  for (int y = 0; y < ir.rows; ++y) {
    for (int x = 0; x < ir.cols; ++x) {
      const float d = out.depth_m.at<float>(y, x);
      if (d <= 0) continue;
      ++n;
      // Two raw steps (~ 2 x 3 mm at 1 m): quantization plus sub-pixel noise.
      const double step = truth.at<float>(y, x) * truth.at<float>(y, x) / (8 * 580 * 0.075);
      within += std::abs(d - truth.at<float>(y, x)) <= 2 * step;
    }
  }
  EXPECT_GT(n, 0.9 * ir.total());
  EXPECT_GT(within, 0.95 * n);
}

TEST(DepthEngineTest, ThreadsGiveTheSameBytes) {
  const Rig rig = RigPreset("kinect-v1");
  GeometryBuffer g;
  testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(1.6, -0.3);
  scene.boxes.push_back({Eigen::Vector3d(-0.1, -0.1, 0.9), Eigen::Vector3d(0.1, 0.1, 1.0), 0, 2});
  const cv::Mat ir = RenderIr(rig, scene, 11, &g);
  DepthEngineOptions two = rig.depth_engine;
  two.threads = 2;
  DepthEngine engine2(two, Engine("kinect-v1").reference_ir());
  DepthEngineOutput a, b;
  Engine("kinect-v1").Compute(ir, &a);
  engine2.Compute(ir, &b);
  EXPECT_TRUE(testing::ImagesBitEqual(a.raw, b.raw));
  EXPECT_TRUE(testing::ImagesBitEqual(a.depth_m, b.depth_m));
  EXPECT_EQ(a.stats.valid, b.stats.valid);
}

TEST(DepthEngineTest, WrongImageIsBadInput) {
  DepthEngineOutput out;
  try {
    Engine("kinect-v1").Compute(cv::Mat(240, 320, CV_16U, cv::Scalar(0)), &out);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "ir");
    EXPECT_NE(std::string(e.what()).find("640 x 480"), std::string::npos) << e.what();
  }
  EXPECT_THROW(Engine("kinect-v1").Compute(cv::Mat(480, 640, CV_8U, cv::Scalar(0)), &out), InputError);
}

TEST(DepthCorrectionTest, BothModelsRecoverAKnownMapping) {
  // Synthetic outputs: raw r gives true depth 1 / (a r + b) exactly; chip depth from the formula.
  const DepthEngine& engine = Engine("kinect-v1");
  std::vector<DepthEngineOutput> outputs(3);
  std::vector<cv::Mat> truth(3);
  const double a = -2.0e-3, b = 6.0;
  for (int i = 0; i < 3; ++i) {
    const int raw = 700 + 40 * i;
    outputs[i].raw = cv::Mat(4, 5, CV_16U, cv::Scalar(raw));
    outputs[i].depth_m = cv::Mat(4, 5, CV_32F, cv::Scalar(engine.ChipDepthM(raw)));
    truth[i] = cv::Mat(4, 5, CV_32F, cv::Scalar(1.0 / (a * raw + b)));
  }
  outputs[0].raw.at<uint16_t>(0, 0) = kRawInvalid;
  outputs[1].raw.at<uint16_t>(0, 0) = kRawInvalid;  // one sample left: no fit
  const DepthCorrection inverse = FitDepthCorrection(DepthCorrectionModel::kInverseAffineInRaw, outputs, truth);
  // The truth is stored as float (relative error 6e-8), which bounds the recovered a and b.
  EXPECT_NEAR(inverse.a.at<double>(1, 1), a, 1e-8);
  EXPECT_NEAR(inverse.b.at<double>(1, 1), b, 1e-5);
  EXPECT_TRUE(std::isnan(inverse.a.at<double>(0, 0)));
  const cv::Mat metric = ApplyDepthCorrection(inverse, outputs[2]);
  EXPECT_NEAR(metric.at<float>(2, 3), truth[2].at<float>(2, 3), 1e-6);
  EXPECT_EQ(metric.at<float>(0, 0), 0.0f);
  // The affine-in-depth model is not exact for this mapping but close over a short range.
  const DepthCorrection affine = FitDepthCorrection(DepthCorrectionModel::kAffineInChipDepth, outputs, truth);
  EXPECT_NEAR(ApplyDepthCorrection(affine, outputs[1]).at<float>(2, 3), truth[1].at<float>(2, 3), 0.02);
}

}  // namespace
}  // namespace romunect
