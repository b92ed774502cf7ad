// The simulated calibration hardware (calib/chain.h's CalibrationHardware): the MuJoCo arm of
// the default scene carries the romunect sensor over a calibration plate on the table. The plate
// (frame K, board.h) holds a printed checkerboard (alternating-albedo squares: the renderer has
// no textures) and a plain white reference area beside it (+x of K). Captures go through the
// Embree renderer, IR synthesis and the depth engine, as the scanner's do:
//   - lamp-lit board images: projector off, an IR lamp (ambient light), 3 x 3 sub-pixel samples
//     per pixel (the board's edges need them; one ray per pixel would alias the corners);
//   - projected images: the projector shows a pattern warped by a given H;
//   - raw depth: the default pattern warped by a given H, through the chip's depth engine.
// The setup's nominal values are the truth perturbed by seeded errors of stated size (CAD,
// datasheet, where the plate was put): the chain plans with them; ground truth (camera, T_H_C,
// T_B_K, the projector) is kept aside for reports (the Truth* accessors).
// Frames: W world, B base, H hand, C camera, P projector, K plate. SI units.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/calib/chain.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/rig.h"
#include "romunect/sim/scanner.h"

namespace romunect::sim {

struct CalibrationRigOptions {
  Rig rig = RigPreset("romunect");      // the sensor's truth (its H_P_rec is what the chain sets)
  calib::BoardSpec board{9, 6, 0.003};  // printed on the plate: 10 x 7 squares of 3 mm
  bool print_board = true;              // false: a plain plate (the target cannot be found)
  // The plate on the table: K's origin (the first inner corner) in W, yawed about W's z.
  Eigen::Vector3d plate_origin_W{0.40, 0.2, 0.001};
  double plate_yaw_rad = M_PI;        // K x towards the robot: the reference area nearer the base
  double reference_offset_m = 0.075;  // reference area's centre: this far along K's x from the board's
  double reference_half_m = 0.05;     // the reference area: a square of twice this side
  // Where the rig is calibrated: the distance of the board views, the homography's plane and
  // the evaluation planes of CompareWithTruth (its value +-5 mm and tilted). 0: the focus distance.
  double working_distance_m = 0.0;
  // Nominal errors: each pose perturbed by exactly this angle (random axis) and distance
  // (random direction); focal lengths scaled by 1 +- focal_error, principal point moved.
  double mount_error_rad = 0.005, mount_error_m = 0.001;           // T_H_C, CAD of the bracket
  double plate_error_rad = 0.01, plate_error_m = 0.002;            // T_B_K, placed by hand
  double projector_error_rad = 0.002, projector_error_m = 0.0003;  // T_C_P
  double focal_error = 0.01, principal_error_px = 4.0;
  double lamp_e_per_s = 1.0e5;  // IR lamp for board views (ambient on white, electrons/s)
  int board_samples = 3;        // sub-pixel samples per axis for lamp-lit images (odd)
  int threads = 2;              // render, IR synthesis and depth engine threads
  uint64_t seed = 1;            // nominal errors and image noise
  std::string Problem() const;  // "" when valid: "field = value: rule"
  double WorkingDistanceM() const { return working_distance_m > 0 ? working_distance_m : rig.optics.focus_distance_m; }
};

// The calibration sized for `rig` (the other options at their defaults). The romunect sensor is
// calibrated at its 0.2 m focus on a board of 3 mm squares. A rig that measures farther (the
// stock Kinect: 0.5-4 m) is calibrated at the near end of its measurable range (0.79 m for the
// Kinect; the arm holds a camera at most ~0.86 m above the table), on a board whose squares look
// as large in its image as the romunect's do (43 mm for the Kinect), with a reference area that
// fills its view at the far depth plane, laid out beside the robot, clear of the bin.
CalibrationRigOptions CalibrationRigOptionsFor(const Rig& rig);

// The depth step's plane distances for a calibration: the rig's measurable range within +-15 %
// of the working distance (the romunect's whole 194-206 mm range; 0.79-0.90 m for the Kinect).
DepthRange CalibrationDepthRange(const CalibrationRigOptions& options);

// Depth after correction against the renderer's ground truth on one plane.
struct PlaneDepthError {
  double distance_m = 0.0;
  double tilt_rad = 0.0;
  double rms_m = 0.0, mean_m = 0.0;  // over pixels with both a corrected depth and truth
  double valid_fraction = 0.0;       // of all pixels
};

class SimulatedCalibrationRig : public calib::CalibrationHardware {
 public:
  // Loads the default scene with the rig's mount, places the plate and builds the ray scene.
  // Throws InputError("calibration rig", field, ...) on bad options.
  explicit SimulatedCalibrationRig(const CalibrationRigOptions& options = {});
  ~SimulatedCalibrationRig() override;

