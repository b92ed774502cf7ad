// Fidelity of the sensor model (F1-F10, docs/fidelity.md): the simulated device must show the physics and
// the failures of the real one. Geometry comes from the exact analytic back end, so each check
// compares against exact ground truth. Every tolerance is named, with its reason.
#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <optional>
#include <tuple>
#include <vector>

#include <gtest/gtest.h>

#include "analytic_geometry.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/ir_synthesis.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

using testing::AnalyticScene;

struct Shot {
  GeometryBuffer geometry;
  cv::Mat ir, truth;
  DepthEngineOutput out;
};

// One rig and engine per preset for the suite (the chip's reference is rendered once).
struct Device {
  explicit Device(const std::string& preset) : Device(RigPreset(preset)) {}
  explicit Device(Rig r) : rig(std::move(r)), engine(rig.depth_engine) {}
  Shot Capture(const AnalyticScene& scene, uint64_t seed) {
    Shot s;
    s.geometry = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
    s.truth = testing::TruthDepth(s.geometry);
    synth.Synthesize(rig, s.geometry, seed, &s.ir, nullptr);
    engine.Compute(s.ir, &s.out);
    return s;
  }
  Rig rig;
  DepthEngine engine;
  IrSynthesizer synth;
};

Device& Kinect() {
  // Without its fixed-pattern distortion (its own row: disparity_distortion_test.cc).
  static Device device([] {
    Rig rig = RigPreset("kinect-v1");
    rig.depth_engine.disparity_distortion = DisparityDistortion{};
    return rig;
  }());
  return device;
}
Device& Romunect() {
  static Device device("romunect");
  return device;
}

double ValidFraction(const Shot& s) { return static_cast<double>(s.out.stats.valid) / s.ir.total(); }

// Depth change per raw unit near z0_m: least squares of raw against true depth over valid
// pixels within band_m of z0_m (the truth is exact, the noise is in raw: no dilution).
double StepPerRawM(const Shot& s, double z0_m, double band_m) {
  double n = 0, sz = 0, sr = 0, szz = 0, szr = 0;
  for (int y = 0; y < s.ir.rows; ++y) {
    for (int x = 0; x < s.ir.cols; ++x) {
      const uint16_t raw = s.out.raw.at<uint16_t>(y, x);
      const double z = s.truth.at<float>(y, x);
      if (raw == kRawInvalid || std::abs(z - z0_m) > band_m) continue;
      n += 1;
      sz += z;
      sr += raw;
      szz += z * z;
      szr += z * raw;
    }
  }
  EXPECT_GT(n, 1000) << "too few valid pixels near " << z0_m;
  const double slope = (n * szr - sz * sr) / (n * szz - sz * sz);  // raw per metre
  return 1.0 / slope;
}

// ---------------------------------------------------------------------------------------- F1

TEST(FidelityTest, F1_RomunectQuantizationStepIsZSquaredOver8fb) {
  Device& d = Romunect();
  const double fb = d.rig.camera.fx * d.rig.T_C_P.translation().x();
  // Within 5 % of the theoretical step Z^2 / (8 f b).
  constexpr double kStepRelTolerance = 0.05;
  for (double z0 : {0.19, 0.20, 0.21}) {
    const Shot s = d.Capture(AnalyticScene::TiltedPlane(z0, 0.15), 100 + static_cast<int>(z0 * 1000));
    const double expected = z0 * z0 / (8 * fb);
    const double step = StepPerRawM(s, z0, 0.0015);
    EXPECT_NEAR(step, expected, expected * kStepRelTolerance) << "at " << z0 << " m";
    RecordProperty("F1_step_mm_at_" + std::to_string(static_cast<int>(z0 * 1000)) + "mm", std::to_string(step * 1e3));
    std::printf("F1 romunect step at %.0f mm: %.4f mm (Z^2/8fb %.4f mm)\n", z0 * 1e3, step * 1e3, expected * 1e3);
  }
}

