#include "romunect/sensor/ir_synthesis.h"

#include <cmath>
#include <random>
#include <utility>

#include <gtest/gtest.h>
#include <opencv2/imgproc.hpp>

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
  rig.optics.speckle_contrast = 0.0;
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

// The noise of a plane's image (seed 1) against its noise-free one: shot, read and speckle
// variance (e + (c e)^2 + read^2, in DN^2) and zero mean. Returns the noisy image.
cv::Mat ExpectNoiseVariance(const Rig& rig, const GeometryBuffer& g) {
  IrSynthesizer quiet(NoNoise()), noisy;
  cv::Mat clean, ir;
  quiet.Synthesize(rig, g, 1, &clean, nullptr);
  noisy.Synthesize(rig, g, 1, &ir, nullptr);
  const double e = quiet.expected_electrons().at<float>(30, 40);
  const double c = rig.optics.speckle_contrast;
  const double gain2 = rig.optics.gain_dn_per_e * rig.optics.gain_dn_per_e;
  const double expected_var = (e + c * c * e * e + rig.optics.read_noise_e * rig.optics.read_noise_e) * gain2 +
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
  return ir;
}

// Laser speckle adds (contrast x signal)^2 to the variance: multiplicative, zero-mean.
TEST(IrSynthesisTest, SpeckleAddsItsContrastTimesTheSignalToTheNoise) {
  Rig rig = UniformRig();
  rig.optics.speckle_contrast = 0.1;
  const GeometryBuffer g = FrontoParallelPlane(rig.camera, 2.0, IrMaterial{0.5f, 0, 50});
  IrSynthesizer quiet(NoNoise());
  cv::Mat clean;
  quiet.Synthesize(rig, g, 1, &clean, nullptr);
  const double e = quiet.expected_electrons().at<float>(30, 40);
  ASSERT_GT(rig.optics.speckle_contrast * rig.optics.speckle_contrast * e, 2.0)
      << "the speckle term must dominate the shot noise here";
  ExpectNoiseVariance(rig, g);
  rig.optics.speckle_contrast = 1.5;
  EXPECT_NE(rig.Problem().find("speckle_contrast"), std::string::npos) << rig.Problem();
}