  const calib::CalibrationSetup& setup() const override;
  std::optional<Pose> MoveHand(const Pose& T_B_H) override;
  cv::Mat CaptureLampIr() override;
  cv::Mat CaptureProjectedIr(const PatternSpec& pattern, const Eigen::Matrix3d& H) override;
  cv::Mat CaptureRaw(const Eigen::Matrix3d& H) override;

  int captures() const;               // images taken so far
  double working_distance_m() const;  // CalibrationRigOptions::WorkingDistanceM()
  int moves() const;                  // MoveHand calls that moved
  // Ground truth depth (CV_32F metres, 0 = none) of the last capture.
  const cv::Mat& last_truth_depth_m() const;

  // ---- Ground truth, for reports only ----
  const Rig& TruthRig() const;
  Pose TruthT_H_C() const;
  Pose TruthT_B_K() const;
  // Eq. 1's residual (camera px, RMS) of pattern points shown through H on the plane of the
  // last CaptureProjectedIr (where the homography loop ran):
  // true projector ray -> plate -> true camera, against the targets. Points off the plate or
  // behind a device count as missed: *used (nullable) gets the number of points compared.
  double TrueHomographyResidualPx(const Eigen::Matrix3d& H, const std::vector<Eigen::Vector2d>& pattern,
                                  const std::vector<Eigen::Vector2d>& target, int* used = nullptr) const;
  // Places the camera (by the TRUE hand-eye) looking at the reference area's centre from
  // distance_m, tilted by tilt_rad about C's x, captures raw depth with H and compares the
  // depth corrected by each of `corrections` with the renderer's truth (one result per
  // correction). Empty when the pose is out of reach.
  std::vector<PlaneDepthError> EvaluateDepth(const std::vector<DepthCorrection>& corrections, const ChipGeometry& chip,
                                             const Eigen::Matrix3d& H, double distance_m, double tilt_rad);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Every error of a chain's result against the rig's ground truth (for reports): intrinsics
// full-image mapping (rotation-compensated and raw), hand-eye and plate poses, eq. 1 on the
// loop's plane, and corrected depth (exact and affine models) on evaluation planes in focus:
// the focus distance -5, 0, +5 mm fronto-parallel and at 0 mm tilted by 0.1 rad. Moves the arm.
struct ChainTruthErrors {
  calib::MappingError mapping, mapping_uncompensated;  // the calibration's (final) camera
  calib::MappingError mapping_zhang;                   // Zhang's, before the hand-eye refinement
  PoseError hand_eye, hand_eye_initial, board;
  // The hand-eye goal (0.02 deg, 0.15 mm; docs/calibrate.md) holds for KNOWN intrinsics: the hand-eye step re-run on
  // the chain's own stations with the true camera (not refined), for the report only. The chain's T_H_C (hand_eye) goes
  // with its estimated camera: a principal point d px off turns it by about d / f, which the lines of sight below do
  // not show.
  PoseError hand_eye_known_intrinsics;
  // Lines of sight in H (the hand-eye rotation together with the intrinsics): the angle
  // between estimated and true rays of pixels over the image. A principal point off by d px
  // turns T_H_C's rotation by about d / f and leaves these rays nearly unchanged: with a
  // narrow lens (f 2133 px) the two are hard to separate, the rays are what scanning uses.
  double line_of_sight_rms_rad = 0.0, line_of_sight_max_rad = 0.0;
  double homography_px = -1.0;
  int homography_points = 0;
  std::vector<PlaneDepthError> depth_exact, depth_affine;  // per evaluation plane
  double depth_rms_m = -1.0, depth_affine_rms_m = -1.0;    // over the planes
};
ChainTruthErrors CompareWithTruth(SimulatedCalibrationRig* rig, const calib::ChainResult& result);

}  // namespace romunect::sim
