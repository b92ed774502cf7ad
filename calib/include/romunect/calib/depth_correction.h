// Per-pixel depth correction (paper, eqs. 2-3): calib only FITS the sensor model's
// DepthCorrection (sensor/depth_engine.h, which applies it). The robot places the camera at
// known poses over a reference plane; per pixel the true depth comes from intersecting the
// pixel's ray with the plane. Both models are fitted per pixel and both residuals reported:
//   kAffineInChipDepth:  d_true = a(x,y) * d_chip + b(x,y)   (the paper's eq. 3), d_chip the
//                        chip's own depth from raw (ChipDepthM). Approximate: d_chip is a
//                        hyperbola in raw, so over 2 cm it leaves millimetres.
//   kInverseAffineInRaw: 1 / d_true = a(x,y) * raw + b(x,y)  (exact for a pinhole camera and
//                        projector: disparity is affine in 1/Z).
// Depth is z in C (metres); raw is the device's CV_16U value (kRawInvalid = no measurement).
#pragma once

#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/pose.h"
#include "romunect/sensor/rig.h"

namespace romunect::calib {

// The chip whose raw values a calibration reads: the stock Kinect's (f 580 px, b 75 mm,
// raw offset 1090), the kinect-v1 rig preset's.
ChipGeometry StockChipGeometry();

// One capture of the reference plane: the plane is z = 0 of frame K, seen from T_C_K.
struct PlaneCapture {
  cv::Mat raw;  // CV_16U, camera size
  Pose T_C_K;
};

struct DepthCorrectionOptions {
  int min_planes = 3;                       // per pixel; fewer captures in total: error
  double min_plane_coverage = 0.9;          // fraction of pixels each plane must cover with valid raw
  double min_depth_spread_m = 0.002;        // per pixel, max - min true depth, else the fit is blind
  ChipGeometry chip = StockChipGeometry();  // its raw -> depth formula feeds the affine model
  std::string Problem() const;
};

struct DepthCorrectionResult {
  // a and b hold float-rounded values (what the calibration file stores); a pixel is fitted in
  // both or NaN in both.
  DepthCorrection affine;     // kAffineInChipDepth
  DepthCorrection inverse;    // kInverseAffineInRaw
  double affine_rms_m = 0.0;  // over all fitted samples, depth after correction vs truth
  double inverse_rms_m = 0.0;
  double affine_max_m = 0.0;
  double inverse_max_m = 0.0;
  cv::Mat inverse_residual_rms_m;  // CV_32F per pixel, RMS of the exact model; NaN = unfitted
  cv::Mat affine_residual_rms_m;   // CV_32F per pixel
  int fitted_pixels = 0;
  int unfitted_pixels = 0;
  std::string BriefReport() const;
  // The better of the two by RMS (normally the exact one).
  const DepthCorrection& Best() const { return inverse_rms_m <= affine_rms_m ? inverse : affine; }
};

// True depth of every pixel for a plane (z = 0 in K) seen from T_C_K: ray-plane intersection,
// CV_32F metres, 0 where the ray misses (parallel or behind).
cv::Mat PlaneDepth(const CameraModel& camera, const Pose& T_C_K);

// Fits both models. Throws InputError (source "depth correction", field "captures[i]") with
// too few captures, a raw image of the wrong size or type, or a plane not covering the image.
DepthCorrectionResult FitDepthCorrection(const CameraModel& camera, const std::vector<PlaneCapture>& captures,
                                         const DepthCorrectionOptions& options = {});

}  // namespace romunect::calib
