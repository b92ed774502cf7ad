// The projector-camera rig: everything optical about the sensor, in one value loaded once.
// Frames (frames.h): C the camera, P the projector (OpenCV axes). T_C_P maps projector points
// into the camera frame. Units SI; pixels with centres at integer coordinates.
//
// Defocus uses the thin-lens circle of confusion seen from the lens, in pixels:
//   coc_px(Z) = f_px * aperture_m * |1/Z - 1/Z_focus|
// (exact for the angular blur of a thin lens; Z is the distance along the optical axis).
//
// Radiometry, in camera electrons (a white Lambertian surface facing the projector at 1 m,
// pattern value 1, gives projector.brightness_e_per_s electrons per second in a camera pixel):
//   e = exposure_s * (brightness_e_per_s * pattern * pi*BRDF * cos(theta_in) / d_P_m^2
//                     + ambient_e_per_s * albedo)
//   DN = round(gain_dn_per_e * min(e + shot + read noise, full_well_e)), clipped to 10 bits.
#pragma once

#include <cstdint>
#include <filesystem>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/disparity_distortion.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/pose.h"

namespace romunect {

// A pinhole projector (no distortion) with a thin lens of finite aperture.
struct ProjectorModel {
  int width = 792;  // projector image size, px
  int height = 594;
  double fx = 580.0, fy = 580.0;      // focal lengths, px
  double cx = 395.5, cy = 296.5;      // principal point, px
  double focus_distance_m = 2.0;      // distance (along its axis) where the pattern is sharp
  double aperture_m = 0.002;          // lens aperture diameter; 0 = pinhole (always sharp)
  double brightness_e_per_s = 1.0e6;  // see the radiometry note above

  // Why the model is unusable, or "" when valid: Check().ToString().
  std::string Problem() const;
  // The same as structure: the field at fault and the rule it breaks (empty when valid).
  FieldProblem Check() const;
  // Circle-of-confusion diameter in projector pixels at distance depth_m (z in P).
  double CircleOfConfusionPx(double depth_m) const;
  // Projector pixel of a point in P; nullopt behind the projector. May be off the image.
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& p_P) const;
  cv::Matx33d Matrix() const;

  bool operator==(const ProjectorModel&) const = default;
};

// The camera's C-mount lens and sensor electronics (the geometry is CameraModel).
struct CameraOptics {
  double focus_distance_m = 1.2;  // z where the image is sharp
  double aperture_m = 0.001;      // aperture diameter (defocus); 0 = pinhole
  double psf_sigma_px = 0.7;      // blur of the focused lens and pixel, Gaussian sigma
  double exposure_s = 0.03;
  double gain_dn_per_e = 0.25;      // digital numbers per electron
  double full_well_e = 4000.0;      // electrons where a pixel saturates
  double read_noise_e = 6.0;        // read noise, electrons RMS
  bool shot_noise = true;           // photon (Poisson) noise, Gaussian approximation
  // Laser speckle: multiplicative noise of this contrast (standard deviation over mean) in each
  // pixel and frame, the same on any surface and at any angle; 0 for incoherent light (LED/DLP).
  // JSON: optional (absent: 0).
  double speckle_contrast = 0.0;
  int bits = 10;                    // quantization: output in [0, 2^bits - 1]
  double ambient_e_per_s = 2000.0;  // ambient IR on a white surface, electrons per second

  std::string Problem() const;
  FieldProblem Check() const;
  double CircleOfConfusionPx(const CameraModel& camera, double depth_m) const;
  int MaxDn() const { return (1 << bits) - 1; }

  bool operator==(const CameraOptics&) const = default;
};

// What the projector shows. Pattern images are CV_32F in [0, 1] of width x height; the
// projector displays them warped by the rig's H_P_rec (pattern.h).
enum class PatternKind {
  kKinectDots,    // pseudo-random dots from `seed`: 3 x 3 tiles, each with a bright centre
  kDotGrid,       // regular dots every `pitch_px`, intensity modulated (seeded) in [min_level, 1]
  kFeatureGrid,   // calibration: round feature points every `pitch_px`, radius pitch/6
  kCheckerboard,  // calibration: squares of `pitch_px`
  kUniform,       // uniform light at level 1
  kOff,           // switched off
};
const char* PatternKindName(PatternKind kind);
std::optional<PatternKind> PatternKindFromName(const std::string& name);

struct PatternSpec {
  PatternKind kind = PatternKind::kKinectDots;
  int width = 792;  // pattern image size, px; Kinect dots need multiples of 3
  int height = 594;
  uint64_t seed = 1;
  double dot_fill = 0.11;          // Kinect dots: share of lit pixels
  double centre_spot_level = 1.0;  // Kinect dots: centre spot value (dots are dot_level)
  double dot_level = 0.6;          // Kinect dots: value of an ordinary dot
  int pitch_px = 8;                // grids and checkerboard
  double min_level = 0.3;          // dot grid: lowest modulation level

  std::string Problem() const;
  FieldProblem Check() const;
  bool operator==(const PatternSpec&) const = default;
};

