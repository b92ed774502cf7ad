// The fixed-pattern disparity distortion (disparity_distortion.h): the seeded beta map, the
// rig's bounds, the engine adding it before rounding, and the fidelity row against a real
// Kinect v1 (the fixed-pattern error after the unit's own raw-to-depth mapping).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include <gtest/gtest.h>

#include "analytic_geometry.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/disparity_distortion.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

double Percentile(std::vector<double> v, double p) {
  const size_t k = std::min(v.size() - 1, static_cast<size_t>(p / 100.0 * v.size()));
  std::nth_element(v.begin(), v.begin() + k, v.end());
  return v[k];
}

double MeanAbs(const cv::Mat& m, const cv::Rect& r) { return cv::mean(cv::abs(m(r)))[0]; }

// beta's two parts summed (their factors at 1).
cv::Mat Beta(const DisparityDistortion& model, int width, int height) {
  const DisparityDistortionMaps beta = DisparityDistortionBeta(model, width, height);
  return beta.radial + beta.pattern;
}

TEST(DisparityDistortionTest, BetaIsSeededZeroMeanAndLargestInTheCorners) {
  const DisparityDistortion model = KinectV1DisparityDistortion();
  const cv::Mat beta = Beta(model, 640, 480);
  const cv::Mat again = Beta(model, 640, 480);
  EXPECT_EQ(cv::norm(beta, again, cv::NORM_INF), 0.0) << "same seed, same map";
  DisparityDistortion other = model;
  other.seed = 2;
  EXPECT_GT(cv::norm(beta, Beta(other, 640, 480), cv::NORM_INF), 0.5) << "the seed matters";
  // Zero mean within 0.01 code (float sums): a unit's c0/c1 hold the mean.
  EXPECT_NEAR(cv::mean(beta)[0], 0.0, 0.01);
  // The corners (40 x 40 px) carry several times the centre's error: the published maps' shape.
  const double centre = MeanAbs(beta, cv::Rect(300, 220, 40, 40));
  for (const cv::Rect corner : {cv::Rect(0, 0, 40, 40), cv::Rect(600, 0, 40, 40), cv::Rect(0, 440, 40, 40),
                                cv::Rect(600, 440, 40, 40)}) {
    EXPECT_GT(MeanAbs(beta, corner), 3.0 * centre + 1.5) << corner;
  }
  EXPECT_EQ(cv::countNonZero(Beta(DisparityDistortion{}, 64, 48)), 0) << "off by default";
}

TEST(DisparityDistortionTest, BoundsNameTheField) {
  Rig rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion.alpha1 = -0.001;
  EXPECT_NE(rig.Problem().find("depth_engine.disparity_distortion.alpha1"), std::string::npos) << rig.Problem();
  rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion.pattern_scale_px = 1.0;
  EXPECT_NE(rig.Problem().find("disparity_distortion.pattern_scale_px"), std::string::npos) << rig.Problem();
  rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion.pattern_alpha1 = 0.5;
  EXPECT_NE(rig.Problem().find("disparity_distortion.pattern_alpha1"), std::string::npos) << rig.Problem();
  rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion.pattern_alpha0 = std::numeric_limits<double>::quiet_NaN();
  EXPECT_NE(rig.Problem().find("disparity_distortion.pattern_alpha0"), std::string::npos) << rig.Problem();
  // Amplitudes that would move matches by more than 8 px at the near end of the search.
  rig = RigPreset("kinect-v1");
  rig.depth_engine.disparity_distortion.corner_codes = 60.0;
  EXPECT_NE(rig.Problem().find("at most 64 raw codes"), std::string::npos) << rig.Problem();
  EXPECT_FALSE(RigPreset("romunect").depth_engine.disparity_distortion.Active()) << "the metric rig stays clean";
}

