// The whole calibration chain in the loop (paper, section 3.2): intrinsics -> projector
// homography -> hand-eye -> per-pixel depth correction, driving the robot and the sensor
// through CalibrationHardware (a simulated rig in sim/, or a real one). The chain plans moves
// with the setup's NOMINAL values (datasheet, CAD, where the plate was put) and calibrates only
// from what the hardware reports: executed hand poses T_B_H and captured images.
// Frames: B base, H hand, C camera, K the calibration plate (board.h: origin at the first inner
// corner, z = 0 on the plate, z into it), P projector. SI units; pixels centred at integers.
#pragma once

#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/calib/board.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/calib/intrinsics.h"
#include "romunect/calib/projector_homography.h"
#include "romunect/sensor/pose.h"
#include "romunect/sensor/rig.h"

namespace romunect::calib {

// What is known before calibrating: nominal values, good for planning moves only.
struct CalibrationSetup {
  Rig nominal_rig;     // camera, projector, T_C_P and chip from datasheets and CAD
  Pose T_H_C_nominal;  // the sensor's mount on the flange (CAD)
  Pose T_B_K_nominal;  // where the plate was put (marked spot on the table)
  BoardSpec board;     // the checkerboard printed on the plate
  // Centre of the plate's plain (white, untextured) reference area, in K (z = 0): where the
  // homography and depth captures look.
  Eigen::Vector3d reference_centre_K = Eigen::Vector3d::Zero();
};

// The robot, the sensor and the projector, as the chain drives them. Captures are taken at the
// pose of the last MoveHand.
class CalibrationHardware {
 public:
  virtual ~CalibrationHardware() = default;
  virtual const CalibrationSetup& setup() const = 0;
  // Moves the hand to T_B_H (commanded) and returns the pose the robot reports after the move
  // (executed); nullopt when the goal is out of reach (nothing moved).
  virtual std::optional<Pose> MoveHand(const Pose& T_B_H) = 0;
  // IR image (CV_16U, camera size) with the projector off and the IR lamp on: board views.
  virtual cv::Mat CaptureLampIr() = 0;
  // IR image with the projector showing `pattern` warped by H (x_P ~ H x_pattern).
  virtual cv::Mat CaptureProjectedIr(const PatternSpec& pattern, const Eigen::Matrix3d& H) = 0;
  // The chip's raw depth (CV_16U, kRawInvalid = none) with the default pattern warped by H.
  virtual cv::Mat CaptureRaw(const Eigen::Matrix3d& H) = 0;
};

struct ChainOptions {
  int views = 20;                // intrinsics: planned board views
  int stations = 15;             // hand-eye: the first stations of the views (more planned if needed)
  int depth_planes = 12;         // depth: captures of the reference area
  unsigned seed = 1;             // view planning jitter
  double view_distance_m = 0.2;  // camera to board centre
  // Views alternate between distance * (1 - spread) and * (1 + spread): known robot motion
  // along the optical axis is what pins the focal length down in the hand-eye refinement.
  double view_distance_spread = 0.08;
  double max_tilt_rad = 0.5;  // board tilts of the views (stronger ones blur beyond detection)
  double margin_px = 50.0;    // planned corners this far inside the image (nominal errors)
  // Projector homography: the feature grid, shown on the reference area from this distance.
  PatternSpec feature_pattern = [] {
    PatternSpec p;
    p.kind = PatternKind::kFeatureGrid;
    p.pitch_px = 64;
    return p;
  }();
  double homography_distance_m = 0.2;
  // Depth: plane distances spread over [near, far] (the measurable range), tilts up to this.
  double depth_near_m = 0.194;
  double depth_far_m = 0.206;
  double depth_max_tilt_rad = 0.06;
  IntrinsicsOptions intrinsics;
  HandEyeOptions hand_eye = [] {
    HandEyeOptions h;
    h.refine_intrinsics = true;  // the chain has the robot's motion: use it for the camera too
    return h;
  }();
  ProjectorHomographyOptions homography;
  DepthCorrectionOptions depth = [] {
    DepthCorrectionOptions d;
    d.min_plane_coverage = 0.5;  // the chip's reference leaves the image borders unmatched
    return d;
  }();
  std::string Problem() const;  // "" when valid: "field = value: rule"
  // The fewest views and depth planes Problem() accepts: the steps' own minimums (a command line's
  // ranges print these).
  int MinViews() const;
  int MinPlanes() const;
};

// Compute time per step: CPU seconds of the calibration's own work (detection, solvers, fits);
// moves and captures excluded (hardware_s is their wall time).
struct ChainTimes {
  double intrinsics_s = 0.0, homography_s = 0.0, hand_eye_s = 0.0, depth_s = 0.0;
  double hardware_s = 0.0;  // moves and captures (simulated or real)
  double ComputeS() const { return intrinsics_s + homography_s + hand_eye_s + depth_s; }
};

struct ChainResult {
  Calibration calibration;              // ready for SaveCalibration (exact depth model; hand-eye's camera)
  IntrinsicsResult intrinsics;          // Zhang's camera, before the hand-eye refinement
  std::vector<std::string> view_names;  // per used view, same order as per_view_rms
  std::vector<std::pair<std::string, std::string>> rejected;  // (view, why)
  std::vector<Pose> view_T_B_H;                               // executed poses of the used views
  ProjectorHomographyResult homography;
  std::vector<Eigen::Vector2d> homography_pattern, homography_target;  // eq. 1's x_P, x_C
  double raw_valid_fraction_unwarped = 0.0;                            // depth engine matches with H = I (before)
  double raw_valid_fraction_initial = 0.0;                             // ... with the nominal pre-warp
  double raw_valid_fraction_final = 0.0;                               // ... with the calibrated H_P_rec (after)
  HandEyeResult hand_eye;
  std::vector<HandEyeStation> hand_eye_stations;  // those of the final fit (outliers dropped)
  int stations_used = 0;
  DepthCorrectionResult depth;
  int planes_used = 0;
  ChainTimes times;
};

// Progress lines ("intrinsics: view 3/20 ...") for a person watching; may be empty.
using ChainProgress = std::function<void(const std::string& line)>;

// Runs the four steps. Throws InputError (source "calibration chain" or the failing step's) when
// a step cannot go on: too few views with the board found, an unreachable homography or depth
// station, too few planes. Nothing is written: the caller saves the calibration.
ChainResult RunCalibrationChain(CalibrationHardware* hardware, const ChainOptions& options,
                                const ChainProgress& progress = {});

// Where the chip's stored reference image has a pattern point (pattern pixels -> camera pixels
// of the stock geometry on its reference plane): the rectified configuration of eq. 1.
Eigen::Vector2d ChipReferencePx(const ChipGeometry& chip, const Eigen::Vector2d& x_pattern);

// Where projector pixel q_P lands in the camera when the plate (z = 0 of K) is at T_C_K: the
// projector's pinhole ray (rig.projector, rig.T_C_P) meets the plane, `camera` projects it.
// nullopt when the ray misses the plane or the point is behind the camera. May be off the image.
std::optional<Eigen::Vector2d> ProjectorPixelToCamera(const Rig& rig, const CameraModel& camera, const Pose& T_C_K,
                                                      const Eigen::Vector2d& q_P);

// Feature detection for the homography step: the projected dot nearest each predicted camera
// position (NaN prediction: skipped), refined to an intensity-weighted centroid. Dots further
// than max_offset_px from their prediction, touching the image border or too faint are NaN.
std::vector<cv::Point2f> DetectProjectedDots(const cv::Mat& ir, const std::vector<Eigen::Vector2d>& predicted_px,
                                             double dot_radius_px, double max_offset_px);

}  // namespace romunect::calib
