#include "romunect/sensor/depth_engine.h"

#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "analytic_geometry.h"
#include "reference_matcher.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

// The stock preset without its fixed-pattern distortion: these tests hold the matching itself
// (the distortion has its own, tests/sensor/disparity_distortion_test.cc).
Rig StockChipRig() {
  Rig rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion = DisparityDistortion{};
  return rig;
}

// One engine per preset for the whole suite: rendering the reference takes a while.
DepthEngine& Engine(const std::string& preset) {
  static DepthEngine kinect(StockChipRig().depth_engine);
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

// A tilted plane with a sphere in front (edges, shadows and a range of shifts) and a box, as the
// kinect-v1 preset sees it.
cv::Mat KinectTestIr(uint64_t seed) {
  testing::AnalyticScene scene = testing::AnalyticScene::TiltedPlane(1.3, 0.4);
  scene.spheres.push_back({Eigen::Vector3d(0.0, 0.0, 0.8), 0.12, 0, 2});
  scene.boxes.push_back({Eigen::Vector3d(-0.3, 0.1, 0.9), Eigen::Vector3d(-0.1, 0.3, 1.0), 0, 2});
  GeometryBuffer g;
  return RenderIr(StockChipRig(), scene, seed, &g);
}

// Every `step`-th pixel of the engine's output against the full-search reference, on the
// reference's own prefilter (cv::boxFilter). Returns how many of them are valid.
int ExpectEqualsReference(DepthEngine& engine, const cv::Mat& ir, int step_y, int step_x) {
  DepthEngineOutput out;
  engine.Compute(ir, &out);
  cv::Mat n_obs, sigma, n_ref, ref_sigma;
  testing::ReferencePrefilter(ir, engine.options().prefilter_px, &n_obs, &sigma);
  testing::ReferencePrefilter(engine.reference_ir(), engine.options().prefilter_px, &n_ref, &ref_sigma);
  int valid = 0;
  for (int y = 0; y < ir.rows; y += step_y) {
    for (int x = 0; x < ir.cols; x += step_x) {
      const uint16_t expected = testing::ReferenceMatchRaw(engine, n_obs, sigma, n_ref, x, y);
      EXPECT_EQ(out.raw.at<uint16_t>(y, x), expected) << "pixel " << x << ", " << y;
      if (out.raw.at<uint16_t>(y, x) != expected) return valid;
      valid += expected != kRawInvalid;
    }
  }
  return valid;
}

TEST(DepthEngineTest, FastPathEqualsTheFullSearchReference) {
  DepthEngine& engine = Engine("kinect-v1");
  const int valid = ExpectEqualsReference(engine, KinectTestIr(3), 5, 7);
  // The comparison covers real matches, not just rejections.
  EXPECT_GT(valid, (480 / 5) * (640 / 7) / 2);
}

TEST(DepthEngineTest, FastPathEqualsTheReferenceOnOtherWindowsRangesAndRules) {
  // Search ranges that are not a multiple of the 32 SIMD lanes, other windows, both ends of the
  // uniqueness rule, a search that starts at a positive shift: each against the reference.
  struct Case {
    int window_px, min_shift_px, search_range_px;
    double uniqueness, max_cost;
  };
  const cv::Mat ir = KinectTestIr(4);
  // The last case accepts every cost and its ambiguity threshold saturates 16 bits.
  for (const Case c : {Case{5, -20, 40, 0.0, 25}, Case{11, -32, 96, 0.5, 25}, Case{7, 3, 29, 0.2, 25},
                       Case{9, -40, 70, 0.1, 25}, Case{9, -32, 64, 0.7, 255}}) {
    DepthEngineOptions options = StockChipRig().depth_engine;
    options.window_px = c.window_px;
    options.min_shift_px = c.min_shift_px;
    options.search_range_px = c.search_range_px;
    options.uniqueness = c.uniqueness;
    options.max_cost = c.max_cost;
    ASSERT_EQ(options.Problem(), "");
    // The stored reference cropped to the image: shifts near the sides leave it (the masked path).
    const cv::Mat& full = Engine("kinect-v1").reference_ir();
    const int left = ReferenceMarginsPx(Engine("kinect-v1").options()).first;
    DepthEngine engine(options, full.colRange(left, left + options.chip.camera.width).clone());
    SCOPED_TRACE("window " + std::to_string(c.window_px) + ", shifts from " + std::to_string(c.min_shift_px) +
                 ", range " + std::to_string(c.search_range_px));
    EXPECT_GT(ExpectEqualsReference(engine, ir, 11, 13), 0);
  }
}

// The window at the image's sides is clipped to its columns and its rows reflected at the top
// and bottom: the edges are measured as the reference matcher measures them, and only the chip's
// right-hand columns are lost (as on a PS1080).
TEST(DepthEngineTest, TheImagesEdgesAreMatchedAndOnlyTheChipsRightColumnsAreLost) {
  DepthEngine& engine = Engine("kinect-v1");
  const cv::Mat ir = KinectTestIr(5);
  DepthEngineOutput out;
  engine.Compute(ir, &out);
  cv::Mat n_obs, sigma, n_ref, ref_sigma;
  testing::ReferencePrefilter(ir, engine.options().prefilter_px, &n_obs, &sigma);
  testing::ReferencePrefilter(engine.reference_ir(), engine.options().prefilter_px, &n_ref, &ref_sigma);
  const int W = ir.cols, H = ir.rows, edge = engine.options().window_px;  // a window's width of each side
  int compared = 0, valid = 0;
  for (int y = 0; y < H; ++y) {
    for (int x = 0; x < W; ++x) {
      const bool at_edge = y < edge || y >= H - edge || x < edge || x >= W - kChipBorderColumns - edge;
      if (!at_edge || (x + y) % 3 != 0) continue;
      const uint16_t expected = testing::ReferenceMatchRaw(engine, n_obs, sigma, n_ref, x, y);
      ASSERT_EQ(out.raw.at<uint16_t>(y, x), expected) << "pixel " << x << ", " << y;
      if (x < W - kChipBorderColumns) {
        ++compared;
        valid += expected != kRawInvalid;
      }
    }
  }
  // The scene's plane fills the edges: most of them measure (the sphere and box shadow a few).
  constexpr double kMinValidAtEdges = 0.9;
  EXPECT_GT(valid, kMinValidAtEdges * compared);
  EXPECT_EQ(cv::countNonZero(out.raw.colRange(W - kChipBorderColumns, W) != kRawInvalid), 0);
  EXPECT_EQ(out.stats.border, kChipBorderColumns * H);
}

TEST(DepthEngineTest, EveryKernelAndThreadCountGivesTheSameBytes) {
  // Scalar, SSE2, AVX2 and AVX-512 (those this CPU runs) at 1, 2 and 3 threads, both presets (two and
  // three blocks of 32 shifts): the same raw, depth, shift and counts.
  for (const std::string preset : {"romunect", "kinect-v1"}) {
    const Rig rig = RigPreset(preset);
    testing::AnalyticScene scene = preset == "romunect" ? testing::AnalyticScene::TiltedPlane(0.2, 0.12)
                                                        : testing::AnalyticScene::TiltedPlane(1.3, 0.4);
    scene.spheres.push_back(preset == "romunect"
                                ? testing::AnalyticScene::Sphere{Eigen::Vector3d(0.004, -0.002, 0.205), 0.008, 0, 2}
                                : testing::AnalyticScene::Sphere{Eigen::Vector3d(0.0, 0.0, 0.8), 0.12, 0, 2});
    GeometryBuffer g;
    const cv::Mat ir = RenderIr(rig, scene, 9, &g);
    DepthEngineOutput first;
    int runs = 0;
    for (Isa isa : {Isa::kScalar, Isa::kSse2, Isa::kAvx2, Isa::kAvx512}) {
      if (!CpuSupports(isa)) continue;
      for (int threads : {1, 2, 3}) {
        DepthEngineOptions options = rig.depth_engine;
        options.threads = threads;
        DepthEngine engine(options, Engine(preset).reference_ir());
        engine.set_isa(isa);
        EXPECT_EQ(engine.isa(), isa);
        DepthEngineOutput out;
        engine.Compute(ir, &out);
        ++runs;
        if (first.raw.empty()) {
          first = out;
          continue;
        }
        SCOPED_TRACE(preset + ", " + ToString(isa) + ", " + std::to_string(threads) + " threads");
        EXPECT_TRUE(testing::ImagesBitEqual(out.raw, first.raw));
        EXPECT_TRUE(testing::ImagesBitEqual(out.depth_m, first.depth_m));
        EXPECT_TRUE(testing::ImagesBitEqual(out.shift_px, first.shift_px));
        EXPECT_EQ(out.stats.valid, first.stats.valid);
        EXPECT_EQ(out.stats.flat, first.stats.flat);
        EXPECT_EQ(out.stats.weak, first.stats.weak);
        EXPECT_EQ(out.stats.ambiguous, first.stats.ambiguous);
        EXPECT_EQ(out.stats.out_of_range, first.stats.out_of_range);
        EXPECT_EQ(out.stats.border, first.stats.border);
      }
    }
    EXPECT_GE(runs, 3);
    EXPECT_GT(first.stats.valid, static_cast<int>(ir.total() / 2));
    EXPECT_EQ(first.stats.valid + first.stats.flat + first.stats.weak + first.stats.ambiguous +
                  first.stats.out_of_range + first.stats.border,
              static_cast<int>(ir.total()));
  }
#if defined(__x86_64__)
  EXPECT_TRUE(CpuSupports(Isa::kSse2));  // the x86-64 baseline
  EXPECT_NE(DepthEngine(RigPreset("romunect").depth_engine, Engine("romunect").reference_ir()).isa(), Isa::kScalar);
#endif
}

TEST(DepthEngineTest, PrefilterEqualsTheBoxFilterReference) {
  // Exact integer box sums against cv::boxFilter on floats: the same bytes, on 10-bit and
  // 12-bit images (32-bit sums up to 11 x 11 windows), on full 16-bit ones (squares above 2^24
  // round in float) and on flat ones, at odd sizes.
  std::mt19937 rng(5);
  const int windows[] = {3, 9, 11, 13, 31, 9, 11, 5};
  const int max_values[] = {1023, 1023, 4095, 1023, 4095, 65535, 65535, 1023};
  for (int trial = 0; trial < 8; ++trial) {
    const int width = 40 + static_cast<int>(rng() % 300), height = 33 + static_cast<int>(rng() % 200);
    const int window = windows[trial];
    const int max_value = max_values[trial];
    cv::Mat ir(height, width, CV_16U);
    for (int y = 0; y < height; ++y) {
      for (int x = 0; x < width; ++x) {
        ir.at<uint16_t>(y, x) = trial == 7 ? static_cast<uint16_t>(300 + x % 3)
                                           : static_cast<uint16_t>(rng() % (max_value + 1));
      }
    }
    cv::Mat n, sigma, n_ref, sigma_ref;
    DepthEngine::Prefilter(ir, window, &n, &sigma);
    testing::ReferencePrefilter(ir, window, &n_ref, &sigma_ref);
    SCOPED_TRACE("trial " + std::to_string(trial) + ", window " + std::to_string(window));
    EXPECT_TRUE(testing::ImagesBitEqual(n, n_ref));
    EXPECT_TRUE(testing::ImagesBitEqual(sigma, sigma_ref));
  }
}

TEST(DepthEngineTest, StockDeviceMeasuresAPlaneWithinQuantization) {
  const Rig rig = StockChipRig();
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
  const Rig rig = StockChipRig();
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

// The whole-map correction equals the per-pixel function for both models, bit for bit: random
// maps with NaN and infinite entries, maps that make 1/Z negative or zero, invalid raw values.
TEST(DepthCorrectionTest, WholeMapEqualsThePerPixelFunction) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> a(-3e-3, -1e-3), b(2.0, 8.0);
  for (const DepthCorrectionModel model :
       {DepthCorrectionModel::kInverseAffineInRaw, DepthCorrectionModel::kAffineInChipDepth}) {
    DepthCorrection c;
    c.model = model;
    c.a = cv::Mat(37, 53, CV_64F);
    c.b = cv::Mat(37, 53, CV_64F);
    DepthEngineOutput out;
    out.raw = cv::Mat(37, 53, CV_16U);
    out.depth_m = cv::Mat(37, 53, CV_32F);
    for (int y = 0; y < 37; ++y) {
      for (int x = 0; x < 53; ++x) {
        c.a.at<double>(y, x) = model == DepthCorrectionModel::kAffineInChipDepth ? 1.0 + 0.1 * (a(rng) * 1e3 + 2)
                                                                                 : a(rng);
        c.b.at<double>(y, x) = model == DepthCorrectionModel::kAffineInChipDepth ? 0.01 * (b(rng) - 5) : b(rng);
        out.raw.at<uint16_t>(y, x) = static_cast<uint16_t>(rng() % 4 == 0 ? kRawInvalid : rng() % 3000);
        out.depth_m.at<float>(y, x) = static_cast<float>(rng() % 5 == 0 ? 0.0 : 0.15 + 1e-4 * (rng() % 1000));
      }
    }
    c.a.at<double>(1, 2) = std::numeric_limits<double>::quiet_NaN();
    c.b.at<double>(3, 4) = std::numeric_limits<double>::infinity();
    c.a.at<double>(5, 6) = std::numeric_limits<double>::infinity();
    c.b.at<double>(7, 8) = -std::numeric_limits<double>::infinity();
    c.a.at<double>(9, 10) = std::numeric_limits<double>::max();  // a finite a whose 1/Z overflows
    out.raw.at<uint16_t>(5, 6) = out.raw.at<uint16_t>(9, 10) = 1000;
    const cv::Mat depth = ApplyDepthCorrection(c, out);
    for (int y = 0; y < 37; ++y) {
      for (int x = 0; x < 53; ++x) {
        const float expected = static_cast<float>(
            ApplyDepthCorrectionPixel(c, y, x, out.raw.at<uint16_t>(y, x), out.depth_m.at<float>(y, x)));
        ASSERT_EQ(std::memcmp(&depth.at<float>(y, x), &expected, sizeof(float)), 0) << y << ", " << x;
      }
    }
  }
}

}  // namespace
}  // namespace romunect
