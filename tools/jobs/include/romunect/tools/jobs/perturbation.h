// Known calibration errors injected into what a pipeline believes (`--perturb` on scan and
// fuse), never into the simulated truth: the hand-eye pose T_H_C (so every camera pose), the
// camera model fusion back-projects with, and the depth model's output. With these the effect
// of each calibration error on the fused map is measured instead of guessed.
//
// Text: NAME=VALUE[,NAME=VALUE...] with
//   hand_eye_deg[_x|_y|_z]  rotation of T_H_C about the camera's axis (x when none given), deg
//   hand_eye_mm[_x|_y|_z]   translation of T_H_C along the camera's axis (z when none given), mm
//   focal_pct               fx and fy scaled by 1 + VALUE / 100
//   principal_px[_x|_y]     cx (x when none given) or cy shifted, px
//   depth_scale_pct         depth scaled by 1 + VALUE / 100 (an affine depth model's gain)
//   depth_offset_mm         depth offset, mm (an affine depth model's offset)
#pragma once

#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::jobs {

struct CalibrationPerturbation {
  Eigen::Vector3d hand_eye_rotation_C = Eigen::Vector3d::Zero();     // rotation vector in C, rad
  Eigen::Vector3d hand_eye_translation_C = Eigen::Vector3d::Zero();  // m
  double focal_fraction = 0.0;
  Eigen::Vector2d principal_px = Eigen::Vector2d::Zero();
  double depth_scale_fraction = 0.0;
  double depth_offset_m = 0.0;

  bool empty() const;
  std::string Text() const;  // the injected errors as given, e.g. "hand_eye_deg_x=0.5"; "none"
  // T_C_C': the believed camera in the true one; T_H_C' = T_H_C * T_C_Cp(), T_W_C' = T_W_C * T_C_Cp().
  Pose T_C_Cp() const;
  CameraModel Apply(const CameraModel& camera) const;
  void ApplyToDepth(cv::Mat* depth_m) const;  // valid (> 0) pixels only
};

// Parses the text above; throws InputError naming `source`, the name and what is expected.
CalibrationPerturbation ParsePerturbation(const std::string& text, const std::string& source = "--perturb");

// A calibration's errors against the truth it should match, as a report states them.
struct CalibrationErrors {
  double hand_eye_deg = 0.0, hand_eye_mm = 0.0;  // T_H_C rotation angle and translation distance
  double focal_pct = 0.0;                        // mean of fx, fy relative to the truth's
  double principal_px = 0.0;                     // distance of (cx, cy) from the truth's
};
CalibrationErrors CompareCalibration(const Pose& T_H_C, const CameraModel& camera, const Pose& T_H_C_truth,
                                     const CameraModel& camera_truth);

}  // namespace romunect::jobs
