// The one calibration file (docs/design.md, "Formats"; keys in docs/calibrate.md): a cv::FileStorage YAML that plain
// OpenCV reads without romunect. Keys:
//   format: "romunect-calibration", version: 1, date: ISO 8601 UTC
//   image_width, image_height, camera_matrix, distortion_coefficients  (OpenCV's names)
//   H_P_rec: 3x3 (projector pre-warp homography, projector pixels)
//   T_H_C: 4x4 (camera in hand, metres), T_B_K: 4x4 (board in base, metres)
//   depth_model: {kind: none | affine_in_chip_depth | inverse_affine_in_raw (the sensor model's
//                 DepthCorrectionModelName), chip_focal_px, chip_baseline_m, chip_raw_offset (the
//                 chip's raw -> depth formula Z = 8 f b / (raw_offset - raw), read by the affine
//                 model; raw 2047 = none), a, b: CV_32F maps inline (NaN = unfitted pixel), or
//                 a_exr, b_exr: paths relative to the file; no a/b when kind is none}
//   residuals: {intrinsics_rms_px, intrinsics_holdout_rms_px, hand_eye_rms_px,
//               homography_rms_px, depth_rms_m}  (-1 = step not run)
#pragma once

#include <filesystem>
#include <optional>
#include <string>

#include <Eigen/Core>

#include "romunect/calib/depth_correction.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/pose.h"
#include "romunect/sensor/rig.h"

namespace romunect::calib {

inline constexpr const char* kCalibrationFormat = "romunect-calibration";
inline constexpr int kCalibrationVersion = 1;

struct CalibrationResiduals {
  double intrinsics_rms_px = -1.0;
  double intrinsics_holdout_rms_px = -1.0;
  double hand_eye_rms_px = -1.0;
  double homography_rms_px = -1.0;
  double depth_rms_m = -1.0;
};

struct Calibration {
  CameraModel camera;
  Eigen::Matrix3d H_P_rec = Eigen::Matrix3d::Identity();
  Pose T_H_C = Pose::Identity();
  Pose T_B_K = Pose::Identity();
  // The sensor model's per-pixel correction (applied by the pipeline); none until the depth
  // step ran. Its a and b hold float values (the file stores CV_32F).
  std::optional<DepthCorrection> depth;
  // The chip whose raw values `depth` reads; the file keeps its depth formula (f, b, raw_offset).
  ChipGeometry chip = StockChipGeometry();
  std::string date;  // set by Save when empty
  CalibrationResiduals residuals;
};

// Which steps of `candidate` are worse than `existing` (a residual larger by more than 1 %,
// or a step that `existing` has and `candidate` lacks); "" when none is.
std::string WorseThan(const Calibration& candidate, const Calibration& existing);

struct SaveOptions {
  bool maps_as_exr = false;      // write depth maps as <stem>_depth_a.exr / _b.exr beside the file
  bool overwrite_worse = false;  // replace an existing file even if the new one is worse
};

struct SaveReport {
  bool replaced_existing = false;
  std::string worse_than_existing;  // non-empty when a worse result replaced the old file
};

// Writes atomically (maps first, YAML last). If `path` exists and the new calibration is worse
// (WorseThan), throws InputError naming the file and the worse steps unless overwrite_worse.
// An existing file that does not load is never replaced without overwrite_worse either.
SaveReport SaveCalibration(const std::filesystem::path& path, Calibration calibration, const SaveOptions& options = {});

// Loads and validates every field; throws InputError naming the file and the field.
Calibration LoadCalibration(const std::filesystem::path& path);

// What a device's frames need from a calibration file (`record`, `fuse`: one reader, so a file
// one command takes the other takes too): the camera, T_H_C and the depth model with its chip.
// A file with a `depth_model` (as `romunect calibrate` writes) is loaded whole by LoadCalibration;
// an integrator's own file may hold only format, version, the camera (OpenCV's names) and T_H_C,
// and then has no depth model and every residual -1.
Calibration LoadDeviceCalibration(const std::filesystem::path& path);

// A camera on the hand lies within this of the flange (the rig's is 66 mm away).
inline constexpr double kHandEyeMaxTranslationM = 1.0;

// A warning for a device calibration whose T_H_C is the identity without a hand-eye residual
// (what `calibrate intrinsics` leaves: a camera at the flange, not calibrated yet), or whose
// translation exceeds kHandEyeMaxTranslationM (a file written in millimetres); "" otherwise.
std::string HandEyeWarning(const Calibration& calibration, const std::string& path);

}  // namespace romunect::calib
