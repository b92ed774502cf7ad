#include "romunect/tools/jobs/calibrate.h"

#include <cctype>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "robot_poses.h"
#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/calib/hand_eye_check.h"
#include "romunect/calib/intrinsics.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/open_source.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using namespace romunect::calib;

// The existing calibration at `path` to update, or a fresh one. An unreadable file is an
// error, unless the user asked to overwrite: then it is replaced (Save says so).
Calibration Existing(const fs::path& path, bool overwrite) {
  if (!fs::exists(path)) return {};
  try {
    return LoadCalibration(path);
  } catch (const InputError&) {
    if (!overwrite) throw;
    return {};
  }
}

// --board and --square, each named when wrong.
BoardSpec ParseBoard(const std::string& board, double square_m) {
  if (!(square_m > 0.0) || !std::isfinite(square_m)) {
    throw InputError("--square", "", std::to_string(square_m) + ": must be the square's edge in metres (> 0)");
  }
  return ParseBoardSize(board, square_m, "--board");
}

// Writes the file unless it exists with a better result (--overwrite-worse overrides). With
// camera_replaced, the existing file's hand-eye result is not compared: it went with its camera.
void Save(const CalibrationFileOptions& args, const Calibration& calibration, bool camera_replaced = false) {
  std::string worse;
  if (fs::exists(args.output)) {
    try {
      Calibration existing = LoadCalibration(args.output);
      if (camera_replaced) existing.residuals.hand_eye_rms_px = -1.0;
      worse = WorseThan(calibration, existing);
    } catch (const InputError& e) {
      worse = std::string("the existing file does not load (") + e.what() + ")";
    }
  }
  if (!worse.empty() && !args.overwrite_worse) {
    throw InputError(args.output, "",
                     "exists and the new calibration is worse (" + worse +
                         "); not overwritten: write elsewhere with --output, or pass --overwrite-worse");
  }
  SaveCalibration(args.output, calibration, {.maps_as_exr = args.maps_as_exr, .overwrite_worse = true});
  if (!worse.empty()) {
    std::printf("warning: replaced %s with a WORSE result (--overwrite-worse): %s\n", args.output.c_str(),
                worse.c_str());
  }
  std::printf("wrote %s\n", args.output.c_str());
}

}  // namespace

Calibration RunIntrinsicsStep(const IntrinsicsStepOptions& o) {
  const CalibrationFileOptions& args = o.file;
  const BoardSpec board = ParseBoard(o.board, o.square_m);
  // The file is written after the detection: a folder it cannot go into is refused first.
  if (const fs::path folder = fs::path(args.output).parent_path(); !folder.empty() && !fs::is_directory(folder)) {
    throw InputError("--output", "", args.output + ": " + folder.string() + " is not a folder");
  }
  const DetectedViews detected = DetectBoardInFolder(o.images, board);
  for (const auto& [file, reason] : detected.rejected) std::printf("rejected %s: %s\n", file.c_str(), reason.c_str());
  std::printf("board found in %zu of %zu images\n", detected.views.size(),
              detected.views.size() + detected.rejected.size());
  IntrinsicsOptions options;
  options.model = o.k3 ? DistortionModel::kK1K2P1P2K3 : DistortionModel::kK1K2P1P2;
  const IntrinsicsResult result = CalibrateIntrinsics(detected.views, board, detected.image_size, options);
  for (size_t i = 0; i < detected.views.size(); ++i) {
    std::printf("  %-32s %.3f px\n", detected.views[i].name.c_str(), result.per_view_rms_px[i]);
  }
  std::printf("%s\n", result.BriefReport().c_str());
  Calibration calibration = Existing(args.output, args.overwrite_worse);
  const bool had_hand_eye = calibration.residuals.hand_eye_rms_px >= 0.0;
  if (had_hand_eye) {
    // T_H_C and T_B_K were fitted through the old camera: with a new one they no longer hold
    std::printf("warning: %s held a hand-eye result for its old camera; dropped it: run `romunect calibrate "
                "hand-eye` again\n",
                args.output.c_str());
    calibration.T_H_C = Pose::Identity();
    calibration.T_B_K = Pose::Identity();
    calibration.residuals.hand_eye_rms_px = -1.0;
  }
  calibration.camera = result.camera;
  calibration.date.clear();
  calibration.residuals.intrinsics_rms_px = result.rms_px;
  calibration.residuals.intrinsics_holdout_rms_px = result.holdout_rms_px;
  if (calibration.depth &&
      (calibration.depth->a.cols != result.camera.width || calibration.depth->a.rows != result.camera.height)) {
    throw InputError(args.output, "depth_model", "its maps do not match the new image size; write elsewhere");
  }
  Save(args, calibration, had_hand_eye);
  return calibration;
}

