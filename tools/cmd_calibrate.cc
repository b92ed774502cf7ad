// romunect calibrate: the calibration chain's steps, each on its own input, updating one
// calibration file (calib/calibration_file.h).
//   calibrate intrinsics --images DIR --board 9x6 --square 0.025 [--output FILE]
//   calibrate hand-eye   --frames DIR --board 9x6 --square 0.025 [--output FILE]
//   calibrate depth      --frames DIR [--output FILE] [--model exact|affine]
// hand-eye and depth read a frame directory whose frames carry T_B_H (IR images of the board
// for hand-eye; raw depth of the reference plane, the board's plane z = 0 of K, for depth).
// The no-argument run in the loop with the simulated rig belongs to a later session.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "commands.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/calib/depth_correction.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/calib/intrinsics.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"

namespace romunect::tools {
namespace {
namespace fs = std::filesystem;
using namespace romunect::calib;

struct CommonArgs {
  std::string output = "calibration.yaml";
  bool overwrite_worse = false;
  bool maps_as_exr = false;
};

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

void Save(const CommonArgs& args, const Calibration& calibration) {
  const SaveReport report =
      SaveCalibration(args.output, calibration, {.maps_as_exr = args.maps_as_exr, .overwrite_worse = args.overwrite_worse});
  if (!report.worse_than_existing.empty()) {
    std::printf("warning: replaced %s with a WORSE result (--overwrite-worse): %s\n", args.output.c_str(),
                report.worse_than_existing.c_str());
  }
  std::printf("wrote %s\n", args.output.c_str());
}

void RunIntrinsics(const std::string& images, const std::string& board_text, double square_m, bool k3,
                   const CommonArgs& args) {
  const BoardSpec board = ParseBoardSize(board_text, square_m, "--board");
  const DetectedViews detected = DetectBoardInFolder(images, board);
  for (const auto& [file, reason] : detected.rejected) std::printf("rejected %s: %s\n", file.c_str(), reason.c_str());
  std::printf("board found in %zu of %zu images\n", detected.views.size(),
              detected.views.size() + detected.rejected.size());
  IntrinsicsOptions options;
  options.model = k3 ? DistortionModel::kK1K2P1P2K3 : DistortionModel::kK1K2P1P2;
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
}

FrameDirectoryManifest ReadFrames(const std::string& dir, bool need_raw) {
  FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir);
  for (size_t i = 0; i < manifest.frames.size(); ++i) {
    const FrameRecord& r = manifest.frames[i];
    const std::string field = "frames[" + std::to_string(i) + "]";
    if (!r.T_B_H) throw InputError(dir + "/frames.json", field + ".T_B_H", "missing: every frame needs the robot's hand pose");
    if (need_raw ? r.raw.empty() : r.ir.empty()) {
      throw InputError(dir + "/frames.json", field + (need_raw ? ".raw" : ".ir"),
                       need_raw ? "missing: depth calibration needs raw depth of the plane"
                                : "missing: hand-eye calibration needs IR images of the board (projector off)");
    }
  }
  return manifest;
}

void RunHandEye(const std::string& frames, const std::string& board_text, double square_m, const CommonArgs& args) {
  const BoardSpec board = ParseBoardSize(board_text, square_m, "--board");
  if (!fs::exists(args.output)) {
    throw InputError(args.output, "", "no calibration file with intrinsics; run `romunect calibrate intrinsics` first");
  }
  Calibration calibration = LoadCalibration(args.output);
  const FrameDirectoryManifest manifest = ReadFrames(frames, false);
  if (manifest.camera.width != calibration.camera.width || manifest.camera.height != calibration.camera.height) {
    throw InputError(frames, "camera", "image size differs from the calibration's; use the same camera mode");
  }
  std::vector<HandEyeStation> stations;
  for (size_t i = 0; i < manifest.frames.size(); ++i) {
    const Frame frame = LoadFrame(frames, manifest, i);
    std::string reason;
    auto corners = DetectBoard(frame.ir, board, &reason);
    if (!corners) {
      std::printf("rejected frame %d: %s\n", frame.index, reason.c_str());
      continue;
    }
    stations.push_back({*frame.T_B_H, {"frame " + std::to_string(frame.index), std::move(*corners)}});
  }
  const HandEyeResult result = CalibrateHandEye(stations, calibration.camera, board);
  std::printf("%s\n", result.BriefReport().c_str());
  calibration.T_H_C = result.T_H_C;
  calibration.T_B_K = result.T_B_K;
  calibration.residuals.hand_eye_rms_px = result.rms_px;
  calibration.date.clear();
  Save(args, calibration);
}

void RunDepth(const std::string& frames, const std::string& model, const CommonArgs& args) {
  if (!fs::exists(args.output)) {
    throw InputError(args.output, "", "no calibration file; run intrinsics and hand-eye first");
  }
  Calibration calibration = LoadCalibration(args.output);
  if (calibration.residuals.hand_eye_rms_px < 0) {
    throw InputError(args.output, "T_H_C", "not calibrated yet; run `romunect calibrate hand-eye` first");
  }
  const FrameDirectoryManifest manifest = ReadFrames(frames, true);
  std::vector<PlaneCapture> captures;
  for (size_t i = 0; i < manifest.frames.size(); ++i) {
    const Frame frame = LoadFrame(frames, manifest, i);
    // The reference plane is the board's plane (z = 0 of K), placed by the hand-eye step.
    const Pose T_C_K = (*frame.T_B_H * calibration.T_H_C).inverse() * calibration.T_B_K;
    captures.push_back({frame.raw, T_C_K});
  }
  DepthCorrectionOptions options;
  options.chip = calibration.chip;  // the chip whose raw the file's correction reads
  const DepthCorrectionResult result = FitDepthCorrection(calibration.camera, captures, options);
  std::printf("%s\n", result.BriefReport().c_str());
  if (model == "exact") {
    calibration.depth = result.inverse;
    calibration.residuals.depth_rms_m = result.inverse_rms_m;
  } else {
    calibration.depth = result.affine;
    calibration.residuals.depth_rms_m = result.affine_rms_m;
  }
  calibration.date.clear();
  Save(args, calibration);
}

void AddCommon(CLI::App* cmd, CommonArgs* args) {
  cmd->add_option("--output", args->output, "Calibration file to write or update (cv::FileStorage YAML)");
  cmd->add_flag("--overwrite-worse", args->overwrite_worse,
                "Replace an existing file even when the new result is worse (says so)");
  cmd->add_flag("--maps-as-exr", args->maps_as_exr, "Write depth maps as EXR files beside the YAML");
}

}  // namespace