TEST(DisparityDistortionTest, RigJsonKeepsTheModelAndNamesABadField) {
  const testing::ScratchDir dir("disparity_distortion_json");
  const Rig rig = RigPreset("kinect-v1");
  SaveRig(dir / "kinect.json", rig);
  EXPECT_EQ(LoadRig(dir / "kinect.json").depth_engine, rig.depth_engine);
  // A file without the field (older rigs) loads with none.
  Rig plain = rig;
  plain.depth_engine.disparity_distortion = DisparityDistortion{};
  SaveRig(dir / "plain.json", plain);
  std::string text = testing::ReadText(dir / "plain.json");
  const size_t at = text.find(",\n    \"disparity_distortion\"");
  ASSERT_NE(at, std::string::npos);
  text.erase(at, text.find('}', at) + 1 - at);
  WriteTextAtomically(dir / "old.json", text);
  EXPECT_FALSE(LoadRig(dir / "old.json").depth_engine.disparity_distortion.Active());
  // A model without the random part's own factor has the published single factor.
  text = testing::ReadText(dir / "kinect.json");
  for (const std::string key : {"pattern_alpha0", "pattern_alpha1"}) {
    const size_t at_key = text.find(",\n      \"" + key + "\"");
    ASSERT_NE(at_key, std::string::npos) << key;
    text.erase(at_key, text.find_first_of(",}", at_key + 2) - at_key);
  }
  WriteTextAtomically(dir / "published.json", text);
  const DisparityDistortion published = LoadRig(dir / "published.json").depth_engine.disparity_distortion;
  EXPECT_EQ(published.pattern_alpha0, rig.depth_engine.disparity_distortion.alpha0);
  EXPECT_EQ(published.pattern_alpha1, rig.depth_engine.disparity_distortion.alpha1);
  // A value out of its physical bounds: the file, the field and the rule.
  text = testing::ReadText(dir / "kinect.json");
  const size_t rms = text.find("\"pattern_rms_codes\": ");
  ASSERT_NE(rms, std::string::npos);
  text.replace(rms, text.find(',', rms) - rms, "\"pattern_rms_codes\": 40.0");
  WriteTextAtomically(dir / "bad.json", text);
  try {
    LoadRig(dir / "bad.json");
    ADD_FAILURE() << "a 40-code pattern was accepted";
  } catch (const InputError& e) {
    testing::ExpectContains(e.what(), {"bad.json", "depth_engine.disparity_distortion.pattern_rms_codes", "[0, 16]"});
  }
}

// The engine adds the model (DisparityDistortionCodes) before rounding to codes: averaged over a block
// the raw shift equals the model's, to within the rounding's dither.
TEST(DisparityDistortionTest, EngineAddsTheModelBeforeRounding) {
  Rig rig = RigPreset("kinect-v1");
  const DepthEngineOptions distorted = rig.depth_engine;
  DepthEngineOptions clean = rig.depth_engine;
  clean.disparity_distortion = DisparityDistortion{};
  IrSynthesisOptions synthesis;
  synthesis.noise = false;
  IrSynthesizer synthesizer(synthesis);
  cv::Mat ir;
  const double z_m = 1.5;
  synthesizer.Synthesize(rig, testing::RenderAnalytic(testing::AnalyticScene::TiltedPlane(z_m, 0.2), rig.camera,
                                                      rig.T_C_P.translation()),
                         1, &ir, nullptr);
  DepthEngine with(distorted, ChipReferenceImage(rig.depth_engine)), without(clean, with.reference_ir());
  DepthEngineOutput a, b;
  with.Compute(ir, &a);
  without.Compute(ir, &b);
  const DisparityDistortionMaps beta = DisparityDistortionBeta(distorted.disparity_distortion, ir.cols, ir.rows);
  int blocks = 0;
  for (int y0 = 16; y0 + 32 <= ir.rows - 16; y0 += 32) {
    for (int x0 = 16; x0 + 32 <= ir.cols - 48; x0 += 32) {
      double shift = 0, model = 0;
      int n = 0;
      for (int y = y0; y < y0 + 32; ++y) {
        for (int x = x0; x < x0 + 32; ++x) {
          const int ra = a.raw.at<uint16_t>(y, x), rb = b.raw.at<uint16_t>(y, x);
          if (ra == kRawInvalid || rb == kRawInvalid) continue;
          shift += ra - rb;
          model += DisparityDistortionCodes(distorted.disparity_distortion, beta.radial.at<float>(y, x),
                                            beta.pattern.at<float>(y, x), rb);
          ++n;
        }
      }
      if (n < 512) continue;
      ++blocks;
      // 0.25 code: the rounding of 1000 pixels of a tilted plane averages out to this.
      EXPECT_NEAR(shift / n, model / n, 0.25) << "block at " << x0 << ", " << y0;
    }
  }
  EXPECT_GT(blocks, 150);
}