namespace {

// A bad frame's message with its frame numbers and file numbers blanked, so that frames skipped
// for one reason (an image of the wrong format) count as one.
std::string SkipReason(const std::string& error) {
  std::string reason;
  for (size_t i = 0; i < error.size(); ++i) {
    if (std::isdigit(static_cast<unsigned char>(error[i]))) {
      if (reason.empty() || reason.back() != '#') reason += '#';
    } else {
      reason += error[i];
    }
  }
  return reason;
}

// Every frame of a recorded source (OpenSource: frame directory, .oni file with a pose log,
// device) with its T_B_H and the image a step needs; bad frames are reported and skipped. The
// source's camera must have the image size of `calibration` (read from `calibration_file`).
void ForEachFrame(const std::string& source_text, const PoseLogOptions& poses, bool need_raw,
                  const Calibration& calibration, const std::string& calibration_file,
                  const std::function<void(const Frame&)>& use) {
  if (poses.offset_given && poses.log.empty()) {
    throw InputError("--pose-offset", "", "applies with --poses: it shifts frame times onto the pose log's clock");
  }
  openni2::OpenSourceOptions options;
  options.pose_log = poses.log;
  options.pose.time_offset_s = poses.offset_s;
  options.invalid_depth = InvalidDepthPolicy::kSkip;
  // a recording or device: open only the stream the step reads (IR of the board, or the raw
  // shifts of the plane), so one capture recorded with both (`record --raw`) serves each step
  options.openni2.depth = need_raw;
  options.openni2.raw = need_raw;
  options.openni2.ir = !need_raw;
  std::unique_ptr<FrameSource> source = openni2::OpenSource(source_text, options);
  const CameraModel& camera = source->camera();
  if (camera.width != calibration.camera.width || camera.height != calibration.camera.height) {
    throw InputError(source_text, "camera",
                     "image size " + std::to_string(camera.width) + " x " + std::to_string(camera.height) +
                         " differs from " + std::to_string(calibration.camera.width) + " x " +
                         std::to_string(calibration.camera.height) + " in " + calibration_file +
                         "; record with the camera mode that file was calibrated in");
  }
  Frame frame;
  std::string error;
  std::map<std::string, int> skipped;  // by reason, for the final message
  for (;;) {
    const FrameStatus status = source->Next(&frame, &error);
    if (status == FrameStatus::kEndOfStream) break;
    if (status == FrameStatus::kBadFrame) {
      std::printf("skipped a bad frame: %s\n", error.c_str());
      ++skipped[SkipReason(error)];
      continue;
    }
    const std::string field = "frames[" + std::to_string(frame.index) + "]";
    if (!frame.T_B_H) {
      throw InputError(source_text, field + ".T_B_H",
                       "missing: every frame needs the robot's hand pose (frames.json, or --poses LOG)");
    }
    if (need_raw ? frame.raw.empty() : frame.ir.empty()) {
      throw InputError(source_text, field + (need_raw ? ".raw" : ".ir"),
                       need_raw ? "missing: depth calibration needs raw depth of the plane"
                                : "missing: hand-eye calibration needs IR images of the board (projector off)");
    }
    use(frame);
  }
  for (const auto& [reason, count] : skipped) std::printf("skipped %d frame(s): %s\n", count, reason.c_str());
}

}  // namespace

