// romunect fuse SOURCE: fuses a frame directory, an .oni recording or a live OpenNI2 device into
// one height map (jobs/fuse.h). Arguments -> FuseOptions -> RunFuse -> summary.
#include <cstdio>
#include <memory>

#include "commands.h"
#include "romunect/tools/jobs/fuse.h"

namespace romunect::tools {

void AddFuseCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand(
      "fuse",
      "Fuse the depth maps of a frame directory, an .oni recording or a live OpenNI2 device into one height map");
  auto o = std::make_shared<jobs::FuseOptions>();
  cmd->add_option("SOURCE", o->source,
                  "Frame directory (frames.json with depth and T_W_C per frame), FILE.oni, oni://[URI] or "
                  "romunect:DIR[?...] (the last three with --poses and --calibration)")
      ->required();
  cmd->add_option("--out", o->out, "Output folder (default: SOURCE_fused beside a directory or .oni file)");
  cmd->add_option("--gt", o->gt, "Ground-truth height map (EXR, same box and voxel) for RMSE/MAE");
  auto* box =
      cmd->add_option("--box", o->box,
                      "Fusion box in world metres: xmin,ymin,zmin,xmax,ymax,zmax (default: the frame directory's "
                      "region_W, as romunect scan records it, else -0.075,-0.04,-0.004,0.075,0.04,0.06)");
  cmd->add_option("--voxel", o->voxel_m, "Voxel size in metres (default 0.00025)");
  cmd->add_option("--threads", o->threads, "Insertion threads (default 1)");
  cmd->add_option("--perturb", o->perturb,
                  "Inject calibration errors into the poses, camera and depth fused: NAME=VALUE[,...] with "
                  "hand_eye_deg[_x|_y|_z], hand_eye_mm[_x|_y|_z], focal_pct, principal_px[_x|_y], depth_scale_pct, "
                  "depth_offset_mm (docs/calibrate.md)");
  cmd->add_option("--max-memory-mb", o->max_memory_mb, "Refuse grids larger than this (default 16384)");
  cmd->add_option("--poses,--pose-log", o->poses,
                  ".oni/device: CSV pose log of T_B_H (time_s,x_m,y_m,z_m,qw,qx,qy,qz; docs/hardware.md)");
  auto* pose_offset = cmd->add_option("--pose-offset", o->pose_offset_s,
                                      ".oni/device: seconds added to frame times to get pose-log times");
  cmd->add_option("--calibration", o->calibration,
                  ".oni/device: romunect calibration file: T_H_C turns flange poses into camera poses (world = robot "
                  "base), and its camera is the frames' camera. Frame directory: its depth model applied to the "
                  "frames' raw images (the directory's camera and poses stay)");
  cmd->add_option("--camera", o->camera, ".oni/device: camera model (OpenCV YAML/JSON) replacing the calibration's");
  cmd->add_flag("--device-depth", o->device_depth,
                ".oni/device: fuse the device's metric depth, not the calibration's depth model applied to raw shifts");
  auto* timeout = cmd->add_option("--timeout", o->timeout_s,
                                  ".oni/device: seconds without a frame before the device counts as gone (default 2)")
                      ->check(CLI::PositiveNumber);
  cmd->callback([o, box, pose_offset, timeout] {
    o->box_given = box->count() > 0;  // --box "" is a bad box, not the default
    o->pose_offset_given = pose_offset->count() > 0;
    o->timeout_given = timeout->count() > 0;
    const jobs::FuseJobSummary summary = jobs::RunFuse(*o);
    std::printf("%s", jobs::FuseSummaryText(summary).c_str());
    std::fflush(stdout);
    jobs::CheckSourceEnded(summary, *o);  // non-zero exit after the outputs of a source that stopped
  });
}

}  // namespace romunect::tools
