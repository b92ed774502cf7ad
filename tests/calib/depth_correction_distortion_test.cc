// The calibration's per-pixel depth correction fitted on a stock Kinect's realistic errors: the
// kinect-v1 preset carries the real unit's fixed-pattern disparity distortion
// (disparity_distortion.h), which the chip's own c0/c1 leave in; the fit must take it out.
#include <cmath>
#include <cstdio>
#include <vector>

#include <gtest/gtest.h>

#include "romunect/calib/depth_correction.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/ir_synthesis.h"

namespace romunect::calib {
namespace {

struct Residual {
  double rms_mm = 0.0;
  size_t pixels = 0;
  size_t gross = 0;  // beyond 1 % of the depth
};

// Depth (metres, 0 = none) minus the plane's true depth over the pixels valid in both images.
Residual Against(const cv::Mat& depth_m, double z_m, const cv::Mat& mask) {
  double sum2 = 0;
  Residual r;
  for (int y = 0; y < depth_m.rows; ++y) {
    for (int x = 0; x < depth_m.cols; ++x) {
      const float d = depth_m.at<float>(y, x);
      if (d <= 0 || !mask.at<uint8_t>(y, x)) continue;
      if (std::abs(d - z_m) > 0.01 * z_m) {
        ++r.gross;
        continue;
      }
      sum2 += (d - z_m) * (d - z_m);
      ++r.pixels;
    }
  }
  r.rms_mm = r.pixels > 0 ? 1e3 * std::sqrt(sum2 / r.pixels) : -1.0;
  return r;
}

Pose PlanePose(double z_m) { return MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0, 0, z_m)); }

struct Held {
  double z_m = 0.0, step_mm = 0.0;
  Residual before, after;  // the chip's c0/c1; the calibration's per-pixel fit
  cv::Mat chip_m, corrected_m;
};

// RMS (mm) of a - b over the pixels where both are within 1 % of z_m.
double RmsDifferenceMm(const cv::Mat& a, const cv::Mat& b, double z_m) {
  double sum2 = 0;
  size_t n = 0;
  for (int y = 0; y < a.rows; ++y) {
    for (int x = 0; x < a.cols; ++x) {
      const double u = a.at<float>(y, x), v = b.at<float>(y, x);
      if (std::abs(u - z_m) > 0.01 * z_m || std::abs(v - z_m) > 0.01 * z_m) continue;
      sum2 += (u - v) * (u - v);
      ++n;
    }
  }
  return n > 0 ? 1e3 * std::sqrt(sum2 / n) : -1.0;
}

// Fits the calibration's depth correction on one noisy capture of each of 17 planes from 0.8 to
// 2.0 m (the real unit's working range) and measures it on held-out planes between them, new noise.
std::vector<Held> FitAndHoldOut(const Rig& rig) {
  DepthEngine engine(rig.depth_engine);
  IrSynthesizer synthesizer;
  auto capture = [&](double z_m, uint64_t seed) {
    cv::Mat ir;
    synthesizer.Synthesize(rig, FrontoParallelPlane(rig.camera, z_m, IrMaterial{}), seed, &ir, nullptr);
    DepthEngineOutput out;
    engine.Compute(ir, &out);
    return out.raw.clone();
  };
  std::vector<PlaneCapture> captures;
  for (int i = 0; i < 17; ++i) {
    const double z_m = 0.8 + 0.075 * i;
    captures.push_back({capture(z_m, 100 + i), PlanePose(z_m)});
  }
  DepthCorrectionOptions options;
  options.min_plane_coverage = 0.8;  // the stock chip loses its border columns and a few pixels
  const DepthCorrectionResult fit = FitDepthCorrection(rig.camera, captures, options);
  const DepthCorrection identity{DepthCorrectionModel::kAffineInChipDepth, cv::Mat(rig.camera.height, rig.camera.width, CV_64F, cv::Scalar(1.0)),
                                 cv::Mat(rig.camera.height, rig.camera.width, CV_64F, cv::Scalar(0.0))};
  std::vector<Held> held;
  for (const double z_m : {0.91, 1.31, 1.71}) {
    const cv::Mat raw = capture(z_m, 900 + static_cast<int>(z_m * 10));
    const cv::Mat chip = ApplyDepthCorrection(identity, raw, rig.depth_engine.chip);
    const cv::Mat corrected = ApplyDepthCorrection(fit.inverse, raw, rig.depth_engine.chip);
    const cv::Mat both = (chip > 0) & (corrected > 0);
    Held h;
    h.z_m = z_m;
    h.step_mm = 1e3 * z_m * z_m / (8.0 * rig.depth_engine.chip.FocalTimesBaseline());  // one raw code
    h.before = Against(chip, z_m, both);
    h.after = Against(corrected, z_m, both);
    h.chip_m = chip;
    h.corrected_m = corrected;
    held.push_back(h);
  }
  return held;
}