// The fixed-pattern error: the per-pixel mean error of noisy frames of a camera-facing plane at
// z_m, as the stock preset's chip depth (its own c0/c1) reports it. The frames step the plane
// through one raw code (offsets of 1/frames code around z_m), as a real unit's noise dithers its
// rounding: the mean keeps the fixed pattern, not the rounding of one distance.
struct FixedPattern {
  double p5_mm = 0, p95_mm = 0, p99_abs_mm = 0;
};

FixedPattern MeasureFixedPattern(const Rig& rig, DepthEngine* engine, double z_m, int frames) {
  IrSynthesizer synthesizer;
  const double code_m = z_m * z_m / (8.0 * rig.depth_engine.chip.FocalTimesBaseline());
  cv::Mat sum = cv::Mat::zeros(rig.camera.height, rig.camera.width, CV_64F);
  cv::Mat count = cv::Mat::zeros(sum.size(), CV_32S);
  cv::Mat ir;
  DepthEngineOutput out;
  for (int f = 0; f < frames; ++f) {
    const double z = z_m + code_m * ((f + 0.5) / frames - 0.5);
    const GeometryBuffer geometry = testing::RenderAnalytic(testing::AnalyticScene::TiltedPlane(z, 0.0), rig.camera,
                                                            rig.T_C_P.translation());
    const cv::Mat truth = testing::TruthDepth(geometry);
    synthesizer.Synthesize(rig, geometry, 9000 + f, &ir, nullptr);
    engine->Compute(ir, &out);
    for (int y = 0; y < ir.rows; ++y) {
      for (int x = 0; x < ir.cols; ++x) {
        const float depth = out.depth_m.at<float>(y, x);
        if (depth <= 0) continue;
        sum.at<double>(y, x) += depth - truth.at<float>(y, x);
        ++count.at<int>(y, x);
      }
    }
  }
  std::vector<double> errors_mm;
  for (int y = 0; y < sum.rows; ++y) {
    for (int x = 0; x < sum.cols; ++x) {
      if (count.at<int>(y, x) < frames) continue;  // a pixel valid in every frame
      errors_mm.push_back(1e3 * sum.at<double>(y, x) / frames);
    }
  }
  FixedPattern p;
  if (errors_mm.size() < 1000) return p;
  p.p5_mm = Percentile(errors_mm, 5);
  p.p95_mm = Percentile(errors_mm, 95);
  for (double& e : errors_mm) e = std::abs(e);
  p.p99_abs_mm = Percentile(errors_mm, 99.9);
  return p;
}

// The model's own error in mm at a camera-facing plane z_m: DisparityDistortionCodes at the
// plane's raw value, times the chip's depth step there.
std::vector<double> ModelErrorsMm(const Rig& rig, double z_m) {
  const ChipGeometry& chip = rig.depth_engine.chip;
  const double raw = chip.raw_offset - 8.0 * chip.FocalTimesBaseline() / z_m;
  const double mm_per_code = 1e3 * z_m * z_m / (8.0 * chip.FocalTimesBaseline());
  const DisparityDistortion& model = rig.depth_engine.disparity_distortion;
  const DisparityDistortionMaps beta = DisparityDistortionBeta(model, rig.camera.width, rig.camera.height);
  std::vector<double> errors;
  for (int y = 0; y < beta.radial.rows; ++y) {
    for (int x = 0; x < beta.radial.cols; ++x) {
      errors.push_back(mm_per_code *
                       DisparityDistortionCodes(model, beta.radial.at<float>(y, x), beta.pattern.at<float>(y, x), raw));
    }
  }
  return errors;
}

