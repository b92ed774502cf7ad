#include "romunect/sensor/ir_synthesis.h"

#include <cmath>

#include <gtest/gtest.h>

#include "analytic_geometry.h"
#include "romunect/sensor/pattern.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

// A small rig (80 x 60) with uniform light, for radiometry in closed form.
Rig UniformRig() {
  Rig rig = RigPreset("kinect-v1");
  rig.camera = testing::SmallCamera();
  rig.depth_engine.chip.camera.width = rig.camera.width;  // keep the rig valid at this size
  rig.depth_engine.chip.camera.height = rig.camera.height;
  rig.pattern.kind = PatternKind::kUniform;
  rig.projector.aperture_m = 0.0;
  rig.optics.aperture_m = 0.0;
  rig.optics.psf_sigma_px = 0.0;
  rig.optics.ambient_e_per_s = 0.0;
  rig.projector.brightness_e_per_s = 1.0e5;  // no saturation at 1.5 m
  return rig;
}

IrSynthesisOptions NoNoise() {
  IrSynthesisOptions o;
  o.noise = false;
  return o;
}

// The expected image is exact up to float rounding; 0.1 % covers it.
constexpr double kRadiometryRelTolerance = 1e-3;

TEST(IrSynthesisTest, FrontalWhitePlaneGivesTheRadiometricFormula) {
  const Rig rig = UniformRig();
  IrSynthesizer synth(NoNoise());
  cv::Mat ir;
  const double z = 1.5;
  const testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(z, 0.0, IrMaterial{0.8f, 0, 50});
  synth.Synthesize(rig, testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation()), 1, &ir, nullptr);
  // Centre pixel: p = (x, y, z); light from the projector centre at (b, 0, 0).
  const int u = 40, v = 30;
  const Eigen::Vector3d p = rig.camera.Unproject({u, v}, z);
  const Eigen::Vector3d to_light = rig.T_C_P.translation() - p;
  const double cos_in = to_light.normalized().dot(Eigen::Vector3d(0, 0, -1));
  const double e = rig.optics.exposure_s * rig.projector.brightness_e_per_s * 0.8 * cos_in / to_light.squaredNorm();
  EXPECT_NEAR(synth.expected_electrons().at<float>(v, u), e, e * kRadiometryRelTolerance);
  EXPECT_EQ(ir.at<uint16_t>(v, u), std::lround(e * rig.optics.gain_dn_per_e));
}

TEST(IrSynthesisTest, InverseSquareShadowAmbientAndSaturation) {
  Rig rig = UniformRig();
  rig.optics.ambient_e_per_s = 1000.0;
  IrSynthesizer synth(NoNoise());
  cv::Mat ir;
  auto centre_e = [&](double z, bool lit) {
    GeometryBuffer g = FrontoParallelPlane(rig.camera, z, IrMaterial{0.5f, 0, 50});
    if (!lit) g.layers[0].lit.setTo(0);
    synth.Synthesize(rig, g, 1, &ir, nullptr);
    return static_cast<double>(synth.expected_electrons().at<float>(30, 40));
  };
  const double ambient = rig.optics.exposure_s * 1000.0 * 0.5;
  const double near_e = centre_e(1.0, true) - ambient, far_e = centre_e(2.0, true) - ambient;
  // At z = 1 and 2 m the projector distance differs slightly from z (baseline 7.5 cm).
  const Eigen::Vector3d pn = rig.camera.Unproject({40, 30}, 1.0), pf = rig.camera.Unproject({40, 30}, 2.0);
  const Eigen::Vector3d c = rig.T_C_P.translation();
  const double expected_ratio = ((c - pf).squaredNorm() / (c - pn).squaredNorm()) *
                                ((c - pn).normalized().z() / (c - pf).normalized().z());
  EXPECT_NEAR(near_e / far_e, expected_ratio, expected_ratio * kRadiometryRelTolerance);
  EXPECT_NEAR(centre_e(1.0, false), ambient, ambient * kRadiometryRelTolerance);  // shadow: ambient only
  rig.projector.brightness_e_per_s *= 100;
  IrSynthesisStats stats;
  synth.Synthesize(rig, FrontoParallelPlane(rig.camera, 1.0, IrMaterial{}), 1, &ir, &stats);
  EXPECT_EQ(stats.pixels_saturated, 80 * 60);
  EXPECT_EQ(ir.at<uint16_t>(30, 40), std::lround(rig.optics.full_well_e * rig.optics.gain_dn_per_e));
}

