// Per-pixel depth correction (paper, eqs. 2-3). The robot places the camera at known poses over
// a reference plane; per pixel the true depth comes from intersecting the pixel's ray with the
// plane. Two models are fitted per pixel and both residuals reported:
//   kAffineDepth:      d_true = a(x,y) * d_chip + b(x,y)   (the paper's eq. 3), where d_chip is
//                      the chip's own depth from raw (ChipDepthModel). Approximate: d_chip is a
//                      hyperbola in raw, so over 2 cm it leaves millimetres.
//   kInverseDepthRaw:  1 / d_true = a(x,y) * raw + b(x,y)  (exact for a pinhole camera and
//                      projector: disparity is affine in 1/Z).
// Depth is z in C (metres); raw is the device's CV_16U value (invalid_raw = no measurement).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib {

// The chip's hard-coded raw -> depth formula, a hyperbola: d_chip_m = 1 / (c0 + c1 * raw).
// rig.h's ChipGeometry writes it Z = 8 f b / (raw_offset - raw), so c0 = raw_offset / (8 f b)
// and c1 = -1 / (8 f b); the defaults are its defaults (f 580 px, b 75 mm, offset 1090).
struct ChipDepthModel {
  double c0_per_m = 1090.0 / (8.0 * 580.0 * 0.075);
  double c1_per_m = -1.0 / (8.0 * 580.0 * 0.075);
  int invalid_raw = 2047;
  double DepthM(double raw) const;  // 0 when invalid or non-positive
  // From the chip geometry's focal length, baseline and raw offset.
  static ChipDepthModel FromChip(double focal_times_baseline_px_m, double raw_offset);
};

enum class DepthModelKind { kNone, kAffineDepth, kInverseDepthRaw };
const char* DepthModelKindName(DepthModelKind kind);  // "none", "affine_depth", "inverse_depth_raw"

struct DepthModel {
  DepthModelKind kind = DepthModelKind::kNone;
  cv::Mat a;  // CV_32F, camera size; NaN where the pixel had too few samples
  cv::Mat b;  // CV_32F, camera size
  ChipDepthModel chip;

  // Raw (CV_16U) to metric depth (CV_32F metres, 0 = none): invalid raw, NaN coefficients or
  // a non-positive result give 0. ROMUNECT_CHECKs that raw matches the maps' size.
  cv::Mat Apply(const cv::Mat& raw) const;
  double ApplyPixel(int row, int col, double raw) const;  // same for one pixel
};

// One capture of the reference plane: the plane is z = 0 of frame K, seen from T_C_K.
struct PlaneCapture {
  cv::Mat raw;  // CV_16U, camera size
  Pose T_C_K;
};

struct DepthCorrectionOptions {
  int min_planes = 3;               // per pixel; fewer captures in total: error
  double min_plane_coverage = 0.9;  // fraction of pixels each plane must cover with valid raw
  double min_depth_spread_m = 0.002;  // per pixel, max - min true depth, else the fit is blind
  ChipDepthModel chip;
  std::string Problem() const;
};

struct DepthCorrectionResult {
  DepthModel affine;   // kAffineDepth
  DepthModel inverse;  // kInverseDepthRaw
  double affine_rms_m = 0.0;   // over all fitted samples, depth after correction vs truth
  double inverse_rms_m = 0.0;
  double affine_max_m = 0.0;
  double inverse_max_m = 0.0;
  cv::Mat inverse_residual_rms_m;  // CV_32F per pixel, RMS of the exact model; NaN = unfitted
  cv::Mat affine_residual_rms_m;   // CV_32F per pixel
  int fitted_pixels = 0;
  int unfitted_pixels = 0;
  std::string BriefReport() const;
  // The better of the two by RMS (normally the exact one).
  const DepthModel& Best() const { return inverse_rms_m <= affine_rms_m ? inverse : affine; }
};

// True depth of every pixel for a plane (z = 0 in K) seen from T_C_K: ray-plane intersection,
// CV_32F metres, 0 where the ray misses (parallel or behind).
cv::Mat PlaneDepth(const CameraModel& camera, const Pose& T_C_K);

// Fits both models. Throws InputError (source "depth correction", field "captures[i]") with
// too few captures, a raw image of the wrong size or type, or a plane not covering the image.
DepthCorrectionResult FitDepthCorrection(const CameraModel& camera,
                                         const std::vector<PlaneCapture>& captures,
                                         const DepthCorrectionOptions& options = {});

}  // namespace romunect::calib