// ---------------------------------------------------------------------------------------- F2

TEST(FidelityTest, F2_KinectStepPerRawUnitAndElevenBitRaw) {
  Device& d = Kinect();
  // The Kinect literature's figures; within 10 %.
  constexpr double kStepRelTolerance = 0.10;
  const std::map<double, double> published_step_m = {{0.5, 0.77e-3}, {1.0, 3.1e-3}, {2.0, 12.3e-3}};
  for (const auto& [z0, published] : published_step_m) {
    const Shot s = d.Capture(AnalyticScene::TiltedPlane(z0, 0.3), 200 + static_cast<int>(z0 * 10));
    const double step = StepPerRawM(s, z0, 0.03 * z0);
    EXPECT_NEAR(step, published, published * kStepRelTolerance) << "at " << z0 << " m";
    // The reported depth moves by the same step per raw unit (the chip's own formula).
    const int raw0 = static_cast<int>(std::lround(1090 - 8 * 0.075 * 580 / z0));
    const double reported_step = d.engine.ChipDepthM(raw0 + 1) - d.engine.ChipDepthM(raw0);
    EXPECT_NEAR(reported_step, published, published * kStepRelTolerance);
    std::printf("F2 kinect-v1 step at %.1f m: %.2f mm measured, %.2f mm reported (published %.2f)\n", z0, step * 1e3,
                reported_step * 1e3, published * 1e3);
    for (int y = 0; y < s.ir.rows; ++y) {
      for (int x = 0; x < s.ir.cols; ++x) {
        const uint16_t raw = s.out.raw.at<uint16_t>(y, x);
        ASSERT_LE(raw, 2047);
        ASSERT_EQ(raw == kRawInvalid, s.out.depth_m.at<float>(y, x) == 0.0f);
      }
    }
  }
}

// ---------------------------------------------------------------------------------------- F3

TEST(FidelityTest, F3_KinectNoiseGrowsWithDistanceLikeNguyen2012) {
  Device& d = Kinect();
  // Nguyen, Izadi, Lovell 2012, axial noise of a plane (about 1.2, 1.9, 6.1, 14 mm); within
  // 30 %.
  constexpr double kNoiseRelTolerance = 0.30;
  constexpr double kMaxGrossFraction = 0.01;  // the Kinect has almost no gross outliers
  const std::map<double, double> nguyen_m = {{0.5, 1.2e-3}, {1.0, 1.9e-3}, {2.0, 6.1e-3}, {3.0, 14e-3}};
  for (const auto& [z0, sigma_ref] : nguyen_m) {
    // A plane turned by 0.3 rad, as in their set-up, so quantization is sampled evenly.
    const Shot s = d.Capture(AnalyticScene::TiltedPlane(z0, 0.3), 300 + static_cast<int>(z0 * 10));
    double n = 0, sum = 0, sum2 = 0, gross = 0;
    for (int y = 0; y < s.ir.rows; ++y) {
      for (int x = 0; x < s.ir.cols; ++x) {
        const float z = s.out.depth_m.at<float>(y, x);
        if (z <= 0) continue;
        const double e = z - s.truth.at<float>(y, x);
        if (std::abs(e) > 0.05 * z0) {
          ++gross;
          continue;
        }
        n += 1;
        sum += e;
        sum2 += e * e;
      }
    }
    ASSERT_GT(n, 0.3 * s.ir.total()) << z0;
    const double sigma = std::sqrt(sum2 / n - (sum / n) * (sum / n));
    EXPECT_NEAR(sigma, sigma_ref, sigma_ref * kNoiseRelTolerance) << "at " << z0 << " m";
    EXPECT_LT(gross / (n + gross), kMaxGrossFraction) << z0;
    std::printf("F3 kinect-v1 noise at %.1f m: %.2f mm (Nguyen %.1f), valid %.0f %%\n", z0, sigma * 1e3,
                sigma_ref * 1e3, 100 * ValidFraction(s));
  }
}

