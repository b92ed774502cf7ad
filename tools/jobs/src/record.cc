#include "romunect/tools/jobs/record.h"

#include <unistd.h>

#include <csignal>
#include <cstdio>
#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <utility>

#include <nlohmann/json.hpp>

#include "romunect/calib/calibration_file.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/openni2/open_source.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/tools/jobs/output_folder.h"
#include "romunect/tools/jobs/run_folder.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;

volatile std::sig_atomic_t g_interrupted = 0;
void OnInterrupt(int) { g_interrupted = 1; }

void CheckSourceGiven(const std::string& source) {
  if (source.empty()) throw InputError("record", "SOURCE", "missing (a device URI, a .oni file or a frame directory)");
}

// frames.json's top-level "recording" (provenance) and "ps1080" (the chip's geometry, in the
// keys the virtual device reads back, so a recorded directory replays with the same chip).
std::string ExtraJson(const RecordOptions& o, FrameSource& source, const std::string& incomplete,
                      const std::string& depth_from) {
  // A copied frame directory keeps its unknown keys (its "ps1080" chip among them); "recording"
  // says where this copy came from.
  const FrameDirectorySource* directory = openni2::FindFrameDirectorySource(&source);
  nlohmann::json extra = directory != nullptr ? nlohmann::json::parse(directory->manifest().extra_json)
                                              : nlohmann::json::object();
  extra["recording"] = nlohmann::json::object();
  extra["recording"]["source"] = o.source;
  extra["recording"]["depth_from"] = depth_from;
  extra["recording"]["description"] = source.Describe();
  if (!incomplete.empty()) extra["recording"]["incomplete"] = incomplete;
  if (auto* device = openni2::FindOpenNI2Source(&source)) {
    const openni2::PS1080Properties& c = device->chip();
    extra["recording"]["depth_unit"] = o.raw ? "raw shift9.2" : openni2::ToString(device->depth_unit());
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

// What the capture reads: the source's options, and a calibration's depth model when it applies.
struct Capture {
  openni2::OpenSourceOptions options;
  std::optional<calib::Calibration> depth_model;
  bool depth_model_skipped = false;  // --device-depth with a calibration that has one
  bool from_directory = false;
};

Capture CaptureOptions(const RecordOptions& o) {
  if (o.pose_offset_given && o.pose_log.empty()) {
    throw InputError("--pose-offset", "", "applies with --pose-log: it shifts frame times onto the pose log's clock");
  }
  Capture c;
  c.options.pose_log = o.pose_log;
  c.options.pose.time_offset_s = o.pose_offset_s;
  openni2::OpenNI2SourceOptions& device = c.options.openni2;
  device.width = o.width;
  device.height = o.height;
  device.fps = o.fps;
  device.ir = !o.no_ir;
  device.raw = o.raw;
  device.timeout_s = o.timeout_s;
  device.max_frames = o.frames;
  device.record_oni = o.oni;
  if (o.depth_unit == "100um") device.depth_unit = openni2::DepthUnit::k100um;
  else if (o.depth_unit == "1mm") device.depth_unit = openni2::DepthUnit::k1mm;
  else if (!o.depth_unit.empty()) throw InputError("--depth-unit", "", "'" + o.depth_unit + "': expected 100um or 1mm");
  if (!o.camera.empty() && !o.calibration.empty()) {
    throw InputError("--camera", "", "give either --camera or --calibration (which holds a camera too)");
  }
  if (!o.camera.empty()) device.camera = CameraModel::Load(o.camera);
  c.from_directory = openni2::ClassifySource(o.source) == openni2::SourceKind::kFrameDirectory;
  // A calibration's depth model turns the device's raw shifts into the directory's metric depth,
  // as fuse does for a device: the device's own depth is the chip's, off on modified hardware.
  if (!o.calibration.empty()) {
    calib::Calibration calibration = calib::LoadDeviceCalibration(o.calibration);
    if (const std::string warning = calib::HandEyeWarning(calibration, o.calibration);
        !warning.empty() && !o.pose_log.empty()) {
      std::fprintf(stderr, "romunect: warning: %s\n", warning.c_str());
    }
    device.camera = calibration.camera;
    c.options.pose.T_H_C = calibration.T_H_C;  // with a pose log: T_W_C = T_B_H T_H_C (world = robot base)
    if (c.from_directory && calibration.depth) {
      std::fprintf(stderr,
                   "romunect: warning: %s: its depth model is not applied: a frame directory is copied with "
                   "its own depth\n",
                   o.calibration.c_str());
    }
    if (!c.from_directory && calibration.depth) {
      if (o.device_depth) {
        c.depth_model_skipped = true;
      } else {
        c.depth_model = std::move(calibration);  // its maps have the camera's size (LoadCalibration checks)
        device.raw = true;                       // the model reads the chip's raw shifts
      }
    }
  }
  return c;
}

// Refusals before the source opens: opening starts an .oni recording, which would already have
// replaced the file.
void CheckOutputs(const RecordOptions& o, bool from_directory) {
  if (from_directory) {
    // A frame directory is copied as it is: the device's stream options would be ignored.
    for (const auto& [given, option] : {std::pair{!o.oni.empty(), "--oni"}, std::pair{o.no_ir, "--no-ir"},
                                        std::pair{o.raw, "--raw"}, std::pair{!o.depth_unit.empty(), "--depth-unit"},
                                        std::pair{o.width != 0, "--width"}, std::pair{o.height != 0, "--height"},
                                        std::pair{o.fps != 0, "--fps"}, std::pair{o.device_depth, "--device-depth"}}) {
      if (given)
        throw InputError(option, "",
                         "only an OpenNI2 source (device or .oni file) takes it; a frame directory is copied as it is");
    }
  }
  CheckFolderCanBeCreated(o.out_dir, "OUT_DIR");
  FrameDirectoryWriter::CheckCanWrite(o.out_dir);
  // Another capture's files would mix with this one's (an unfinished one has no frames.json).
  if (std::error_code ec; fs::is_directory(o.out_dir, ec) && !fs::is_empty(o.out_dir, ec)) {
    throw InputError("OUT_DIR", "", o.out_dir + ": is not empty; give a new or empty folder");
  }
  if (o.oni.empty()) return;
  if (fs::exists(o.oni)) throw InputError(o.oni, "", "already exists; refusing to overwrite an earlier recording");
  if (fs::weakly_canonical(o.oni) == fs::weakly_canonical(o.out_dir)) {
    throw InputError("--oni", "", o.oni + ": is OUT_DIR; give the recording a file name of its own");
  }
  // OpenNI2 crashes when its recorder cannot create the file (a missing or read-only folder).
  const fs::path folder = fs::path(o.oni).has_parent_path() ? fs::path(o.oni).parent_path() : fs::path(".");
  if (std::error_code ec; !fs::is_directory(folder, ec) || ::access(folder.c_str(), W_OK | X_OK) != 0) {
    throw InputError("--oni", "",
                     o.oni + ": cannot be created: " + folder.string() +
                         " is not an existing folder this process may write in");
  }
}

std::string DepthFrom(const RecordOptions& o, const Capture& c) {
  if (c.depth_model) {
    return std::string("the calibration's depth model (") + DepthCorrectionModelName(c.depth_model->depth->model) +
           ") on the device's raw shifts (" + o.calibration + ")";
  }
  if (c.from_directory) return "the source directory's depth";
  return c.depth_model_skipped ? "the device's depth (--device-depth: the calibration's depth model not applied)"
                               : "the device's depth";
}

// The frames' camera: the device's (set from --camera or --calibration when given), and for a
// frame directory the given one in place of the directory's.
CameraModel FramesCamera(const RecordOptions& o, const Capture& c, const FrameSource& source) {
  const std::optional<CameraModel>& given = c.options.openni2.camera;
  if (!c.from_directory || !given) return source.camera();
  const CameraModel& camera = source.camera();
  if (given->width != camera.width || given->height != camera.height) {
    throw InputError(o.camera.empty() ? o.calibration : o.camera, "image_width/image_height",
                     std::to_string(given->width) + " x " + std::to_string(given->height) + ", the frames are " +
                         std::to_string(camera.width) + " x " + std::to_string(camera.height));
  }
  return *given;
}

// The options that decide the frames, by the name the user gives them: a resume must match.
nlohmann::json ArgsJson(const RecordOptions& o) {
  nlohmann::json a = nlohmann::json::object();
  a["SOURCE"] = o.source;
  a["--oni"] = o.oni;
  a["--frames"] = o.frames;
  a["--width"] = o.width;
  a["--height"] = o.height;
  a["--fps"] = o.fps;
  a["--depth-unit"] = o.depth_unit;
  a["--no-ir"] = o.no_ir;
  a["--compress-frames"] = o.compress_frames;
  a["--raw"] = o.raw;
  a["--device-depth"] = o.device_depth;
  a["--camera"] = o.camera;
  a["--calibration"] = o.calibration;
  a["--pose-log"] = o.pose_log;
  a["--pose-offset"] = o.pose_offset_given ? nlohmann::json(o.pose_offset_s) : nlohmann::json();
  return a;
}

// Before a resume takes the work folder: the source can be replayed, and the interrupted run had
// the same options (named when one differs).
void CheckResumable(const RecordOptions& o, const fs::path& work_dir) {
  if (openni2::ClassifySource(o.source) == openni2::SourceKind::kDevice) {
    throw InputError("--resume", "",
                     "a device cannot send again the frames it already sent; resume applies to a "
                     "frame directory or an .oni file as SOURCE");
  }
  if (!o.oni.empty()) throw InputError("--resume", "", "an interrupted --oni recording cannot be continued");
  if (std::error_code ec; !fs::is_directory(work_dir, ec)) {
    throw InputError(work_dir.string(), "",
                     "does not exist: there is no interrupted record to resume into " + o.out_dir +
                         "; run without --resume");
  }
  if (const auto changed = FindChangedOption(work_dir / kRecordArgsFile, ArgsJson(o).dump())) {
    throw InputError(changed->key, "",
                     "differs from the interrupted run's (" + changed->recorded + ", now " + changed->now +
                         "); resume with the same arguments or run without --resume");
  }
}

// The capture loop: until the source ends, --frames are written or Ctrl-C. Returns the skipped.
// A frame that cannot be written (a full disk) sets *write_failed before its InputError goes on.
// With --resume, leading frames whose files the interrupted run wrote are kept (counted in *reused).
int CaptureFrames(const RecordOptions& o, const Capture& c, FrameSource& source, FrameDirectoryWriter& writer,
                  bool* write_failed, size_t* reused) {
  bool reusing = o.resume;
  // A copied directory's entries keep their unknown keys, found by frame index.
  std::map<int, std::string> entry_extra;
  if (const FrameDirectorySource* d = openni2::FindFrameDirectorySource(&source)) {
    for (const FrameRecord& r : d->manifest().frames) entry_extra[r.index] = r.extra_json;
  }
  int skipped = 0;
  Frame frame;
  std::string error;
  while (!g_interrupted && (o.frames == 0 || static_cast<int>(writer.size()) < o.frames)) {
    const FrameStatus status = source.Next(&frame, &error);
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
    if (c.depth_model && !frame.raw.empty()) {
      frame.depth_m = ApplyDepthCorrection(*c.depth_model->depth, frame.raw, c.depth_model->chip);
    }
    const auto entry = entry_extra.find(frame.index);
    const std::string& extra = entry != entry_extra.end() ? entry->second : std::string("{}");
    if (reusing && writer.AddIfWritten(frame, extra)) {
      ++*reused;
      continue;
    }
    reusing = false;  // from the first frame not on disk on, every frame is written
    try {
      writer.Add(frame, extra);
    } catch (const InputError&) {
      *write_failed = true;
      throw;
    }
  }
  return skipped;
}

}  // namespace

RecordSummary Record(const RecordOptions& o) {
  CheckSourceGiven(o.source);
  if (o.out_dir.empty()) throw InputError("record", "OUT_DIR", "missing (the frame directory to write)");
  const Capture c = CaptureOptions(o);
  CheckFolderCanBeCreated(o.out_dir, "OUT_DIR");
  CheckOutputs(o, c.from_directory);
  // The frames go to OUT_DIR.incomplete, renamed to OUT_DIR when the directory is finished; a
  // second run into OUT_DIR is refused here, before the source opens.
  RunFolder run(o.out_dir, "OUT_DIR", "record");
  if (o.resume) {
    CheckResumable(o, run.work_dir());
    if (!run.Resume()) {  // gone meanwhile: the fresh folder goes with `run`
      throw InputError(run.work_dir().string(), "", "there is no interrupted record to resume; run without --resume");
    }
    std::error_code ec;  // a run killed between its frames.json and the rename: written again
    fs::remove(run.work_dir() / "frames.json", ec);
  } else {
    run.Begin();
  }
  WriteTextAtomically(run.work_dir() / kRecordArgsFile, ArgsJson(o).dump(1) + "\n");
  std::unique_ptr<FrameSource> source = openni2::OpenSource(o.source, c.options);
  const std::string depth_from = DepthFrom(o, c);
  // A live device delivers 30 frames a second: uncompressed files keep up (image_io.h).
  FrameDirectoryWriter writer(run.work_dir(), FramesCamera(o, c, *source),
                              o.compress_frames ? ImageCompression::kCompact : ImageCompression::kFast);
  // A frame directory's region carries over while its poses do (no pose log gives others).
  if (const FrameDirectorySource* d = openni2::FindFrameDirectorySource(source.get());
      d != nullptr && d->manifest().region_W && o.pose_log.empty()) {
    writer.SetRegion(*d->manifest().region_W);
  }
  std::printf("recording from %s\n", source->Describe().c_str());
  RecordSummary s;
  g_interrupted = 0;
  auto previous = std::signal(SIGINT, OnInterrupt);
  bool write_failed = false;
  try {
    s.skipped = CaptureFrames(o, c, *source, writer, &write_failed, &s.reused);
  } catch (const InputError& e) {
    std::signal(SIGINT, previous);
    // A frame that could not be written (a full disk): no frames.json claims the capture, and
    // the partial directory goes with the run (~RunFolder), freeing the disk.
    if (write_failed) {
      throw InputError(e.source(), e.field(),
                       e.problem() + "; no frame directory was written (the " + std::to_string(writer.size()) +
                           " frames written before are removed)");
    }
    // The device is gone: keep what arrived, say so in the directory, then report the error.
    writer.SetExtraJson(ExtraJson(o, *source, e.what(), depth_from));
    writer.Finish();
    fs::remove(run.work_dir() / kRecordArgsFile);
    run.Commit();
    std::fprintf(stderr, "romunect: kept %zu frames in %s\n", writer.size(), o.out_dir.c_str());
    throw;
  }
  std::signal(SIGINT, previous);
  if (auto* d = openni2::FindOpenNI2Source(source.get())) {
    d->FinishRecording();
    s.dropped = ", " + std::to_string(d->stats().dropped_frames) + " dropped by the device";
  }
  if (writer.size() == 0) {
    // No frame directory claims a capture that holds nothing: the run folder is not committed.
    throw InputError(o.source, "",
                     "recorded no frames (" + std::to_string(s.skipped) + " skipped" + s.dropped + "); " + o.out_dir +
                         " was not written" + (o.oni.empty() ? "" : "; the streams are in " + o.oni));
  }
  writer.SetExtraJson(ExtraJson(o, *source, g_interrupted ? "interrupted" : "", depth_from));
  writer.Finish();
  fs::remove(run.work_dir() / kRecordArgsFile);
  run.Commit();
  s.frames = writer.size();
  return s;
}

std::string RecordSummaryText(const RecordSummary& s, const RecordOptions& o) {
  const std::string reused = o.resume ? std::to_string(s.reused) + " reused from the interrupted run, " : std::string();
  return "recorded " + std::to_string(s.frames) + " frames (" + reused + std::to_string(s.skipped) + " skipped" +
         s.dropped + ") to " + o.out_dir + (o.oni.empty() ? "" : " and " + o.oni) + "\n";
}

std::string DeviceListText() {
  const auto devices = openni2::ListDevices();
  std::string text = "OpenNI2 drivers: " + openni2::DriverDirectory().string() + "\n";
  for (const auto& d : devices) text += d.uri + "  (" + d.vendor + " " + d.name + ")\n";
  if (devices.empty()) text += "no OpenNI2 devices found\n";
  return text;
}

std::string VideoModesText(const std::string& source) {
  CheckSourceGiven(source);
  if (openni2::ClassifySource(source) == openni2::SourceKind::kFrameDirectory) {
    throw InputError(source, "--list-modes", "only OpenNI2 devices have video modes");
  }
  const std::string uri = source.rfind("oni://", 0) == 0 ? source.substr(6) : source;
  std::string text;
  for (const std::string& m : openni2::ListVideoModes(uri)) text += m + "\n";
  return text;
}

}  // namespace romunect::jobs