TEST(DepthCorrectionDistortionTest, FitOnTheStockFixedPatternTakesItOut) {
  const Rig rig = RigPreset("kinect-v1");
  ASSERT_TRUE(rig.depth_engine.disparity_distortion.Active());
  Rig clean = rig;
  clean.depth_engine.disparity_distortion = DisparityDistortion{};
  const std::vector<Held> real = FitAndHoldOut(rig), none = FitAndHoldOut(clean);
  std::printf("kinect-v1 depth - ground truth, RMS within 1 %% of the depth (mm) [pixels beyond it];\n"
              "  'pattern': RMS of the depth's change from the distortion (same IR, the chip without it)\n");
  std::printf("%5s | %14s | %14s | %8s | %8s | %8s | %8s\n", "z (m)", "chip c0/c1", "calibrated", "pattern",
              "pattern", "no dist.", "one code");
  std::printf("%5s | %14s | %14s | %8s | %8s | %8s | %8s\n", "", "", "", "chip", "calib.", "calib.", "");
  for (size_t i = 0; i < real.size(); ++i) {
    const Held& h = real[i];
    const double pattern_before = RmsDifferenceMm(h.chip_m, none[i].chip_m, h.z_m);
    const double pattern_after = RmsDifferenceMm(h.corrected_m, none[i].corrected_m, h.z_m);
    std::printf("%5.2f | %6.2f [%5zu] | %6.2f [%5zu] | %8.2f | %8.2f | %8.2f | %8.2f\n", h.z_m, h.before.rms_mm,
                h.before.gross, h.after.rms_mm, h.after.gross, pattern_before, pattern_after, none[i].after.rms_mm,
                h.step_mm);
    ASSERT_GT(h.after.pixels, 250000u) << h.z_m;
    // The fit takes the fixed pattern out: a smaller error against the truth, the corners' gross
    // errors (beyond 1 % of the depth) mostly gone.
    EXPECT_LT(h.after.rms_mm, h.before.rms_mm) << h.z_m << " m";
    EXPECT_LT(h.after.gross, h.before.gross / 2) << h.z_m << " m";
    // The depth's dependence on the distortion falls by a quarter at least: what is left is its
    // curvature in raw (1/Z = a raw + b is affine) and the two fits' own rounding and noise.
    EXPECT_LT(pattern_after, 0.75 * pattern_before) << h.z_m << " m";
    // The calibrated sensor is within 25 % of the same fit on a chip without the distortion: the
    // rest is the chip's rounding, noise and pixel locking, which the fit cannot remove either way.
    EXPECT_LT(h.after.rms_mm, 1.25 * none[i].after.rms_mm) << h.z_m << " m";
    // ... and below one code's depth step.
    EXPECT_LT(h.after.rms_mm, h.step_mm) << h.z_m << " m";
  }
}

}  // namespace
}  // namespace romunect::calib