// ---------------------------------------------------------------------------------------- F4

TEST(FidelityTest, F4_ProjectorShadowBehindAStepIsAsWideAsTheGeometry) {
  Device& d = Kinect();
  // Background at 1 m, a slab at 0.8 m on the right half (the projector's side).
  const double z_back = 1.0, z_front = 0.8;
  AnalyticScene scene = AnalyticScene::TiltedPlane(z_back, 0.0);
  scene.boxes.push_back({Eigen::Vector3d(0.0, -1, z_front), Eigen::Vector3d(1, 1, z_front + 0.05), 0, 2});
  const Shot s = d.Capture(scene, 400);
  const double expected_px = d.rig.camera.fx * 0.075 * (1 / z_front - 1 / z_back);  // f b (1/Z1 - 1/Z2)
  // The shadow, invalid pixels left of the edge (column 319.5), per row.
  std::vector<int> widths;
  for (int y = 40; y < s.ir.rows - 40; ++y) {
    int w = 0;
    for (int x = 280; x < 340; ++x) w += s.out.raw.at<uint16_t>(y, x) == kRawInvalid;
    widths.push_back(w);
  }
  std::nth_element(widths.begin(), widths.begin() + widths.size() / 2, widths.end());
  const int median = widths[widths.size() / 2];
  // Within 1 px of the geometric width.
  constexpr double kShadowWidthTolerancePx = 1.0;
  EXPECT_NEAR(median, expected_px, kShadowWidthTolerancePx);
  // On the side away from the projector: the band lies left of the edge.
  int left = 0, right = 0;
  for (int y = 40; y < s.ir.rows - 40; ++y) {
    for (int x = 280; x < 340; ++x) {
      if (s.out.raw.at<uint16_t>(y, x) == kRawInvalid) (x < 320 ? left : right)++;
    }
  }
  EXPECT_GT(left, 4 * right);
  std::printf("F4 shadow band: %d px measured (median row), %.2f px geometric\n", median, expected_px);
}

// ---------------------------------------------------------------------------------------- F5

TEST(FidelityTest, F5_WindowFattensEdgesByAtMostHalfAWindowAndMissesAOnePixelRidge) {
  Device& d = Kinect();
  const double z_back = 1.0, z_front = 0.8;
  // Slab on the left: its right edge (column 320) has no visible shadow, only the window.
  AnalyticScene scene = AnalyticScene::TiltedPlane(z_back, 0.0);
  scene.boxes.push_back({Eigen::Vector3d(-1, -1, z_front), Eigen::Vector3d(0.0, 1, z_front + 0.05), 0, 2});
  const Shot s = d.Capture(scene, 500);
  const double half_window_px = d.rig.depth_engine.window_px / 2.0;
  int worst = 0;
  std::vector<int> fattening;
  for (int y = 40; y < s.ir.rows - 40; ++y) {
    int f = 0;
    for (int x = 320; x < 360; ++x) {  // background pixels that report the foreground
      const float z = s.out.depth_m.at<float>(y, x);
      f += z > 0 && std::abs(z - z_front) < std::abs(z - z_back);
    }
    fattening.push_back(f);
    worst = std::max(worst, f);
  }
  std::nth_element(fattening.begin(), fattening.begin() + fattening.size() / 2, fattening.end());
  const int median = fattening[fattening.size() / 2];
  EXPECT_LE(worst, half_window_px);
  EXPECT_GE(worst, 1);  // the window does fatten: it comes out of the matching
  std::printf("F5 foreground fattening: median %d px, worst %d px (half window %.1f)\n", median, worst, half_window_px);

  // A ridge one pixel wide at 0.9 m in front of the 1 m plane.
  const double z_ridge = 0.9;
  const double w_m = z_ridge / d.rig.camera.fx;
  AnalyticScene ridge = AnalyticScene::TiltedPlane(z_back, 0.0);
  ridge.boxes.push_back(
      {Eigen::Vector3d(-0.5 * w_m, -1, z_ridge), Eigen::Vector3d(0.5 * w_m, 1, z_ridge + 0.01), 0, 3});
  const Shot r = d.Capture(ridge, 501);
  int ridge_pixels = 0, resolved = 0;
  for (int y = 40; y < r.ir.rows - 40; ++y) {
    for (int x = 300; x < 340; ++x) {
      if (r.geometry.layers[0].object_id.at<int>(y, x) != 3) continue;
      ++ridge_pixels;
      const float z = r.out.depth_m.at<float>(y, x);
      resolved += z > 0 && std::abs(z - z_ridge) < 0.25 * (z_back - z_ridge);
    }
  }
  ASSERT_GT(ridge_pixels, 300);
  constexpr double kMaxResolvedFraction = 0.1;  // "not resolved": at most a stray tenth
  EXPECT_LT(resolved, kMaxResolvedFraction * ridge_pixels);
  std::printf("F5 1-px ridge: %d of %d ridge pixels report the ridge\n", resolved, ridge_pixels);
}