namespace {

// What the user changes on the command line to undo a mistake the hand-eye check found.
std::string Remedy(const HandEyeAlternative& alt, const HandEyeStepOptions& o) {
  switch (alt.mistake) {
    case HandEyeMistake::kPosesInMillimetres: return "pass --pose-units mm";
    case HandEyeMistake::kPosesInMetres: return "pass --pose-units m";
    case HandEyeMistake::kInvertedPoses:
      return o.poses_are == "base-in-hand" ? "pass --poses-are hand-in-base" : "pass --poses-are base-in-hand";
    case HandEyeMistake::kPairedOneLate:
    case HandEyeMistake::kPairedOneEarly:
      return "an image or a pose is missing or extra at one end: pair image i with the pose it was taken at";
    case HandEyeMistake::kSquareSize: {
      char text[80];
      std::snprintf(text, sizeof(text), "measure the board: pass --square %.4f if that is its square", alt.square_m);
      return text;
    }
  }
  return "";
}

[[noreturn]] void RefuseHandEye(const CheckedHandEye& checked, const Calibration& calibration,
                                const HandEyeStepOptions& o) {
  const HandEyeAlternative* best = nullptr;
  for (const HandEyeAlternative& alt : checked.alternatives) {
    if (alt.fits && (best == nullptr || alt.rms_px < best->rms_px)) best = &alt;
  }
  char head[300];
  std::snprintf(head, sizeof(head),
                "reprojection RMS %.3f px is over the limit %.3f px (max(1 px, 5 x the intrinsics' %.3f px)): the "
                "poses and the images disagree; nothing written. Likely cause: ",
                checked.fit.rms_px, checked.limit_px, calibration.residuals.intrinsics_rms_px);
  throw InputError("hand-eye", "stations",
                   std::string(head) + checked.cause + (best ? "; " + Remedy(*best, o) : std::string()));
}

// The board in each image of the folder (any bit depth), paired in name order with the poses.
HandEyeCaptures CapturesFromImages(const HandEyeStepOptions& o, const BoardSpec& board, const CameraModel& camera,
                                   const std::vector<Pose>& T_B_H) {
  const std::vector<fs::path> files = ListBoardImages(o.images);
  if (files.size() != T_B_H.size()) {
    throw InputError(o.poses.log, "",
                     std::to_string(T_B_H.size()) + " poses for " + std::to_string(files.size()) + " images in " +
                         o.images + "; one pose per image, in the images' name order");
  }
  HandEyeCaptures captures;
  captures.T_B_H = T_B_H;
  for (const fs::path& file : files) {
    const cv::Mat image = cv::imread(file.string(), cv::IMREAD_UNCHANGED);
    if (image.empty()) throw InputError(file.string(), "", "cannot be read as an image");
    if (image.cols != camera.width || image.rows != camera.height) {
      throw InputError(file.string(), "size",
                       std::to_string(image.cols) + "x" + std::to_string(image.rows) + " differs from the camera's " +
                           std::to_string(camera.width) + "x" + std::to_string(camera.height) +
                           " in the intrinsics file");
    }
    std::string reason;
    auto corners = DetectBoard(image, board, &reason);
    if (!corners) std::printf("rejected %s: %s\n", file.filename().c_str(), reason.c_str());
    captures.views.push_back(
        corners ? std::optional<BoardView>(BoardView{file.filename().string(), std::move(*corners)}) : std::nullopt);
  }
  return captures;
}

void CheckHandEyeOptions(const HandEyeStepOptions& o) {
  if (o.frames.empty() == o.images.empty()) {
    throw InputError("--frames", "", "give either --frames SOURCE or --images DIR with --poses FILE");
  }
  if (!o.images.empty() && o.poses.log.empty()) {
    throw InputError("--images", "", "needs --poses FILE: the robot's hand pose for each image");
  }
  if (!o.images.empty() && o.poses.offset_given) {
    throw InputError("--pose-offset", "", "applies with --frames: images are paired with poses by order");
  }
  if (o.pose_units != "m" && o.pose_units != "mm") throw InputError("--pose-units", "", "must be m or mm");
  if (o.poses_are != "hand-in-base" && o.poses_are != "base-in-hand") {
    throw InputError("--poses-are", "", "must be hand-in-base or base-in-hand");
  }
}

// The focal length the robot's motion gives against the intrinsics' one: a large change means
// the intrinsics' views constrained it weakly (little tilt or depth spread).
void WarnWeakFocal(const CheckedHandEye& checked, const Calibration& calibration, const BoardSpec& board,
                   const HandEyeOptions& options) {
  constexpr double kWeakFocalFraction = 3e-4;  // 0.03 %: ~1 mm of hand-eye translation at 0.2 m
  HandEyeResult refined = checked.fit;
  if (!options.refine_intrinsics) {
    HandEyeOptions refine = options;
    refine.refine_intrinsics = true;
    try {
      refined = CalibrateHandEye(checked.used, calibration.camera, board, refine);
    } catch (const InputError&) {
      return;  // the fit above worked with these stations; no second opinion is no warning
    }
  }
  const double change = FocalChangeFraction(calibration.camera, refined);
  if (std::abs(change) > kWeakFocalFraction) {
    std::printf("warning: the robot's motion puts the focal length %+.3f %% from the intrinsics file's: its views "
                "constrain the focal length weakly (add views tilted 30-45 deg at several distances)%s\n",
                100.0 * change, options.refine_intrinsics ? "; refined here" : "; pass --refine-intrinsics");
  }
}

}  // namespace

