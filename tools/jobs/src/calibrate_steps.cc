#include "romunect/tools/jobs/calibrate.h"

#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
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

void Save(const CalibrationFileOptions& args, const Calibration& calibration) {
  const SaveReport report = SaveCalibration(args.output, calibration,
                                            {.maps_as_exr = args.maps_as_exr, .overwrite_worse = args.overwrite_worse});
  if (!report.worse_than_existing.empty()) {
    std::printf("warning: replaced %s with a WORSE result (--overwrite-worse): %s\n", args.output.c_str(),
                report.worse_than_existing.c_str());
  }
  std::printf("wrote %s\n", args.output.c_str());
}

}  // namespace

Calibration RunIntrinsicsStep(const IntrinsicsStepOptions& o) {
  const CalibrationFileOptions& args = o.file;
  const BoardSpec board = ParseBoardSize(o.board, o.square_m, "--board");
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
  calibration.camera = result.camera;
  calibration.date.clear();
  calibration.residuals.intrinsics_rms_px = result.rms_px;
  calibration.residuals.intrinsics_holdout_rms_px = result.holdout_rms_px;
  if (calibration.depth &&
      (calibration.depth->a.cols != result.camera.width || calibration.depth->a.rows != result.camera.height)) {
    throw InputError(args.output, "depth_model", "its maps do not match the new image size; write elsewhere");
  }
  Save(args, calibration);
  return calibration;
}

namespace {

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
  for (;;) {
    const FrameStatus status = source->Next(&frame, &error);
    if (status == FrameStatus::kEndOfStream) break;
    if (status == FrameStatus::kBadFrame) {
      std::printf("skipped a bad frame: %s\n", error.c_str());
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
}

}  // namespace

Calibration RunHandEyeStep(const HandEyeStepOptions& o) {
  const CalibrationFileOptions& args = o.file;
  const BoardSpec board = ParseBoardSize(o.board, o.square_m, "--board");
  if (!fs::exists(args.output)) {
    throw InputError(args.output, "", "no calibration file with intrinsics; run `romunect calibrate intrinsics` first");
  }
  Calibration calibration = LoadCalibration(args.output);
  std::vector<HandEyeStation> stations;
  ForEachFrame(o.frames, o.poses, false, calibration, args.output, [&](const Frame& frame) {
    std::string reason;
    auto corners = DetectBoard(frame.ir, board, &reason);
    if (!corners) {
      std::printf("rejected frame %d: %s\n", frame.index, reason.c_str());
      return;
    }
    stations.push_back({*frame.T_B_H, {"frame " + std::to_string(frame.index), std::move(*corners)}});
  });
  const HandEyeResult result = CalibrateHandEye(stations, calibration.camera, board);
  std::printf("%s\n", result.BriefReport().c_str());
  calibration.T_H_C = result.T_H_C;
  calibration.T_B_K = result.T_B_K;
  calibration.residuals.hand_eye_rms_px = result.rms_px;
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