// ---------------------------------------------------------------------------------------- F6

TEST(FidelityTest, F6_RomunectSingleScanReachesATenthOfAMillimetreInItsFocusedRange) {
  Device& d = Romunect();
  std::vector<DepthEngineOutput> outputs;
  std::vector<cv::Mat> truths;
  uint64_t seed = 600;
  for (double z : {0.19, 0.1925, 0.195, 0.1975, 0.20, 0.2025, 0.205, 0.2075, 0.21}) {
    const Shot s = d.Capture(AnalyticScene::TiltedPlane(z, 0.04), seed++);
    outputs.push_back(s.out);
    truths.push_back(s.truth);
  }
  // A pixel is calibrated when at least 5 of the 9 planes measured it (fewer extrapolate).
  constexpr int kMinCalibrationSamples = 5;
  const DepthCorrection correction = FitDepthCorrection(DepthCorrectionModel::kInverseAffineInRaw, outputs, truths,
                                                        kMinCalibrationSamples);
  const DepthCorrection affine = FitDepthCorrection(DepthCorrectionModel::kAffineInChipDepth, outputs, truths,
                                                    kMinCalibrationSamples);
  constexpr double kPaperRmsM = 0.1e-3;  // the paper's single-scan accuracy
  for (double z : {0.193, 0.2, 0.207}) {
    const Shot s = d.Capture(AnalyticScene::TiltedPlane(z, -0.04), seed++);
    for (const auto* c : {&correction, &affine}) {
      const cv::Mat metric = ApplyDepthCorrection(*c, s.out);
      double n = 0, sum2 = 0;
      for (int y = 0; y < metric.rows; ++y) {
        for (int x = 0; x < metric.cols; ++x) {
          const float m = metric.at<float>(y, x);
          if (m <= 0) continue;
          const double e = m - s.truth.at<float>(y, x);
          n += 1;
          sum2 += e * e;
        }
      }
      ASSERT_GT(n, 0.3 * metric.total()) << z;
      const double rms = std::sqrt(sum2 / n);
      if (c == &correction) {
        EXPECT_LE(rms, kPaperRmsM) << "at " << z;
      }
      std::printf("F6 romunect at %.0f mm, %s: RMS %.4f mm over %.0f %% of pixels\n", z * 1e3,
                  DepthCorrectionModelName(c->model), rms * 1e3, 100 * n / metric.total());
    }
  }
  // Outside the focused range the projector's blur kills the correlation.
  const double in_focus = ValidFraction(d.Capture(AnalyticScene::TiltedPlane(0.2, 0.0), 650));
  for (double z : {0.18, 0.225}) {
    const double valid = ValidFraction(d.Capture(AnalyticScene::TiltedPlane(z, 0.0), 651));
    EXPECT_LT(valid, 0.5 * in_focus) << z;
    std::printf("F6 valid fraction at %.0f mm: %.2f (at 200 mm %.2f)\n", z * 1e3, valid, in_focus);
  }
}

