// romunect record SOURCE OUT_DIR: capture from an OpenNI2 device (real or virtual), a recording
// or a frame directory into a frame directory, optionally also into an .oni file. A device that
// stops mid-stream ends the capture with an error, and the frames up to then are kept.
#include <unistd.h>

#include <atomic>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include <nlohmann/json.hpp>
#include <opencv2/core.hpp>

#include "commands.h"
#include "romunect/jobs/output_folder.h"
#include "romunect/calib/calibration_file.h"
#include "romunect/openni2/open_source.h"
#include "romunect/openni2/openni2_source.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"

namespace romunect::tools {
namespace {
using jobs::CheckFolderCanBeCreated;
using jobs::OutputFolder;
namespace fs = std::filesystem;

volatile std::sig_atomic_t g_interrupted = 0;
void OnInterrupt(int) { g_interrupted = 1; }

struct RecordArgs {
  std::string source, out_dir, oni, camera, calibration, pose_log, depth_unit;
  int frames = 0, width = 0, height = 0, fps = 0;
  double timeout_s = 2.0, pose_offset_s = 0.0;
  bool no_ir = false, raw = false, list_devices = false, list_modes = false, compress_frames = false;
  bool device_depth = false;  // record the device's metric depth even with a depth model
  const CLI::Option* pose_offset_option = nullptr;  // to tell a given 0 from none
};

// frames.json's top-level "recording" (provenance) and "ps1080" (the chip's geometry, in the
// keys the virtual device reads back, so a recorded directory replays with the same chip).
std::string ExtraJson(const RecordArgs& args, FrameSource& source, const std::string& incomplete,
                      const std::string& depth_from) {
  // A copied frame directory keeps its unknown keys (its "ps1080" chip among them); "recording"
  // says where this copy came from.
  const FrameDirectorySource* directory = openni2::FindFrameDirectorySource(&source);
  nlohmann::json extra = directory != nullptr ? nlohmann::json::parse(directory->manifest().extra_json) : nlohmann::json::object();
  extra["recording"] = nlohmann::json::object();
  extra["recording"]["source"] = args.source;
  extra["recording"]["depth_from"] = depth_from;
  extra["recording"]["description"] = source.Describe();
  if (!incomplete.empty()) extra["recording"]["incomplete"] = incomplete;
  if (auto* device = openni2::FindOpenNI2Source(&source)) {
    const openni2::PS1080Properties& c = device->chip();
    extra["recording"]["depth_unit"] = args.raw ? "raw shift9.2" : openni2::ToString(device->depth_unit());
    nlohmann::json chip = nlohmann::json::object();
    if (c.zero_plane_distance_m) chip["zero_plane_distance_mm"] = std::llround(*c.zero_plane_distance_m * 1e3);
    if (c.zero_plane_pixel_size_m) chip["zero_plane_pixel_size_mm"] = *c.zero_plane_pixel_size_m * 1e3;
    if (c.emitter_camera_distance_m) chip["emitter_dcmos_distance_cm"] = *c.emitter_camera_distance_m * 1e2;
    if (c.depth_rgb_camera_distance_m) chip["dcmos_rcmos_distance_cm"] = *c.depth_rgb_camera_distance_m * 1e2;
    if (c.const_shift) chip["const_shift"] = *c.const_shift;
    if (c.param_coeff) chip["param_coeff"] = *c.param_coeff;
    if (c.shift_scale) chip["shift_scale"] = *c.shift_scale;
    if (c.max_shift) chip["max_shift"] = *c.max_shift;
    if (c.pixel_size_factor) chip["pixel_size_factor"] = *c.pixel_size_factor;
    if (!chip.empty()) extra["ps1080"] = chip;
  }
  return extra.dump();
}

void RunRecord(const RecordArgs& args) {
  if (args.list_devices) {
    const auto devices = openni2::ListDevices();
    std::printf("OpenNI2 drivers: %s\n", openni2::DriverDirectory().string().c_str());
    for (const auto& d : devices) std::printf("%s  (%s %s)\n", d.uri.c_str(), d.vendor.c_str(), d.name.c_str());
    if (devices.empty()) std::printf("no OpenNI2 devices found\n");
    return;
  }
  if (args.source.empty()) throw InputError("record", "SOURCE", "missing (a device URI, a .oni file or a frame directory)");
  if (args.list_modes) {
    if (openni2::ClassifySource(args.source) == openni2::SourceKind::kFrameDirectory) {
      throw InputError(args.source, "--list-modes", "only OpenNI2 devices have video modes");
    }
    std::string uri = args.source.rfind("oni://", 0) == 0 ? args.source.substr(6) : args.source;
    for (const std::string& m : openni2::ListVideoModes(uri)) std::printf("%s\n", m.c_str());
    return;
  }
  if (args.out_dir.empty()) throw InputError("record", "OUT_DIR", "missing (the frame directory to write)");

  if (args.pose_offset_option->count() > 0 && args.pose_log.empty()) {
    throw InputError("--pose-offset", "", "applies with --pose-log: it shifts frame times onto the pose log's clock");
  }
  openni2::OpenSourceOptions options;
  options.pose_log = args.pose_log;
  options.pose.time_offset_s = args.pose_offset_s;
  openni2::OpenNI2SourceOptions& device = options.openni2;
  device.width = args.width;
  device.height = args.height;
  device.fps = args.fps;
  device.ir = !args.no_ir;
  device.raw = args.raw;
  device.timeout_s = args.timeout_s;
  device.max_frames = args.frames;
  device.record_oni = args.oni;
  if (args.depth_unit == "100um") device.depth_unit = openni2::DepthUnit::k100um;
  else if (args.depth_unit == "1mm") device.depth_unit = openni2::DepthUnit::k1mm;
  else if (!args.depth_unit.empty()) throw InputError("--depth-unit", "", "'" + args.depth_unit + "': expected 100um or 1mm");
  if (!args.camera.empty() && !args.calibration.empty()) {
    throw InputError("--camera", "", "give either --camera or --calibration (which holds a camera too)");
  }
  if (!args.camera.empty()) device.camera = CameraModel::Load(args.camera);
  const bool from_directory = openni2::ClassifySource(args.source) == openni2::SourceKind::kFrameDirectory;
  // A calibration's depth model turns the device's raw shifts into the directory's metric depth,
  // as fuse does for a device: the device's own depth is the chip's, off on modified hardware.
  std::optional<calib::Calibration> depth_model;
  bool depth_model_skipped = false;  // --device-depth with a calibration that has one
  if (!args.calibration.empty()) {
    calib::Calibration calibration = calib::LoadDeviceCalibration(args.calibration);
    if (const std::string warning = calib::HandEyeWarning(calibration, args.calibration);
        !warning.empty() && !args.pose_log.empty()) {
      std::fprintf(stderr, "romunect: warning: %s\n", warning.c_str());
    }
    device.camera = calibration.camera;
    options.pose.T_H_C = calibration.T_H_C;  // with a pose log: T_W_C = T_B_H T_H_C (world = robot base)
    if (from_directory && calibration.depth) {
      std::fprintf(stderr, "romunect: warning: %s: its depth model is not applied: a frame directory is copied with "
                   "its own depth\n", args.calibration.c_str());
    }
    if (!from_directory && calibration.depth) {
      if (args.device_depth) {
        depth_model_skipped = true;
      } else {
        depth_model = std::move(calibration);  // its maps have the camera's size (LoadCalibration checks)
        device.raw = true;                     // the model reads the chip's raw shifts
      }
    }
  }
  if (from_directory) {
    // A frame directory is copied as it is: the device's stream options would be ignored.
    for (const auto& [given, option] : {std::pair{!args.oni.empty(), "--oni"}, std::pair{args.no_ir, "--no-ir"},
                                        std::pair{args.raw, "--raw"}, std::pair{!args.depth_unit.empty(), "--depth-unit"},
                                        std::pair{args.width != 0, "--width"}, std::pair{args.height != 0, "--height"},
                                        std::pair{args.fps != 0, "--fps"}, std::pair{args.device_depth, "--device-depth"}}) {
      if (given) throw InputError(option, "", "only an OpenNI2 source (device or .oni file) takes it; a frame directory is copied as it is");
    }
  }
  // Refusals before the source opens: opening starts an .oni recording, which would already
  // have replaced the file.
  CheckFolderCanBeCreated(args.out_dir, "OUT_DIR");
  FrameDirectoryWriter::CheckCanWrite(args.out_dir);
  // Another capture's files would mix with this one's (an unfinished one has no frames.json).
  if (std::error_code ec; fs::is_directory(args.out_dir, ec) && !fs::is_empty(args.out_dir, ec)) {
    throw InputError("OUT_DIR", "", args.out_dir + ": is not empty; give a new or empty folder");
  }
  if (!args.oni.empty()) {
    if (fs::exists(args.oni)) throw InputError(args.oni, "", "already exists; refusing to overwrite an earlier recording");
    if (fs::weakly_canonical(args.oni) == fs::weakly_canonical(args.out_dir)) {
      throw InputError("--oni", "", args.oni + ": is OUT_DIR; give the recording a file name of its own");
    }
    // OpenNI2 crashes when its recorder cannot create the file (a missing or read-only folder).
    const fs::path folder = fs::path(args.oni).has_parent_path() ? fs::path(args.oni).parent_path() : fs::path(".");
    if (std::error_code ec; !fs::is_directory(folder, ec) || ::access(folder.c_str(), W_OK | X_OK) != 0) {
      throw InputError("--oni", "", args.oni + ": cannot be created: " + folder.string() +
                                        " is not an existing folder this process may write in");
    }
  }

  const bool out_dir_existed = fs::exists(args.out_dir);
  std::unique_ptr<FrameSource> source = openni2::OpenSource(args.source, options);
  const std::string depth_from =
      depth_model ? std::string("the calibration's depth model (") + DepthCorrectionModelName(depth_model->depth->model) +
                        ") on the device's raw shifts (" + args.calibration + ")"
      : from_directory ? "the source directory's depth"
      : depth_model_skipped ? "the device's depth (--device-depth: the calibration's depth model not applied)"
                       : "the device's depth";
  // The frames' camera: the device's (set from --camera or --calibration when given), and for a
  // frame directory the given one in place of the directory's.
  CameraModel camera = source->camera();
  if (from_directory && device.camera) {
    if (device.camera->width != camera.width || device.camera->height != camera.height) {
      throw InputError(args.camera.empty() ? args.calibration : args.camera, "image_width/image_height",
                       std::to_string(device.camera->width) + " x " + std::to_string(device.camera->height) +
                           ", the frames are " + std::to_string(camera.width) + " x " + std::to_string(camera.height));
    }
    camera = *device.camera;
  }
  // A live device delivers 30 frames a second: uncompressed files keep up (image_io.h).
  FrameDirectoryWriter writer(args.out_dir, camera,
                              args.compress_frames ? ImageCompression::kCompact : ImageCompression::kFast);
  // A frame directory's region carries over while its poses do (no pose log gives others).
  if (const FrameDirectorySource* d = openni2::FindFrameDirectorySource(source.get());
      d != nullptr && d->manifest().region_W && args.pose_log.empty()) {
    writer.SetRegion(*d->manifest().region_W);
  }
  std::printf("recording from %s\n", source->Describe().c_str());

  // A copied directory's entries keep their unknown keys, found by frame index.
  std::map<int, std::string> entry_extra;
  if (const FrameDirectorySource* d = openni2::FindFrameDirectorySource(source.get())) {
    for (const FrameRecord& r : d->manifest().frames) entry_extra[r.index] = r.extra_json;
  }
  g_interrupted = 0;
  auto previous = std::signal(SIGINT, OnInterrupt);
  int skipped = 0;
  Frame frame;
  std::string error;
  try {
    while (!g_interrupted && (args.frames == 0 || static_cast<int>(writer.size()) < args.frames)) {
      const FrameStatus status = source->Next(&frame, &error);
      if (status == FrameStatus::kEndOfStream) break;
      if (status == FrameStatus::kBadFrame) {
        ++skipped;
        std::fprintf(stderr, "romunect: warning: frame skipped: %s\n", error.c_str());
        continue;
      }
      if (frame.depth_m.empty() && frame.raw.empty()) {
        ++skipped;
        std::fprintf(stderr, "romunect: warning: frame %d has no depth, skipped\n", frame.index);
        continue;
      }
      if (depth_model && !frame.raw.empty()) {
        frame.depth_m = ApplyDepthCorrection(*depth_model->depth, frame.raw, depth_model->chip);
      }
      const auto entry = entry_extra.find(frame.index);
      writer.Add(frame, entry != entry_extra.end() ? entry->second : "{}");
    }
  } catch (const InputError& e) {
    // The device is gone: keep what arrived, say so in the directory, then report the error.
    std::signal(SIGINT, previous);
    writer.SetExtraJson(ExtraJson(args, *source, e.what(), depth_from));
    writer.Finish();
    std::fprintf(stderr, "romunect: kept %zu frames in %s\n", writer.size(), args.out_dir.c_str());
    throw;
  }
  std::signal(SIGINT, previous);
  std::string dropped;
  if (auto* d = openni2::FindOpenNI2Source(source.get())) {
    d->FinishRecording();
    dropped = ", " + std::to_string(d->stats().dropped_frames) + " dropped by the device";
  }
  if (writer.size() == 0) {
    // No frame directory claims a capture that holds nothing; a folder this run made is removed.
    std::error_code ec;
    if (!out_dir_existed) fs::remove(args.out_dir, ec);
    throw InputError(args.source, "", "recorded no frames (" + std::to_string(skipped) + " skipped" + dropped +
                                          "); " + args.out_dir + " was not written" +
                                          (args.oni.empty() ? "" : "; the streams are in " + args.oni));
  }
  writer.SetExtraJson(ExtraJson(args, *source, g_interrupted ? "interrupted" : "", depth_from));
  writer.Finish();
  std::printf("recorded %zu frames (%d skipped%s) to %s%s\n", writer.size(), skipped, dropped.c_str(),
              args.out_dir.c_str(), args.oni.empty() ? "" : (" and " + args.oni).c_str());
}

}  // namespace

void AddRecordCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "record",
      "Capture from an OpenNI2 device, an .oni recording or a frame directory into a frame directory "
      "(and optionally an .oni file)");
  auto args = std::make_shared<RecordArgs>();
  cmd->add_option("SOURCE", args->source,
                  "oni:// (first device) | oni://URI | romunect:DIR[?pace=step&...] (virtual device) | FILE.oni | DIR");
  cmd->add_option("OUT_DIR", args->out_dir, "Frame directory to write (must not hold frames.json yet)");
  cmd->add_option("--oni", args->oni, "Also record the streams, lossless, to this .oni file");
  cmd->add_option("--frames", args->frames, "Stop after this many frames (0 = until the stream ends or Ctrl-C)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--timeout", args->timeout_s, "Seconds without a frame before the device counts as gone")->check(CLI::PositiveNumber);
  cmd->add_option("--width", args->width, "Video mode width (default 640 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--height", args->height, "Video mode height (default 480 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--fps", args->fps, "Video mode rate (default 30 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--depth-unit", args->depth_unit, "Depth on the wire: 100um (default when offered) or 1mm");
  cmd->add_flag("--no-ir", args->no_ir, "Do not open the IR stream");
  cmd->add_flag("--compress-frames", args->compress_frames,
                "Compress the frame files (PNG, EXR ZIP: 2-5x smaller, ~50 ms of CPU per frame)");
  cmd->add_flag("--raw", args->raw,
                "Record the chip's raw 11-bit shifts (PS1080 shift9.2, frames' raw images) instead of metric depth");
  cmd->add_flag("--device-depth", args->device_depth,
                "Record the device's metric depth, not the calibration's depth model applied to raw shifts");
  cmd->add_option("--camera", args->camera, "Camera model (OpenCV YAML/JSON) of the frames; default: from the fields of view");
  cmd->add_option("--calibration", args->calibration,
                  "romunect calibration file: its camera replaces the fields-of-view camera, and with --pose-log its "
                  "T_H_C gives every frame T_W_C (world = robot base), so `fuse` can use the directory");
  cmd->add_option("--pose-log", args->pose_log, "CSV pose log of T_B_H (time_s,x_m,y_m,z_m,qw,qx,qy,qz)");
  args->pose_offset_option =
      cmd->add_option("--pose-offset", args->pose_offset_s, "With --pose-log: seconds added to frame times to get pose-log times");
  cmd->add_flag("--list-devices", args->list_devices, "List the OpenNI2 devices and exit");
  cmd->add_flag("--list-modes", args->list_modes, "List the video modes of SOURCE and exit");
  cmd->callback([args] { RunRecord(*args); });
}

}  // namespace romunect::tools