void AddCalibrateCommand(CLI::App& app) {
  auto* calibrate = app.add_subcommand("calibrate", "Calibrate the sensor: intrinsics, hand-eye, depth correction");
  calibrate->require_subcommand(1);

  struct IntrinsicsArgs {
    std::string images, board = "9x6";
    double square_m = 0.025;
    bool k3 = false;
    CommonArgs common;
  };
  auto in = std::make_shared<IntrinsicsArgs>();
  auto* intrinsics = calibrate->add_subcommand("intrinsics", "Zhang's method on a folder of checkerboard images");
  intrinsics->add_option("--images", in->images, "Folder of board images (png, jpg, bmp, tif)")->required();
  intrinsics->add_option("--board", in->board, "Inner corners, COLSxROWS (default 9x6)");
  intrinsics->add_option("--square", in->square_m, "Square edge in metres (default 0.025)");
  intrinsics->add_flag("--k3", in->k3, "Also estimate k3 (default: fixed at 0)");
  AddCommon(intrinsics, &in->common);
  intrinsics->callback([in] { RunIntrinsics(in->images, in->board, in->square_m, in->k3, in->common); });

  struct HandEyeArgs {
    std::string frames, board = "9x6";
    double square_m = 0.025;
    CommonArgs common;
  };
  auto he = std::make_shared<HandEyeArgs>();
  auto* hand_eye = calibrate->add_subcommand("hand-eye", "T_H_C from IR board views with T_B_H per frame");
  hand_eye->add_option("--frames", he->frames, "Frame directory (IR images, T_B_H per frame)")->required();
  hand_eye->add_option("--board", he->board, "Inner corners, COLSxROWS (default 9x6)");
  hand_eye->add_option("--square", he->square_m, "Square edge in metres (default 0.025)");
  AddCommon(hand_eye, &he->common);
  hand_eye->callback([he] { RunHandEye(he->frames, he->board, he->square_m, he->common); });

  struct DepthArgs {
    std::string frames, model = "exact";
    CommonArgs common;
  };
  auto de = std::make_shared<DepthArgs>();
  auto* depth = calibrate->add_subcommand("depth", "Per-pixel depth correction from raw depth of the board plane");
  depth->add_option("--frames", de->frames, "Frame directory (raw depth, T_B_H per frame)")->required();
  depth->add_option("--model", de->model, "exact (1/Z affine in raw) or affine (paper eq. 3)")
      ->check(CLI::IsMember({"exact", "affine"}));
  AddCommon(depth, &de->common);
  depth->callback([de] { RunDepth(de->frames, de->model, de->common); });
}

}  // namespace romunect::tools