// ---------------------------------------------------------------------------------------- F7

TEST(FidelityTest, F7_DarkAndShinySurfacesGiveHoles) {
  Device& d = Romunect();
  const double white = ValidFraction(d.Capture(AnalyticScene::TiltedPlane(0.2, 0.0, IrMaterial{0.5f, 0, 50}), 700));
  const double dark = ValidFraction(d.Capture(AnalyticScene::TiltedPlane(0.2, 0.0, IrMaterial{0.05f, 0, 50}), 701));
  EXPECT_LT(dark, 0.5 * white);  // holes: at least half the measurements lost
  std::printf("F7 valid fraction: albedo 0.5 %.2f, albedo 0.05 %.2f\n", white, dark);
  // A shiny plane turned to mirror the projector into the camera at the image centre.
  const Eigen::Vector3d p(0, 0, 0.2);
  const Eigen::Vector3d n = ((d.rig.T_C_P.translation() - p).normalized() + (-p).normalized()).normalized();
  AnalyticScene shiny;
  shiny.materials = {IrMaterial{0.3f, 1.0f, 200.0f}};
  shiny.planes.push_back({p, n, 0, 1});
  const Shot s = d.Capture(shiny, 702);
  const int max_dn = std::lround(d.rig.optics.full_well_e * d.rig.optics.gain_dn_per_e);
  int saturated = 0, saturated_holes = 0;
  for (int y = 0; y < s.ir.rows; ++y) {
    for (int x = 0; x < s.ir.cols; ++x) {
      // Inside the saturated patch: the pixel and its neighbours all clipped.
      if (y < 2 || x < 2 || y >= s.ir.rows - 2 || x >= s.ir.cols - 2) continue;
      double lo;
      cv::minMaxLoc(s.ir(cv::Rect(x - 2, y - 2, 5, 5)), &lo, nullptr);
      if (lo < max_dn) continue;
      ++saturated;
      saturated_holes += s.out.raw.at<uint16_t>(y, x) == kRawInvalid;
    }
  }
  ASSERT_GT(saturated, 500);
  constexpr double kMinHoleFraction = 0.95;  // a saturated patch has no pattern left to match
  EXPECT_GT(saturated_holes, kMinHoleFraction * saturated);
  std::printf("F7 saturated specular patch: %d px, %d invalid\n", saturated, saturated_holes);
}

// ---------------------------------------------------------------------------------------- F8

TEST(FidelityTest, F8_SameSeedSameBytesAtOneAndTwoThreads) {
  const Rig rig = RigPreset("romunect");
  AnalyticScene scene = AnalyticScene::TiltedPlane(0.205, 0.1);
  scene.spheres.push_back({Eigen::Vector3d(0.005, 0.0, 0.2), 0.01, 0, 2});
  const GeometryBuffer g = testing::RenderAnalytic(scene, rig.camera, rig.T_C_P.translation());
  cv::Mat ir_reference;
  DepthEngineOutput out_reference;
  for (int threads : {1, 2}) {
    IrSynthesisOptions so;
    so.threads = threads;
    IrSynthesizer synth(so);
    DepthEngineOptions eo = rig.depth_engine;
    eo.threads = threads;
    DepthEngine engine(eo, Romunect().engine.reference_ir());
    for (int repeat = 0; repeat < 2; ++repeat) {
      cv::Mat ir;
      DepthEngineOutput out;
      synth.Synthesize(rig, g, 77, &ir, nullptr);
      engine.Compute(ir, &out);
      if (ir_reference.empty()) {
        ir_reference = ir.clone();
        out_reference = out;
        continue;
      }
      EXPECT_TRUE(testing::ImagesBitEqual(ir, ir_reference)) << threads;
      EXPECT_TRUE(testing::ImagesBitEqual(out.raw, out_reference.raw)) << threads;
      EXPECT_TRUE(testing::ImagesBitEqual(out.depth_m, out_reference.depth_m)) << threads;
    }
  }
  EXPECT_GT(out_reference.stats.valid, 0);
}