TEST(IrSynthesisTest, NoiseHasTheShotAndReadVariance) {
  const Rig rig = UniformRig();
  IrSynthesizer quiet(NoNoise()), noisy;
  cv::Mat clean, ir;
  const GeometryBuffer g = FrontoParallelPlane(rig.camera, 2.0, IrMaterial{0.5f, 0, 50});
  quiet.Synthesize(rig, g, 1, &clean, nullptr);
  noisy.Synthesize(rig, g, 1, &ir, nullptr);
  const double e = quiet.expected_electrons().at<float>(30, 40);
  const double expected_var = (e + rig.optics.read_noise_e * rig.optics.read_noise_e) *
                                  rig.optics.gain_dn_per_e * rig.optics.gain_dn_per_e +
                              1.0 / 6.0;  // rounding of both images
  cv::Mat diff;
  cv::subtract(ir, clean, diff, cv::noArray(), CV_64F);
  cv::Scalar mean, sd;
  cv::meanStdDev(diff, mean, sd);
  // 4800 samples: the variance estimate is good to ~2 % (1 sigma); the image falls off a
  // little across the field (cos and distance), so 10 %.
  constexpr double kVarianceRelTolerance = 0.10;
  EXPECT_NEAR(sd[0] * sd[0], expected_var, expected_var * kVarianceRelTolerance);
  EXPECT_NEAR(mean[0], 0.0, 4 * sd[0] / std::sqrt(diff.total()));  // zero-mean noise: 4 standard errors
  // Same seed, same bytes; another seed, other bytes.
  cv::Mat again, other;
  noisy.Synthesize(rig, g, 1, &again, nullptr);
  noisy.Synthesize(rig, g, 2, &other, nullptr);
  EXPECT_TRUE(testing::ImagesBitEqual(ir, again));
  EXPECT_GT(cv::norm(ir, other, cv::NORM_L1), 0.0);
}

TEST(IrSynthesisTest, DefocusBlursTheDotsAwayFromFocus) {
  Rig rig = RigPreset("romunect");
  IrSynthesizer synth(NoNoise());
  cv::Mat ir;
  // Fine-scale contrast: mean |difference of neighbouring pixels| over the mean level.
  auto contrast = [&](double z) {
    synth.Synthesize(rig, FrontoParallelPlane(rig.camera, z, IrMaterial{}), 1, &ir, nullptr);
    double diff = 0, sum = 0;
    for (int y = 160; y < 320; ++y) {
      for (int x = 200; x < 440; ++x) {
        diff += std::abs(ir.at<uint16_t>(y, x + 1) - ir.at<uint16_t>(y, x));
        sum += ir.at<uint16_t>(y, x);
      }
    }
    return diff / sum;
  };
  const double focused = contrast(0.2), blurred = contrast(0.17);
  // At 3 cm from focus the projector's circle of confusion is ~10 px: dots all but vanish.
  EXPECT_GT(focused, 4 * blurred);
}

TEST(IrSynthesisTest, ThreadsGiveTheSameBytes) {
  const Rig rig = RigPreset("kinect-v1");
  testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(1.2, 0.3);
  scene.spheres.push_back({Eigen::Vector3d(0.05, 0, 1.0), 0.1, 0, 2});
  const GeometryBuffer g = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
  IrSynthesisOptions two;
  two.threads = 2;
  IrSynthesizer a, b(two);
  cv::Mat ir_a, ir_b;
  a.Synthesize(rig, g, 9, &ir_a, nullptr);
  b.Synthesize(rig, g, 9, &ir_b, nullptr);
  EXPECT_TRUE(testing::ImagesBitEqual(ir_a, ir_b));
}

}  // namespace
}  // namespace romunect
