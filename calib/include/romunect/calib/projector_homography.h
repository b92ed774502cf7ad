// The projector pre-warp homography H_P_rec (paper, eq. 1):
//   argmin_H  sum_i || F_img(H * x_P^i) - x_C^i ||^2
// x_P^i: feature points of the projector's default pattern (projector pixels); x_C^i: where the
// rectified configuration wants them in the camera image (camera pixels, distorted, as the
// chip sees them); F_img: projector pixels -> camera pixels via the scene. For a plane F_img is
// a homography followed by the camera's (known) distortion; it is estimated from captures where
// the projector showed the pattern warped by a known H, and then H is solved by
// Levenberg-Marquardt (Ceres). In the loop: project with H, observe, re-estimate, repeat.
#pragma once

#include <functional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"

namespace romunect::calib {

// One capture: the projector showed the default pattern warped by H_shown (pattern pixel x_P
// appears at projector pixel H_shown * x_P); its features were detected at detected_px (same
// order as the pattern points; NaN = not detected).
struct ProjectorCapture {
  Eigen::Matrix3d H_shown = Eigen::Matrix3d::Identity();
  std::vector<cv::Point2f> detected_px;
};

struct ProjectorHomographyOptions {
  int max_captures = 5;        // loop: stop after this many captures
  double tolerance_px = 0.05;  // loop: stop when an update moves no feature's predicted
                               // camera position by more than this (camera px)
  int min_points = 8;          // detected features per capture, at least
  int max_iterations = 100;    // Levenberg-Marquardt
  std::string Problem() const;
};

struct ProjectorHomographyStep {
  Eigen::Matrix3d H_P_rec = Eigen::Matrix3d::Identity();  // normalized: H(2,2) = 1
  Eigen::Matrix3d F_img = Eigen::Matrix3d::Identity();    // fitted: projector px -> ideal camera px
  double predicted_rms_px = 0.0;                          // || F_img(H x_P) - x_C || with the fitted F_img
  double mapping_fit_rms_px = 0.0;                        // how well the homography model explains the captures
  int points_used = 0;
  int iterations = 0;
};

// Pure step: fits F_img to all captures jointly (they share the scene) and solves eq. 1.
// Throws InputError (source "projector homography") on mismatched sizes or too few points.
ProjectorHomographyStep SolveProjectorHomography(const std::vector<Eigen::Vector2d>& pattern_P,
                                                 const std::vector<Eigen::Vector2d>& target_C,
                                                 const std::vector<ProjectorCapture>& captures,
                                                 const CameraModel& camera,
                                                 const ProjectorHomographyOptions& options = {});

struct ProjectorHomographyResult {
  Eigen::Matrix3d H_P_rec = Eigen::Matrix3d::Identity();
  std::vector<double> observed_rms_px;  // per capture: detected vs target, with that H shown
  double predicted_rms_px = 0.0;
  int captures = 0;
  bool converged = false;
  std::string BriefReport() const;
};

// The hardware-in-the-loop iteration: observe(H) shows the pattern warped by H and returns
// the detected features (camera pixels, pattern order). Starts from H_initial.
ProjectorHomographyResult CalibrateProjectorHomography(
    const std::vector<Eigen::Vector2d>& pattern_P, const std::vector<Eigen::Vector2d>& target_C,
    const CameraModel& camera, const Eigen::Matrix3d& H_initial,
    const std::function<std::vector<cv::Point2f>(const Eigen::Matrix3d& H)>& observe,
    const ProjectorHomographyOptions& options = {});

}  // namespace romunect::calib
