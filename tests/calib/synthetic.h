// Synthetic observations with known truth for calib's tests and benchmark: board corners
// through a CameraModel with seeded pixel noise, robot stations from a known T_H_C, plane raw
// depth from a known per-pixel disparity model, a projector seeing a plane. No renderer.
#pragma once

#include <filesystem>
#include <optional>
#include <random>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/calib/board.h"
#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib::testing {

// 640 x 480, f 580 px, principal point off centre, barrel distortion: a C-mount-like camera.
CameraModel TruthCamera();

// The board's corners seen from T_C_K with Gaussian noise (sigma_px); nullopt when any corner
// is off the image.
std::optional<BoardView> ObserveBoard(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K,
                                      double sigma_px, std::mt19937* rng);

// Weak coverage: board near the image centre, small tilts (the bar's "weak" case).
std::vector<Pose> CentralViews(const CameraModel& camera, const BoardSpec& board, int count, double distance_m,
                               std::mt19937* rng);

// A known rig for hand-eye: truth T_H_C, T_B_K, and stations whose cameras look at the board
// from distance_m with tilts up to max_tilt_rad and rolls up to max_roll_rad (rotations about
// all axes). Stations whose board leaves the image are redrawn.
struct HandEyeRig {
  Pose T_H_C;
  Pose T_B_K;
  std::vector<HandEyeStation> stations;
  std::vector<Pose> T_C_K_truth;
};
// The camera on a bracket, looking along -x of the hand: the mount under which OpenCV 4.6's
// Tsai fails for station pairs rotated past 120 deg (quaternion sign chosen per frame).
Pose TruthHandEye();
Pose TruthBoardInBase();
HandEyeRig MakeHandEyeRig(const CameraModel& camera, const BoardSpec& board, int stations, double sigma_px,
                          double max_tilt_rad, double max_roll_rad, unsigned seed);

// The per-pixel truth of the device's raw disparity: 1/Z = alpha(x,y) * raw + beta(x,y),
// smooth over the image (projector-camera geometry, lens), raw quantized to integers.
struct RawDepthTruth {
  double focal_baseline_px_m = 580.0 * 0.075;  // f * b
  double reference_depth_m = 0.2;              // raw = raw_at_reference at this depth
  double raw_at_reference = 700.0;
  double raw_per_px = 8.0;  // 1/8 px disparity steps
  // Per-pixel inverse-depth model for a camera; alpha, beta as CV_64F maps.
  void Maps(const CameraModel& camera, cv::Mat* alpha, cv::Mat* beta) const;
};
// Raw image of a plane (z = 0 in K) seen from T_C_K, with Gaussian noise on the continuous
// raw value (sigma_raw) before rounding; pixels whose ray misses the plane are invalid.
cv::Mat RenderPlaneRaw(const CameraModel& camera, const RawDepthTruth& truth, const Pose& T_C_K, double sigma_raw,
                       std::mt19937* rng, int invalid_raw = 2047);

// The reference plane at depth_m in front of the camera, tilted by up to tilt_rad (seeded).
Pose PlaneAt(double depth_m, double tilt_x_rad, double tilt_y_rad);

// A downscaled camera (same field of view) for fast per-pixel tests.
CameraModel Scaled(const CameraModel& camera, double factor);

// Renders the board (a distortion-free camera, so a homography) into an 8-bit image: squares
// of side square_m, a white border of one square, grey around; 4x supersampled.
cv::Mat RenderBoardImage(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K);

// A projector (1280 x 800 pixels, f 1400 px) 75 mm beside the camera, both seeing a tilted
// plane at 0.2 m, and the pattern of the homography step: a 12 x 8 grid of dots over the
// projector image, with targets on a rectangular grid of the ideal camera image, distorted
// (what the chip expects to see), reachable by a homography.
struct ProjectorScene {
  CameraModel camera;
  CameraModel projector;
  Pose T_C_P;
  Pose T_C_K;
  std::vector<Eigen::Vector2d> pattern_P, target_C;

  ProjectorScene();
  // Truth F_img: projector pixel -> ray -> plane -> camera pixel (distorted).
  Eigen::Vector2d Map(const Eigen::Vector2d& q_P) const;
  // RMS (px) between where the pre-warped pattern lands and the targets.
  double TrueResidualPx(const Eigen::Matrix3d& H_P_rec) const;
};

// Frame directories as a rig records them, with T_B_H per frame (the CLI's recorded input):
// IR board views (16-bit, 10 bits used) at the rig's stations, raw all invalid; and raw depth
// of the board's plane (z = 0 of rig.T_B_K) from `planes` hand poses at 0.19 .. 0.21 m, tilted.
// Frame i is at 0.1 i s.
void WriteBoardFrames(const std::filesystem::path& dir, const CameraModel& camera, const BoardSpec& board,
                      const HandEyeRig& rig);
void WritePlaneFrames(const std::filesystem::path& dir, const CameraModel& camera, const HandEyeRig& rig, int planes,
                      unsigned seed);

}  // namespace romunect::calib::testing