TEST(IrSynthesisTest, NoiseHasTheShotAndReadVariance) {
  const Rig rig = UniformRig();
  const GeometryBuffer g = FrontoParallelPlane(rig.camera, 2.0, IrMaterial{0.5f, 0, 50});
  const cv::Mat ir = ExpectNoiseVariance(rig, g);
  IrSynthesizer noisy;
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

// Prepare() and switching the noise off and on (what SensorImager's ground-truth sweep does
// with the synthesizer it keeps) give the bytes of synthesizers made with each setting.
TEST(IrSynthesisTest, PreparedPatternAndSwitchedNoiseGiveTheSameBytes) {
  const Rig rig = RigPreset("kinect-v1");
  const GeometryBuffer g =
      testing::RenderAnalytic(testing::AnalyticScene::TiltedPlane(1.2, 0.3), rig.camera, rig.T_C_P.translation());
  IrSynthesizer noisy, quiet(NoNoise()), switched;
  cv::Mat ir_noisy, ir_quiet, ir;
  noisy.Synthesize(rig, g, 9, &ir_noisy, nullptr);
  quiet.Synthesize(rig, g, 9, &ir_quiet, nullptr);
  ASSERT_FALSE(testing::ImagesBitEqual(ir_noisy, ir_quiet));  // else the test shows nothing
  switched.Prepare(rig);
  switched.set_noise(false);
  EXPECT_FALSE(switched.noise());
  switched.Synthesize(rig, g, 9, &ir, nullptr);
  EXPECT_TRUE(testing::ImagesBitEqual(ir, ir_quiet));
  switched.set_noise(true);
  switched.Synthesize(rig, g, 9, &ir, nullptr);
  EXPECT_TRUE(testing::ImagesBitEqual(ir, ir_noisy));
}

// Every kernel (scalar, AVX2, AVX-512, those this CPU has) gives the scalar kernel's bytes: IR
// and expected electrons, on full frames of both rigs with shiny and dull materials, shadows,
// the pattern's edge, camera defocus, noise, and lens-like layers that partly repeat layer 0;
// with more materials than fit a lookup register; and on an odd-sized camera, whose rows end in
// a partial vector.
TEST(IrSynthesisTest, EveryKernelGivesTheScalarBytes) {
  for (const char* preset : {"romunect", "kinect-v1"}) {
    const Rig rig = RigPreset(preset);
    const double z = preset == std::string("romunect") ? 0.205 : 1.2, r = z / 20;
    testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(z, 0.3);
    scene.materials = {IrMaterial{0.5f, 0.0f, 50.0f}, IrMaterial{0.9f, 0.6f, 80.0f}, IrMaterial{0.2f, 0.3f, 5.0f}};
    scene.spheres.push_back({Eigen::Vector3d(r, 0, z - 2 * r), r, 1, 2});
    scene.spheres.push_back({Eigen::Vector3d(-r, r, z - 3 * r), 0.8 * r, 2, 3});
    Rig odd = rig;
    odd.camera.width = 83;
    odd.camera.height = 61;
    odd.camera.cx = 41;
    odd.camera.cy = 30;
    const GeometryBuffer frame = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
    const GeometryBuffer odd_frame = testing::RenderAnalytic(scene, odd.camera, odd.T_C_P.translation());
    // Layers: the frame, a copy with every other row moved 1 mm closer, and the frame again.
    GeometryBuffer layered = frame;
    GeometryLayer moved = frame.layers[0];
    for (int y = 0; y < moved.p_C.rows; y += 2) {
      for (int x = 0; x < moved.p_C.cols; ++x) moved.p_C.at<cv::Vec3f>(y, x) *= 1.f - 0.001f / static_cast<float>(z);
    }
    moved.lens_offset_m = Eigen::Vector2f(1e-3f, 0.f);
    layered.layers.push_back(moved);
    layered.layers.push_back(frame.layers[0]);
    // More materials than the kernels look up by permutation (16): the same scene at indices 17+.
    GeometryBuffer many = frame;
    many.materials.insert(many.materials.begin(), 17, IrMaterial{0.1f, 0.9f, 3.0f});
    cv::Mat& material = many.layers[0].material;
    cv::add(material, 17, material, material >= 0);
    struct Case {
      const Rig* rig;
      const GeometryBuffer* geometry;
      bool noise, defocus;
    };
    for (const Case& c :
         {Case{&rig, &frame, true, true}, Case{&rig, &frame, false, true}, Case{&rig, &frame, true, false},
          Case{&rig, &layered, true, true}, Case{&rig, &many, true, true}, Case{&odd, &odd_frame, true, true}}) {
      IrSynthesisOptions options;
      options.noise = c.noise;
      options.camera_defocus = c.defocus;
      IrSynthesizer scalar(options);
      scalar.set_isa(Isa::kScalar);
      cv::Mat ir_scalar;
      scalar.Synthesize(*c.rig, *c.geometry, 11, &ir_scalar, nullptr);
      for (Isa isa : {Isa::kAvx2, Isa::kAvx512}) {
        if (!CpuSupports(isa)) continue;
        SCOPED_TRACE(std::string(preset) + ", " + ToString(isa) + ", " + std::to_string(c.geometry->layers.size()) +
                     " layers, " + std::to_string(c.geometry->materials.size()) + " materials, " +
                     std::to_string(c.rig->camera.width) + " wide, noise " + std::to_string(c.noise) + ", defocus " +
                     std::to_string(c.defocus));
        IrSynthesizer fast(options);
        fast.set_isa(isa);
        EXPECT_EQ(fast.isa(), isa);
        cv::Mat ir;
        fast.Synthesize(*c.rig, *c.geometry, 11, &ir, nullptr);
        EXPECT_TRUE(testing::ImagesBitEqual(ir, ir_scalar));
        EXPECT_TRUE(testing::ImagesBitEqual(fast.expected_electrons(), scalar.expected_electrons()));
      }
    }
  }
}

// The slow obvious pattern lookup: the displayed image blurred by a Gaussian of exactly sigma
// (OpenCV's kernel for that sigma, zero outside), sampled bilinearly at (x, y), tap by tap.
double ExactPattern(const cv::Mat& displayed, double x, double y, double sigma) {
  const int ksize = cvRound(sigma * 4 * 2 + 1) | 1, r = ksize / 2;
  const cv::Mat k = cv::getGaussianKernel(ksize, sigma, CV_64F);
  auto blurred = [&](int row, int col) {
    double sum = 0.0;
    for (int a = 0; a < ksize; ++a) {
      for (int b = 0; b < ksize; ++b) {
        const int yy = row + a - r, xx = col + b - r;
        if (yy < 0 || xx < 0 || yy >= displayed.rows || xx >= displayed.cols) continue;
        sum += k.at<double>(a) * k.at<double>(b) * displayed.at<float>(yy, xx);
      }
    }
    return sum;
  };
  const int x0 = static_cast<int>(std::floor(x)), y0 = static_cast<int>(std::floor(y));
  const double fx = x - x0, fy = y - y0;
  return (1 - fy) * ((1 - fx) * blurred(y0, x0) + fx * blurred(y0, x0 + 1)) +
         fy * ((1 - fx) * blurred(y0 + 1, x0) + fx * blurred(y0 + 1, x0 + 1));
}

// Blending two pre-blurred levels 1.5x apart in sigma instead of blurring at sigma: for an
// isolated dot the peak goes as 1 / sigma^2, and the linear blend overshoots it by at most
// ~13 % of the peak midway between levels; on the dot pattern (dots of 0.6, spots of 1.0 on
// 0) that stays below 0.06 of the brightest pattern value.
constexpr double kLevelBlendTolerance = 0.06;

// The camera blur blurs each level only over the bands of rows that read it (ir_synthesis.cc):
// that relies on OpenCV blurring a band of rows to the bytes the whole image has there (it takes
// the rows around the band as its border). Checked at the levels' range of sigmas and at bands
// touching the image's edges.
// kAuto resolves to an instruction set the synthesizer implements; SSE2 is not one of them.
TEST(IrSynthesisTest, IsaResolvesOrIsRefused) {
  IrSynthesizer synth;
  EXPECT_NE(synth.isa(), Isa::kAuto);
  EXPECT_NE(synth.isa(), Isa::kSse2);
  synth.set_isa(Isa::kScalar);
  EXPECT_EQ(synth.isa(), Isa::kScalar);
  synth.set_isa(Isa::kAuto);
  EXPECT_NE(synth.isa(), Isa::kAuto);
  EXPECT_DEATH(synth.set_isa(Isa::kSse2), "sse2");
}

TEST(IrSynthesisTest, ABandOfRowsBlursToTheWholeImagesBytes) {
  cv::Mat image(120, 160, CV_32F);
  cv::RNG rng(7);
  rng.fill(image, cv::RNG::UNIFORM, 0.0, 5000.0);
  for (const float sigma : {0.3f, 0.9f, 2.0f, 4.5f, 12.0f, 30.0f}) {
    cv::Mat whole;
    cv::GaussianBlur(image, whole, cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
    for (const auto& [y0, y1] :
         {std::pair{0, 120}, std::pair{0, 17}, std::pair{40, 41}, std::pair{33, 90}, std::pair{101, 120}}) {
      cv::Mat out(image.size(), CV_32F, cv::Scalar(-1.0f));
      cv::Mat band = out.rowRange(y0, y1);
      cv::GaussianBlur(image.rowRange(y0, y1), band, cv::Size(0, 0), sigma, sigma, cv::BORDER_REPLICATE);
      EXPECT_TRUE(testing::ImagesBitEqual(band, whole.rowRange(y0, y1)))
          << "sigma " << sigma << ", rows " << y0 << ".." << y1;
    }
  }
}

TEST(IrSynthesisTest, PatternBlurLevelsStayCloseToTheExactBlur) {
  Rig rig = RigPreset("romunect");
  rig.optics.psf_sigma_px = 0.0;
  rig.optics.ambient_e_per_s = 0.0;
  IrSynthesisOptions options = NoNoise();
  options.camera_defocus = false;
  IrSynthesizer synth(options);
  const cv::Mat displayed = ProjectorImage(rig);
  const Pose T_P_C = rig.T_C_P.inverse();
  const ProjectorModel& pr = rig.projector;
  const Eigen::Vector3d c_P = rig.T_C_P.translation();
  std::mt19937 rng(3);
  std::uniform_int_distribution<int> column(0, rig.camera.width - 1), row(0, rig.camera.height - 1);
  double worst = 0.0, sigma_min = 1e9, sigma_max = 0.0;
  cv::Mat ir;
  // In focus (0.206 m) to far out of it: sigmas from the pixel footprint up to ~5 px.
  for (double z : {0.15, 0.185, 0.2, 0.206, 0.212, 0.25}) {
    const GeometryBuffer g = FrontoParallelPlane(rig.camera, z, IrMaterial{1.0f, 0.0f, 50.0f});
    synth.Synthesize(rig, g, 1, &ir, nullptr);
    for (int i = 0; i < 150; ++i) {
      const int u = column(rng), v = row(rng);
      const cv::Vec3f p = g.layers[0].p_C.at<cv::Vec3f>(v, u);
      const Eigen::Vector3d p_C(p[0], p[1], p[2]);
      const Eigen::Vector3d p_P = T_P_C * p_C;
      const double xp = pr.fx * p_P.x() / p_P.z() + pr.cx, yp = pr.fy * p_P.y() / p_P.z() + pr.cy;
      const double coc = pr.fx * pr.aperture_m * std::abs(1.0 / p_P.z() - 1.0 / pr.focus_distance_m);
      const double footprint = pr.fx / rig.camera.fx / std::sqrt(12.0) * p_C.z() / p_P.z();
      const double sigma = std::sqrt(0.29 * 0.29 + footprint * footprint + coc * coc / 16.0);
      sigma_min = std::min(sigma_min, sigma);
      sigma_max = std::max(sigma_max, sigma);
      const Eigen::Vector3d to_light = c_P - p_C;
      const double cos_in = to_light.normalized().dot(Eigen::Vector3d(0, 0, -1));
      const double unit_e = rig.optics.exposure_s * pr.brightness_e_per_s * cos_in / to_light.squaredNorm();
      const double pattern = synth.expected_electrons().at<float>(v, u) / unit_e;
      worst = std::max(worst, std::abs(pattern - ExactPattern(displayed, xp, yp, sigma)));
    }
  }
  EXPECT_LT(sigma_min, 0.6);  // the comparison covers sharp dots ...
  EXPECT_GT(sigma_max, 4.0);  // ... and strongly defocused ones
  EXPECT_LT(worst, kLevelBlendTolerance);
}

TEST(IrSynthesisTest, NoiseIsGaussianOutToItsTails) {
  Rig rig = UniformRig();
  rig.camera = RigPreset("kinect-v1").camera;  // 640 x 480: enough samples for the tails
  rig.optics.shot_noise = false;
  rig.optics.read_noise_e = 160.0;  // 40 DN: quantization (1 DN) is negligible
  IrSynthesizer quiet(NoNoise()), noisy;
  cv::Mat clean, ir;
  const GeometryBuffer g = FrontoParallelPlane(rig.camera, 2.0, IrMaterial{0.5f, 0, 50});
  // ~2000 e (0.03 s x 0.5 / 4 m^2 x brightness): 5 sigma from 0 and from the full well.
  rig.projector.brightness_e_per_s = 2000.0 / (0.03 * 0.5 / 4.0);
  quiet.Synthesize(rig, g, 1, &clean, nullptr);
  noisy.Synthesize(rig, g, 7, &ir, nullptr);
  const double sigma_dn = rig.optics.read_noise_e * rig.optics.gain_dn_per_e;
  // Integer differences: one exactly at k sigma (k sigma is a whole DN) counts half, the
  // midpoint of the rounded values on either side.
  double beyond[4] = {0, 0, 0, 0};
  int used = 0;
  double sum = 0.0, sum2 = 0.0;
  for (int v = 0; v < ir.rows; ++v) {
    for (int u = 0; u < ir.cols; ++u) {
      const int level = clean.at<uint16_t>(v, u);
      if (level < 5 * sigma_dn || level > rig.optics.MaxDn() - 5 * sigma_dn) continue;  // no clipping
      ++used;
      const int diff = ir.at<uint16_t>(v, u) - level;
      const double d = diff / sigma_dn;
      sum += d;
      sum2 += d * d;
      for (int k = 1; k <= 3; ++k) {
        const int at = static_cast<int>(k * sigma_dn);
        beyond[k] += std::abs(diff) > at ? 1.0 : (std::abs(diff) == at ? 0.5 : 0.0);
      }
    }
  }
  ASSERT_GT(used, 250000);
  const double n = used;
  // ~300000 samples: standard errors 0.002 (mean), 0.003 (variance), 0.0008, 0.0004 and 0.0001
  // (tail shares); the tolerances are about 4 of them.
  EXPECT_NEAR(sum / n, 0.0, 0.01);
  EXPECT_NEAR(sum2 / n, 1.0, 0.012);
  EXPECT_NEAR(beyond[1] / n, 0.3173, 0.0035);
  EXPECT_NEAR(beyond[2] / n, 0.0455, 0.0016);
  EXPECT_NEAR(beyond[3] / n, 0.0027, 0.0004);
}

// Quality-mode layers are averaged; a layer that repeats layer 0's hit in a pixel (adaptive
// sampling away from edges) reuses its radiance, which must give the same average.
TEST(IrSynthesisTest, LayersAreAveragedAndRepeatedSamplesReuseTheCentre) {
  const Rig rig = RigPreset("kinect-v1");
  testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(1.2, 0.3);
  scene.spheres.push_back({Eigen::Vector3d(0.05, 0, 1.0), 0.1, 0, 2});
  const GeometryBuffer g = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
  GeometryBuffer other = FrontoParallelPlane(rig.camera, 1.5, IrMaterial{0.7f, 0.2f, 30.0f});
  other.layers[0].pixel_offset_px = Eigen::Vector2f(0.3f, 0.1f);
  // Layers: g, g, g (repeats), and one that differs everywhere but shares g's materials.
  GeometryBuffer mixed = g;
  mixed.layers.push_back(g.layers[0]);
  mixed.layers.push_back(g.layers[0]);
  mixed.materials.push_back(other.materials[0]);
  other.layers[0].material.setTo(static_cast<int>(mixed.materials.size()) - 1);
  mixed.layers.push_back(other.layers[0]);
  GeometryBuffer only_other = other;
  only_other.materials = mixed.materials;
  IrSynthesisOptions options = NoNoise();
  options.camera_defocus = false;
  IrSynthesizer a(options), b(options), c(options);
  cv::Mat ir;
  a.Synthesize(rig, mixed, 1, &ir, nullptr);
  b.Synthesize(rig, g, 1, &ir, nullptr);
  c.Synthesize(rig, only_other, 1, &ir, nullptr);
  // Before the camera PSF (a linear blur), the average is (3 e_g + e_other) / 4; float sums of
  // a few hundred electrons: 1e-4 relative.
  cv::Mat expected = (3.0 * b.expected_electrons() + c.expected_electrons()) / 4.0;
  EXPECT_LT(cv::norm(a.expected_electrons(), expected, cv::NORM_INF), 1e-4 * cv::norm(expected, cv::NORM_INF));
}

}  // namespace
}  // namespace romunect