TEST(DisparityDistortionTest, FidelityKinectFixedPatternErrorMatchesARealUnit) {
  const Rig rig = RigPreset("kinect-v1");
  DepthEngine engine(rig.depth_engine);
  struct Row {
    double z_m, real_p5_mm, real_p95_mm;
  };
  // A real Kinect v1's 5th-95th percentiles after its own c0/c1 (joint depth/colour calibration).
  const Row rows[] = {{1.0, -6, 4}, {2.0, -15, 10}, {3.0, -28, 19}};
  std::printf("fixed-pattern error after the chip's c0/c1 (mm), kinect-v1, camera-facing plane\n");
  std::printf("%6s | %12s | %12s | %14s\n", "z (m)", "real p5..p95", "model", "simulated");
  for (const Row& r : rows) {
    const std::vector<double> model = ModelErrorsMm(rig, r.z_m);
    const double model_p5 = Percentile(model, 5), model_p95 = Percentile(model, 95);
    const FixedPattern p = MeasureFixedPattern(rig, &engine, r.z_m, 16);
    std::printf("%6.2f | %5.0f..%+4.0f | %5.1f..%+5.1f | %6.1f..%+5.1f\n", r.z_m, r.real_p5_mm, r.real_p95_mm,
                model_p5, model_p95, p.p5_mm, p.p95_mm);
    // The model: each percentile within 20 % of the real unit's (the fidelity bound).
    EXPECT_NEAR(model_p5, r.real_p5_mm, 0.2 * std::abs(r.real_p5_mm)) << r.z_m << " m";
    EXPECT_NEAR(model_p95, r.real_p95_mm, 0.2 * std::abs(r.real_p95_mm)) << r.z_m << " m";
    // The simulated device: the spread within 20 % of the real one. Its centre also carries the
    // depth engine's own sub-pixel bias (a separate fidelity row), so only the spread is held here.
    const double spread = r.real_p95_mm - r.real_p5_mm;
    EXPECT_NEAR(p.p95_mm - p.p5_mm, spread, 0.2 * spread) << r.z_m << " m";
  }
  // The corners at the far end: up to about 115 mm on the real unit.
  std::vector<double> far = ModelErrorsMm(rig, 3.4);
  for (double& e : far) e = std::abs(e);
  const double model_corner_mm = *std::max_element(far.begin(), far.end());
  const FixedPattern measured = MeasureFixedPattern(rig, &engine, 3.4, 8);
  std::printf("%6.2f | %12s | %12.0f | %14.0f  largest |error| (simulated: 99.9th percentile of pixels)\n", 3.4,
              "up to 115", model_corner_mm, measured.p99_abs_mm);
  EXPECT_NEAR(model_corner_mm, 115.0, 0.2 * 115.0);
  EXPECT_GT(measured.p99_abs_mm, 0.5 * 115.0) << "the simulated corners show the pattern";
  // Without the distortion the stock preset has no such pattern: the model is what makes the row.
  // What is left is the random code noise in the 8-frame mean (about 60 % of the real spread).
  Rig clean = rig;
  clean.depth_engine.disparity_distortion = DisparityDistortion{};
  DepthEngine clean_engine(clean.depth_engine, engine.reference_ir());
  const FixedPattern none = MeasureFixedPattern(clean, &clean_engine, 3.0, 8);
  std::printf("without the distortion at 3 m: %.1f..%+.1f mm\n", none.p5_mm, none.p95_mm);
  EXPECT_LT(none.p95_mm - none.p5_mm, 0.7 * (19 + 28));
}

}  // namespace
}  // namespace romunect
