// `romunect record SOURCE OUT_DIR`: capture from an OpenNI2 device (real or virtual), a
// recording or a frame directory into a frame directory, optionally also into an .oni file. A
// device that stops mid-stream ends the capture with an error, and the frames up to then are
// kept. Ctrl-C ends a capture early and keeps it (frames.json says "interrupted").
#pragma once

#include <cstddef>
#include <string>

namespace romunect::jobs {

struct RecordOptions {
  std::string source, out_dir, oni, camera, calibration, pose_log, depth_unit;
  int frames = 0, width = 0, height = 0, fps = 0;  // 0: until the end / the device's default
  double timeout_s = 2.0, pose_offset_s = 0.0;
  bool no_ir = false, raw = false, compress_frames = false;
  bool device_depth = false;       // record the device's metric depth even with a depth model
  bool pose_offset_given = false;  // to tell a given 0 from none
  // Continue the capture an interrupted run left in OUT_DIR.incomplete: its source (a frame
  // directory or an .oni file) is replayed with the same options, and frames whose files are
  // already there and equal are kept instead of written again.
  bool resume = false;
};

struct RecordSummary {
  size_t frames = 0;
  int skipped = 0;
  size_t reused = 0;    // with resume: frames an interrupted run had already written
  std::string dropped;  // ", N dropped by the device" for a device, else ""
};

// The options a capture was started with, in the work folder, so that a resume can check them.
constexpr const char* kRecordArgsFile = ".romunect-record-args.json";

// Validates the options (InputError naming the option or file; refusals before the source
// opens, which would start an .oni recording), records and finishes the frame directory.
RecordSummary Record(const RecordOptions& options);

// "recorded N frames (...) to OUT_DIR[ and FILE.oni]".
std::string RecordSummaryText(const RecordSummary& summary, const RecordOptions& options);

// The OpenNI2 devices, and the video modes of `source` (a device or an .oni file), as lines.
std::string DeviceListText();
std::string VideoModesText(const std::string& source);

}  // namespace romunect::jobs