// ---------------------------------------------------------------------------------------- F9

// The true shift (px) of pixel (x, y) seen at true depth z_m: the camera column minus the
// column where the chip's reference shows the same pattern point (through the projector, the
// pre-warp and the chip's geometry); NaN when the point is outside the projector's view.
double TrueShiftPx(const Rig& rig, int x, int y, double z_m) {
  const Eigen::Vector3d p_C = rig.camera.Unproject(Eigen::Vector2d(x, y), z_m);
  const std::optional<Eigen::Vector2d> p_P = rig.projector.Project(rig.T_C_P.inverse() * p_C);
  if (!p_P) return std::nan("");
  const Eigen::Vector3d pattern = rig.H_P_rec.inverse() * p_P->homogeneous();
  const ChipGeometry& chip = rig.depth_engine.chip;
  const double ray_x = (pattern.x() / pattern.z() - chip.projector.cx) / chip.projector.fx;
  const double z_ref = chip.reference_distance_m;
  return x - (chip.camera.fx * (ray_x * z_ref + chip.baseline_m) / z_ref + chip.camera.cx);
}

int PhaseOfEighths(long eighths) { return static_cast<int>((eighths % 8 + 8) % 8); }

// Counts per 1/8-px phase (0: whole pixels, 4: half pixels): of the valid codes, and of the true
// shifts of every pixel the window fits around.
void CountPhases(const Device& d, const Shot& s, std::array<double, 8>* codes, std::array<double, 8>* truth) {
  const long raw_at_reference = std::lround(d.engine.RawAtReference());
  const int r = d.rig.depth_engine.window_px / 2;
  for (int y = r; y < s.ir.rows - r; ++y) {
    for (int x = r; x < s.ir.cols - r; ++x) {
      const uint16_t raw = s.out.raw.at<uint16_t>(y, x);
      if (raw != kRawInvalid) (*codes)[PhaseOfEighths(raw_at_reference - raw)] += 1;
      const double z = s.truth.at<float>(y, x);
      const double shift = z > 0 ? TrueShiftPx(d.rig, x, y, z) : std::nan("");
      if (std::isfinite(shift)) (*truth)[PhaseOfEighths(std::lround(std::floor(8 * shift + 0.5)))] += 1;
    }
  }
}