// The PrimeSense chip's hard-coded geometry (Konolige and Mihelich): the stock IR camera and
// laser projector with parallel axes, the projector centre at (+baseline_m, 0, 0) in C, and a
// reference image of the Kinect pattern on a plane at reference_distance_m stored in the chip.
// Raw values follow Z = 8 f b / (raw_offset - raw) (depth_engine.h documents raw depth).
struct ChipGeometry {
  CameraModel camera;        // stock IR camera: 640 x 480, f = 580 px
  ProjectorModel projector;  // stock laser projector (its pattern frame); aperture ~0
  PatternSpec pattern;       // the Kinect pattern burnt into the DOE (kind kKinectDots)
  double baseline_m = 0.075;
  double reference_distance_m = 1.0;
  double raw_offset = 1090.0;  // raw value at zero disparity (infinite depth), "doff"

  std::string Problem() const;
  FieldProblem Check() const;
  double FocalTimesBaseline() const { return camera.fx * baseline_m; }  // px m
  bool operator==(const ChipGeometry&) const = default;
};

struct DepthEngineOptions {
  ChipGeometry chip;
  int window_px = 9;       // correlation window, odd
  int min_shift_px = -32;  // search along the row: shifts [min, min + range) vs reference
  int search_range_px = 64;
  int subpixel_steps = 8;    // 1/8 px
  // The sub-pixel fit through the best integer shift's cost and its neighbours', calibrated so
  // that codes fall evenly on the eight 1/8-px phases, as the real chip's do (docs/fidelity.md):
  // this weight on the equiangular (V) fit, the rest on the parabola (a parabola on sums of
  // absolute differences pulls codes to whole pixels, a V to half pixels), then the offset u
  // from the nearest half pixel moved by -correction u (1 - 16 u^2), which spreads codes
  // from the quarter pixels to the whole and half ones, and the offset v from the nearest
  // quarter pixel by -eighth_correction v (1 - 64 v^2), which moves codes from the odd
  // eighths to the even ones (both monotone). The V's weight falls by subpixel_rounding_slope
  // times c0 / a, clamped to [0, 1], for the best cost c0 and its rise a to the higher of its
  // neighbours: camera defocus (near) and faint, noisy dots (far) lift and round the cost's
  // minimum, and a rounded minimum is nearer a parabola. JSON: each optional (absent: 1, 0, 0, 0).
  double subpixel_equiangular_weight = 1.0;
  double subpixel_rounding_slope = 0.0;
  double subpixel_quarter_correction = 0.0;
  double subpixel_eighth_correction = 0.0;
  double min_texture = 6.0;  // mean |prefiltered| in the window below this: flat -> invalid
  double max_cost = 25.0;    // mean |difference| per pixel above this: weak -> invalid
  double uniqueness = 0.20;  // second best (>1 px away) within this fraction: ambiguous
  int prefilter_px = 9;      // local-mean removal window (odd), as the chip normalizes
  int threads = 1;
  // The chip's fixed-pattern disparity error (disparity_distortion.h), added before rounding to
  // codes; none by default. JSON: optional "disparity_distortion" (absent: none).
  DisparityDistortion disparity_distortion;

  std::string Problem() const;
  FieldProblem Check() const;
  bool operator==(const DepthEngineOptions&) const = default;
};

struct Rig {
  std::string name = "custom";
  CameraModel camera;
  CameraOptics optics;
  ProjectorModel projector;
  Pose T_C_P = Pose::Identity();  // projector pose in the camera frame
  PatternSpec pattern;
  // Pre-warp: maps pattern pixels to projector pixels (x_P ~ H_P_rec * x_pattern).
  Eigen::Matrix3d H_P_rec = Eigen::Matrix3d::Identity();
  DepthEngineOptions depth_engine;
  double frame_rate_hz = 30.0;

  // Why the rig is unusable, or "" when valid: "field: problem" (Check().ToString()).
  std::string Problem() const;
  FieldProblem Check() const;
  Eigen::Vector3d ProjectorCentre_C() const { return T_C_P.translation(); }
};

// The built-in rigs: "romunect" (the paper's modified device: 200 mm working distance, about
// 6 x 4.5 cm field of view there, ~2 cm focused depth range, 5 cm baseline, toed-in DLP
// projector, H_P_rec from IdealPrewarp) and "kinect-v1" (the stock device). Throws InputError
// for another name.
Rig RigPreset(const std::string& name);

// The pre-warp that makes the projected pattern, seen by the camera on a fronto-parallel
// plane at plane_distance_m, land where the chip's reference image has it (zero shift).
// Ignores lens distortion (the per-pixel depth correction absorbs what is left).
Eigen::Matrix3d IdealPrewarp(const Rig& rig, double plane_distance_m);

// JSON rig files. LoadRig validates everything and throws InputError naming the file and the
// field; SaveRig writes atomically. SaveRig then LoadRig gives back an equal rig.
Rig LoadRig(const std::filesystem::path& path);
void SaveRig(const std::filesystem::path& path, const Rig& rig);

}  // namespace romunect
