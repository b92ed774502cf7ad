// The depth chip's fixed-pattern disparity error: what a real unit shows after its own
// raw-to-depth mapping, largest in the image corners (the lens distortion of the IR camera and
// projector against the chip's stored reference). The model is the published one of Herrera,
// Kannala and Heikkilae (joint depth and colour camera calibration): a pixel whose undistorted raw
// value would be d reports
//   d_measured = d + beta(u, v) * exp(alpha0 - alpha1 * d)          (raw codes, 1/8 px)
// so the error in codes shrinks with depth while the error in metres grows. The engine adds it
// before rounding to the chip's 1/8-px codes (depth_engine.h), as the real chip does.
//
// beta(u, v) is a smooth seeded map in two parts, both of zero mean over the image (a unit's
// c0/c1 absorb the mean): a radial term that reaches corner_codes in the corners, and a random
// field of RMS pattern_rms_codes with features about pattern_scale_px across. The random part
// may decay at its own rate, exp(pattern_alpha0 - pattern_alpha1 d): on a real unit the corners
// fade with depth while the fine pattern keeps its size in codes (the plane-fit RMS of a
// camera-facing plane's centre, 0.4-0.6 codes beyond the random noise at 1-3 m). Amplitudes are
// raw codes at the factor 1.
#pragma once

#include <cstdint>
#include <string>

#include <opencv2/core.hpp>

#include "romunect/sensor/errors.h"

namespace romunect {

struct DisparityDistortion {
  uint64_t seed = 1;
  double alpha0 = 0.0;             // exp(alpha0 - alpha1 d): alpha0 sets the raw code where it is 1
  double alpha1 = 0.0;             // per raw code, >= 0: the decay with depth
  double pattern_rms_codes = 0.0;  // RMS of beta's random part
  double pattern_scale_px = 80.0;  // size of its features (Gaussian correlation length)
  double corner_codes = 0.0;       // beta's radial part in the corners (its sign: depth too far)
  // The random part's factor exp(pattern_alpha0 - pattern_alpha1 d); the published model's single
  // factor when equal to alpha0, alpha1 (what a rig file without them gets).
  double pattern_alpha0 = 0.0;
  double pattern_alpha1 = 0.0;  // per raw code, >= 0

  // On at all: a model with both amplitudes 0 changes nothing (the default).
  bool Active() const { return pattern_rms_codes != 0.0 || corner_codes != 0.0; }
  // A bound on the distortion over raw codes d >= min_raw (4 x the RMS for the random part); the
  // depth engine's options hold it to 64 codes (8 px) over their search.
  double WorstCaseCodes(double min_raw) const;
  std::string Problem() const { return Check().ToString(); }
  FieldProblem Check() const;
  bool operator==(const DisparityDistortion&) const = default;
};

// The distortion of the stock Kinect v1 the kinect-v1 preset carries: with the chip's own
// c0/c1, -6..+4 mm at 1 m, -15..+10 mm at 2 m, -28..+19 mm at 3 m (5th-95th percentile over the
// image) and about 115 mm in the corners at 3.4 m, as measured on a real unit.
DisparityDistortion KinectV1DisparityDistortion();

// beta(u, v)'s two parts for a width x height image (CV_32F, raw codes at the factor 1); all
// zeros when not Active().
struct DisparityDistortionMaps {
  cv::Mat radial;   // factor exp(alpha0 - alpha1 d)
  cv::Mat pattern;  // factor exp(pattern_alpha0 - pattern_alpha1 d)
};
DisparityDistortionMaps DisparityDistortionBeta(const DisparityDistortion& model, int width, int height);

// The distortion in raw codes of a pixel with those parts of beta at undistorted raw value `raw`.
double DisparityDistortionCodes(const DisparityDistortion& model, double radial_beta, double pattern_beta, double raw);

}  // namespace romunect