// The real chip's codes on a tilted plane fall evenly on the eight phases (within 4 %); a
// parabola through sums of absolute differences put 65 % too many on whole pixels. Each
// preset's sub-pixel fit is calibrated in its working range. At each depth, tilted planes whose
// shifts at the image centre step through one pixel in eighths; each phase's share of the codes
// is divided by its share of the planes' true shifts, so that what the planes sample unevenly
// (their ends) does not count.
TEST(FidelityTest, F9_SubPixelCodesSpreadEvenlyOverTheEighthPixelPhases) {
  // The real chip's 4 %, and the planes' random codes (about 1 %).
  constexpr double kPhaseTolerance = 0.05;
  constexpr int kPlanes = 8;  // per tilt
  for (auto [name, device, z0, tilt] : {std::tuple{"kinect-v1", &Kinect(), 0.6, 0.3},
                                        std::tuple{"kinect-v1", &Kinect(), 1.0, 0.3},
                                        std::tuple{"kinect-v1", &Kinect(), 2.0, 0.3},
                                        std::tuple{"kinect-v1", &Kinect(), 3.0, 0.3},
                                        std::tuple{"romunect", &Romunect(), 0.193, 0.04},
                                        std::tuple{"romunect", &Romunect(), 0.2, 0.04},
                                        std::tuple{"romunect", &Romunect(), 0.207, 0.04}}) {
    const double focal_baseline = device->rig.camera.fx * device->rig.T_C_P.translation().norm();  // px m
    std::array<double, 8> codes{}, truth{};
    uint64_t seed = 900;
    for (int k = 0; k < kPlanes; ++k) {
      const double z = 1 / (1 / z0 + ((k + 0.5) / kPlanes - 0.5) / focal_baseline);
      for (double sign : {-1.0, 1.0}) {
        CountPhases(*device, device->Capture(AnalyticScene::TiltedPlane(z, sign * tilt), seed++), &codes, &truth);
      }
    }
    double n_codes = 0, n_truth = 0;
    for (int k = 0; k < 8; ++k) {
      n_codes += codes[k];
      n_truth += truth[k];
    }
    std::printf("F9 %s at %.3f m, share of codes per phase 0..7 (1 = even):", name, z0);
    for (int k = 0; k < 8; ++k) {
      const double share = (codes[k] / n_codes) / (truth[k] / n_truth);
      std::printf(" %.3f", share);
      EXPECT_NEAR(share, 1.0, kPhaseTolerance) << name << " at " << z0 << " phase " << k;
    }
    std::printf("\n");
  }
}

// ---------------------------------------------------------------------------------------- F10

// A camera-facing plane's pixels in a region, valid and within 5 % of the truth (the rest are
// gross errors): depth and raw about their best-fit planes, the mean error.
struct PlaneFit {
  double rms_m = 0;
  double code_rms = 0;
  double bias_codes = 0;  // mean error in raw units
  double valid = 0;       // share of the region
};

PlaneFit FitCameraFacingPlane(const Device& d, const Shot& s, double z0, const cv::Rect& region) {
  std::vector<Eigen::Vector3d> xy1;
  std::vector<double> depth, raw, error;
  for (int y = region.y; y < region.br().y; ++y) {
    for (int x = region.x; x < region.br().x; ++x) {
      const double z = s.out.depth_m.at<float>(y, x), truth = s.truth.at<float>(y, x);
      if (z <= 0 || std::abs(z - truth) > 0.05 * z0) continue;
      xy1.emplace_back(x, y, 1);
      depth.push_back(z);
      raw.push_back(s.out.raw.at<uint16_t>(y, x));
      error.push_back(z - truth);
    }
  }
  PlaneFit fit;
  fit.valid = static_cast<double>(xy1.size()) / region.area();
  if (xy1.size() < 1000) return fit;
  const auto rms_about_plane = [&](const std::vector<double>& v) {
    Eigen::Matrix3d A = Eigen::Matrix3d::Zero();
    Eigen::Vector3d b = Eigen::Vector3d::Zero();
    for (size_t i = 0; i < v.size(); ++i) {
      A += xy1[i] * xy1[i].transpose();
      b += xy1[i] * v[i];
    }
    const Eigen::Vector3d p = A.ldlt().solve(b);
    double sum2 = 0;
    for (size_t i = 0; i < v.size(); ++i) sum2 += std::pow(v[i] - p.dot(xy1[i]), 2);
    return std::sqrt(sum2 / v.size());
  };
  fit.rms_m = rms_about_plane(depth);
  fit.code_rms = rms_about_plane(raw);
  double mean_error = 0;
  for (double e : error) mean_error += e / error.size();
  const double step_m = z0 * z0 / (8.0 * d.rig.depth_engine.chip.FocalTimesBaseline());
  fit.bias_codes = mean_error / step_m;
  return fit;
}