Calibration RunHandEyeStep(const HandEyeStepOptions& o) {
  const CalibrationFileOptions& args = o.file;
  CheckHandEyeOptions(o);
  const BoardSpec board = ParseBoard(o.board, o.square_m);
  const std::string camera_file = o.intrinsics.empty() ? args.output : o.intrinsics;
  if (!fs::exists(camera_file)) {
    throw InputError(camera_file, "", "no calibration file with intrinsics; run `romunect calibrate intrinsics` first");
  }
  Calibration calibration = LoadCalibration(camera_file);
  const RobotPoseFileOptions pose_options{o.pose_units == "mm" ? 1e-3 : 1.0, o.poses_are == "base-in-hand"};
  HandEyeCaptures captures;
  if (!o.images.empty()) {
    const RobotPoses poses = ReadRobotPoses(o.poses.log, pose_options);
    if (poses.reorthonormalized > 0) {
      std::printf("warning: %d rotations re-orthonormalized (max |R^T R - I| %.2g: rounded values)\n",
                  poses.reorthonormalized, poses.worst_orthonormality);
    }
    captures = CapturesFromImages(o, board, calibration.camera, poses.T_B_H);
  } else {
    ForEachFrame(o.frames, o.poses, false, calibration, camera_file, [&](const Frame& frame) {
      Pose T_B_H = *frame.T_B_H;
      T_B_H.translation() *= pose_options.metres_per_unit;
      captures.T_B_H.push_back(pose_options.base_in_hand ? T_B_H.inverse() : T_B_H);
      std::string reason;
      auto corners = DetectBoard(frame.ir, board, &reason);
      if (!corners) std::printf("rejected frame %d: %s\n", frame.index, reason.c_str());
      captures.views.push_back(
          corners ? std::optional<BoardView>(BoardView{"frame " + std::to_string(frame.index), std::move(*corners)})
                  : std::nullopt);
    });
  }
  HandEyeCheckOptions check;
  check.hand_eye.refine_intrinsics = o.refine_intrinsics;
  check.intrinsics_rms_px = calibration.residuals.intrinsics_rms_px;
  const CheckedHandEye checked = CalibrateHandEyeChecked(captures, calibration.camera, board, check);
  std::printf("per-station reprojection RMS:\n%s", checked.StationTable().c_str());
  std::printf("%zu stations used, %zu dropped as outliers, of %zu poses\n", checked.used.size(), checked.dropped.size(),
              captures.T_B_H.size());
  std::printf("%s\n", checked.fit.BriefReport().c_str());
  if (!checked.accepted) RefuseHandEye(checked, calibration, o);
  WarnWeakFocal(checked, calibration, board, check.hand_eye);
  calibration.camera = checked.fit.camera;  // refined with --refine-intrinsics, else as loaded
  calibration.T_H_C = checked.fit.T_H_C;
  calibration.T_B_K = checked.fit.T_B_K;
  calibration.residuals.hand_eye_rms_px = checked.fit.rms_px;
  calibration.date.clear();
  Save(args, calibration);
  return calibration;
}

Calibration RunDepthStep(const DepthStepOptions& o) {
  const CalibrationFileOptions& args = o.file;
  if (!fs::exists(args.output)) {
    throw InputError(args.output, "", "no calibration file; run intrinsics and hand-eye first");
  }
  Calibration calibration = LoadCalibration(args.output);
  if (calibration.residuals.hand_eye_rms_px < 0) {
    throw InputError(args.output, "T_H_C", "not calibrated yet; run `romunect calibrate hand-eye` first");
  }
  std::vector<PlaneCapture> captures;
  ForEachFrame(o.frames, o.poses, true, calibration, args.output, [&](const Frame& frame) {
    // The reference plane is the board's plane (z = 0 of K), placed by the hand-eye step.
    const Pose T_C_K = (*frame.T_B_H * calibration.T_H_C).inverse() * calibration.T_B_K;
    captures.push_back({frame.raw.clone(), T_C_K});
  });
  DepthCorrectionOptions options;
  options.chip = calibration.chip;  // the chip whose raw the file's correction reads
  const DepthCorrectionResult result = FitDepthCorrection(calibration.camera, captures, options);
  std::printf("%s\n", result.BriefReport().c_str());
  if (o.model == "exact") {
    calibration.depth = result.inverse;
    calibration.residuals.depth_rms_m = result.inverse_rms_m;
  } else {
    calibration.depth = result.affine;
    calibration.residuals.depth_rms_m = result.affine_rms_m;
  }
  calibration.date.clear();
  Save(args, calibration);
  return calibration;
}

}  // namespace romunect::jobs
