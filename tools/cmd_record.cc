// romunect record SOURCE OUT_DIR: capture into a frame directory (jobs/record.h).
// Arguments -> RecordOptions -> Record -> summary; --list-devices and --list-modes list and exit.
#include <cstdio>
#include <memory>
#include <string>

#include "commands.h"
#include "romunect/tools/jobs/record.h"

namespace romunect::tools {

void AddRecordCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "record", "Capture from an OpenNI2 device, an .oni recording or a frame directory into a frame directory "
                "(and optionally an .oni file)");
  auto o = std::make_shared<jobs::RecordOptions>();
  cmd->add_option("SOURCE", o->source,
                  "oni:// (first device) | oni://URI | romunect:DIR[?pace=step&...] (virtual device) | FILE.oni | DIR");
  cmd->add_option("OUT_DIR", o->out_dir, "Frame directory to write (must not hold frames.json yet)");
  cmd->add_option("--oni", o->oni, "Also record the streams, lossless, to this .oni file");
  cmd->add_option("--frames", o->frames, "Stop after this many frames (0 = until the stream ends or Ctrl-C)")
      ->check(CLI::NonNegativeNumber);
  cmd->add_option("--timeout", o->timeout_s, "Seconds without a frame before the device counts as gone")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--width", o->width, "Video mode width (default 640 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--height", o->height, "Video mode height (default 480 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--fps", o->fps, "Video mode rate (default 30 when offered)")->check(CLI::NonNegativeNumber);
  cmd->add_option("--depth-unit", o->depth_unit, "Depth on the wire: 100um (default when offered) or 1mm");
  cmd->add_flag("--no-ir", o->no_ir, "Do not open the IR stream");
  cmd->add_flag("--compress-frames", o->compress_frames,
                "Compress the frame files (PNG, EXR ZIP: 2-5x smaller, ~50 ms of CPU per frame)");
  cmd->add_flag("--raw", o->raw,
                "Record the chip's raw 11-bit shifts (PS1080 shift9.2, frames' raw images) instead of metric depth");
  cmd->add_flag("--device-depth", o->device_depth,
                "Record the device's metric depth, not the calibration's depth model applied to raw shifts");
  cmd->add_option("--camera", o->camera,
                  "Camera model (OpenCV YAML/JSON) of the frames; default: from the fields of view");
  cmd->add_option("--calibration", o->calibration,
                  "romunect calibration file: its camera replaces the fields-of-view camera, and with --pose-log its "
                  "T_H_C gives every frame T_W_C (world = robot base), so `fuse` can use the directory");
  cmd->add_option("--pose-log", o->pose_log, "CSV pose log of T_B_H (time_s,x_m,y_m,z_m,qw,qx,qy,qz)");
  auto* pose_offset = cmd->add_option("--pose-offset", o->pose_offset_s,
                                      "With --pose-log: seconds added to frame times to get pose-log times");
  cmd->add_flag("--resume", o->resume,
                "Continue the capture an interrupted run left in OUT_DIR.incomplete (SOURCE a frame directory or .oni "
                "file, same arguments): frames already written are kept, the result is the same as one whole run");
  auto list_devices = std::make_shared<bool>(false), list_modes = std::make_shared<bool>(false);
  cmd->add_flag("--list-devices", *list_devices, "List the OpenNI2 devices and exit");
  cmd->add_flag("--list-modes", *list_modes, "List the video modes of SOURCE and exit");
  cmd->callback([o, pose_offset, list_devices, list_modes] {
    o->pose_offset_given = pose_offset->count() > 0;
    const std::string text = *list_devices ? jobs::DeviceListText()
                             : *list_modes ? jobs::VideoModesText(o->source)
                                           : jobs::RecordSummaryText(jobs::Record(*o), *o);
    std::printf("%s", text.c_str());
  });
}

}  // namespace romunect::tools