// Camera-facing planes against a real Kinect v1 (walls and boards, 0.56-3.4 m): the plane-fit
// RMS over the image's central half (the unit's own fixed pattern included), the random code
// noise and bias (without it), the share of valid pixels, and the range.
TEST(FidelityTest, F10_CameraFacingPlanesHaveTheRealSensorsNoiseAndRange) {
  static Device full("kinect-v1");
  const cv::Rect centre(160, 120, 320, 240), image(0, 0, 640, 480);
  constexpr double kFidelityRelTolerance = 0.20;  // the fidelity bound
  struct Row {
    double z_m, real_rms_mm;
  };
  const Row rows[] = {{1.0, 1.97}, {1.5, 4.82}, {2.05, 9.48}, {3.05, 17.5}};
  std::printf("F10 kinect-v1 camera-facing plane | plane-fit RMS (real) | code noise, bias (raw units)\n");
  uint64_t seed = 1000;
  for (const Row& r : rows) {
    const PlaneFit f = FitCameraFacingPlane(full, full.Capture(AnalyticScene::TiltedPlane(r.z_m, 0.0), seed), r.z_m,
                                            centre);
    const PlaneFit g = FitCameraFacingPlane(
        Kinect(), Kinect().Capture(AnalyticScene::TiltedPlane(r.z_m, 0.0), seed++), r.z_m, image);
    std::printf("F10 %.2f m | %.2f mm (%.2f) | %.2f, %+.2f\n", r.z_m, f.rms_m * 1e3, r.real_rms_mm, g.code_rms,
                g.bias_codes);
    EXPECT_NEAR(f.rms_m * 1e3, r.real_rms_mm, kFidelityRelTolerance * r.real_rms_mm) << r.z_m << " m";
    // The real unit's random part: 0.5-0.6 raw units at any depth, within 20 %.
    EXPECT_GE(g.code_rms, 0.5 * (1 - kFidelityRelTolerance)) << r.z_m << " m";
    EXPECT_LE(g.code_rms, 0.6 * (1 + kFidelityRelTolerance)) << r.z_m << " m";
    constexpr double kMaxBiasCodes = 0.2;  // no bias: a fifth of a code (the fit's own error)
    EXPECT_LT(std::abs(g.bias_codes), kMaxBiasCodes) << r.z_m << " m";
  }
  // A real unit keeps a plane whole from 0.56 to 3.4 m but for its 8 right-hand columns.
  constexpr double kMaxInvalidInside = 0.01;  // a hundredth of the plane: stray rejections
  constexpr double kMaxInvalidInsideNearest = 0.03;  // at 0.55 m, the near end, the dots blur
  const int searched = image.width - kChipBorderColumns;
  for (double z : {0.55, 0.56, 0.6, 0.8, 1.0, 1.5, 2.0, 2.5, 3.0, 3.4}) {
    const Shot s = full.Capture(AnalyticScene::TiltedPlane(z, 0.0), seed++);
    const double invalid_inside =
        1.0 - cv::countNonZero(s.out.depth_m.colRange(0, searched) > 0) / static_cast<double>(searched * image.height);
    std::printf("F10 valid at %.2f m: %.1f %% (invalid but the right-hand columns: %.2f %%)\n", z,
                100 * ValidFraction(s), 100 * invalid_inside);
    EXPECT_LE(invalid_inside, z < 0.56 ? kMaxInvalidInsideNearest : kMaxInvalidInside) << z << " m";
    EXPECT_EQ(cv::countNonZero(s.out.depth_m.colRange(searched, image.width) > 0), 0) << z << " m";
  }
  // Depth to 6 m and beyond (real: codes up to 1041, 6.7 m).
  const Shot far = full.Capture(AnalyticScene::TiltedPlane(6.0, 0.0), seed++);
  double max_depth = 0;
  cv::minMaxLoc(far.out.depth_m, nullptr, &max_depth);
  std::printf("F10 at 6 m: %.1f %% valid, depth up to %.2f m\n", 100 * ValidFraction(far), max_depth);
  EXPECT_GT(ValidFraction(far), 0.5);
  EXPECT_GE(max_depth, 6.0);
}

}  // namespace
}  // namespace romunect
