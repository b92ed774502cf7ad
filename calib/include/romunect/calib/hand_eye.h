// Hand-eye (tool-hand) calibration, the paper's [7] (Tsai and Lenz): from robot hand poses T_B_H
// and board views at each station, estimates T_H_C (camera in hand) and T_B_K (board in base).
// OpenCV's calibrateHandEye gives the initial estimate; a Ceres refinement over all corner
// reprojection residuals gives the result. Frames: B base, H hand (flange), C camera, K board.
//
// OpenCV 4.6 (Debian 12) has a known failure of its Tsai (and Daniilidis) solvers when station
// pairs are rotated by more than about 120 degrees (fixed upstream after 4.6). The guard: when
// any pair exceeds `max_pair_rotation_rad`, Park's method gives the initial estimate, and in any
// case the candidate that best explains the observed board poses wins.
#pragma once

#include <string>
#include <vector>

#include "romunect/calib/board.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib {

struct HandEyeStation {
  Pose T_B_H;      // hand pose reported by the robot
  BoardView view;  // the board's corners in the camera image at that pose
};

enum class HandEyeInitialMethod {
  kAuto,  // Tsai unless a station pair rotates more than max_pair_rotation_rad; then Park;
          // the candidate with the smaller board-pose inconsistency wins
  kTsai,  // OpenCV's Tsai alone (the bar; fails for large pair rotations in 4.6)
  kPark,  // OpenCV's Park alone
  kHoraud,
  kAndreff,
  kDaniilidis,  // OpenCV's other solvers alone (for comparison)
};

struct HandEyeOptions {
  HandEyeInitialMethod initial = HandEyeInitialMethod::kAuto;
  double max_pair_rotation_rad = 2.0944;  // 120 deg: OpenCV 4.6's Tsai fails above this
  bool refine = true;                     // Ceres refinement over corner residuals
  // With refine: also refine the camera (fx, fy, cx, cy, k1, k2, p1, p2; k3 kept) over the
  // same residuals. The robot's known motion pins the focal length down (a 0.1 % error in f is
  // 0.2 mm of distance at 200 mm, which Zhang's views alone leave with a narrow lens).
  bool refine_intrinsics = false;
  int min_stations = 3;
  // Motion checks: at least `min_stations` with rotation between them; rotations about at
  // least two distinct axes (pure translation or one axis leaves T_H_C unobservable).
  double min_rotation_rad = 0.035;    // 2 deg: relative rotations below count as none
  double min_axis_spread_rad = 0.17;  // 10 deg between rotation axes
  int max_iterations = 100;
  std::string Problem() const;
};

struct HandEyeResult {
  Pose T_H_C;
  Pose T_B_K;
  Pose T_H_C_initial;                // before refinement
  CameraModel camera;                // the camera T_H_C goes with (refined with refine_intrinsics)
  std::string initial_method;        // "tsai" or "park"
  double max_pair_rotation_rad = 0;  // largest relative rotation between two stations
  double rms_px = 0.0;               // corner reprojection RMS after refinement
  double initial_rms_px = 0.0;       // same with the initial estimate (T_B_K fitted to it)
  int iterations = 0;
  std::string BriefReport() const;
};

// Calibrates from stations with a known camera. Throws InputError (source "hand-eye") with too
// few stations, a view with the wrong corner count, or degenerate motion (saying which and what
// would fix it).
HandEyeResult CalibrateHandEye(const std::vector<HandEyeStation>& stations, const CameraModel& camera,
                               const BoardSpec& board, const HandEyeOptions& options = {});

// OpenCV's calibrateHandEye alone (no guard, no refinement), for comparison: T_H_C.
Pose OpenCvHandEye(const std::vector<HandEyeStation>& stations, const CameraModel& camera, const BoardSpec& board,
                   HandEyeInitialMethod method);

// OpenCV's five solvers alone (Tsai, Park, Horaud, Andreff, Daniilidis), each with the board
// pose T_B_K averaged over the stations and its corner RMS: the comparison for held-out error.
// A solver that fails is left out.
struct OpenCvHandEyeResult {
  std::string method;
  HandEyeResult fit;
};
std::vector<OpenCvHandEyeResult> OpenCvHandEyeAll(const std::vector<HandEyeStation>& stations,
                                                  const CameraModel& camera, const BoardSpec& board);

// The board pose in the camera from one view (solvePnP, iterative), with a known camera.
Pose EstimateBoardPose(const BoardView& view, const CameraModel& camera, const BoardSpec& board);

}  // namespace romunect::calib
