// romunect calibrate: the calibration chain (jobs/calibrate.h).
//   calibrate [--out DIR] [--seed N] [--rig NAME|FILE] [--views N] [--stations N] [--planes N]
//             [--nominal-errors SCALE] [--save-captures DIR]
//       no step named: the whole chain in the loop with the simulated rig.
//   calibrate intrinsics --images DIR --board 9x6 --square 0.025 [--output FILE]
//   calibrate hand-eye   --frames SOURCE [--poses LOG [--pose-offset S]] | --images DIR --poses FILE
//       [--pose-units m|mm] [--poses-are hand-in-base|base-in-hand] [--intrinsics FILE] [--refine-intrinsics]
//       --board 9x6 --square 0.025 [--output FILE]
//   calibrate depth      --frames SOURCE [--poses LOG [--pose-offset S]] [--output FILE] [--model exact|affine]
#include <cstdio>
#include <memory>
#include <string>

#include "commands.h"
#include "romunect/calib/chain.h"
#include "romunect/tools/jobs/calibrate.h"

namespace romunect::tools {
namespace {

void AddFileOptions(CLI::App* cmd, jobs::CalibrationFileOptions* o) {
  cmd->add_option("--output", o->output, "Calibration file to write or update (cv::FileStorage YAML)");
  cmd->add_flag("--overwrite-worse", o->overwrite_worse,
                "Replace an existing file even when the new result is worse (says so)");
  cmd->add_flag("--maps-as-exr", o->maps_as_exr, "Write depth maps as EXR files beside the YAML");
}

// --poses and --pose-offset; the returned option tells a given offset of 0 from none.
CLI::Option* AddPoseOptions(CLI::App* cmd, jobs::PoseLogOptions* o,
                            const std::string& help = "CSV pose log of T_B_H, for an .oni file or a device") {
  cmd->add_option("--poses", o->log, help);
  return cmd->add_option("--pose-offset", o->offset_s,
                         "With --poses: seconds added to frame times to get pose-log times");
}

}  // namespace

void AddCalibrateCommand(CLI::App& app) {
  auto* calibrate = app.add_subcommand("calibrate", "Calibrate the sensor: intrinsics, hand-eye, depth correction");
  calibrate->require_subcommand(0, 1);
  auto loop = std::make_shared<jobs::InTheLoopOptions>();
  calibrate->add_option("--out", loop->out,
                        "No step named: output folder of the in-the-loop run (default calibration)");
  calibrate->add_option("--seed", loop->seed, "Seed of the simulated rig's nominal errors, noise and view jitter");
  calibrate->add_option("--rig", loop->rig, "Rig preset (romunect, kinect-v1) or rig JSON file (default romunect)");
  // The printed ranges are the validator's (calib::ChainOptions::Problem).
  const calib::ChainOptions chain;
  calibrate->add_option("--views", loop->views, "Board views for the intrinsics (default 20)")
      ->check(CLI::Range(chain.MinViews(), 200));
  calibrate->add_option("--stations", loop->stations, "Hand-eye stations (default 15)")->check(CLI::Range(3, 200));
  calibrate->add_option("--planes", loop->planes, "Reference-plane captures for the depth step (default 12)")
      ->check(CLI::Range(chain.MinPlanes(), 200));
  calibrate->add_option("--board-samples", loop->board_samples, "Sub-pixel samples per axis for board images (odd)");
  calibrate->add_option("--threads", loop->threads, "Simulation threads (default 2)")->check(CLI::Range(1, 64));
  calibrate->add_flag("--overwrite-worse", loop->overwrite_worse, "Replace an existing file even when worse");
  calibrate->add_option("--nominal-errors", loop->nominal_errors,
                        "Scale of the rig's nominal errors (mount, plate, projector, focal length, principal point): "
                        "0 = exact nominal values, 1 = default");
  calibrate->add_option("--save-captures", loop->save_captures,
                        "Also save the captures as the single steps' input: DIR/intrinsics (images), DIR/hand_eye and "
                        "DIR/depth (frame directories with T_B_H)");
  calibrate->callback([calibrate, loop] {
    if (calibrate->get_subcommands().empty()) {
      std::printf("%s", jobs::InTheLoopSummaryText(jobs::CalibrateInTheLoop(*loop)).c_str());
    }
  });

  auto in = std::make_shared<jobs::IntrinsicsStepOptions>();
  auto* intrinsics = calibrate->add_subcommand("intrinsics", "Zhang's method on a folder of checkerboard images");
  intrinsics->add_option("--images", in->images, "Folder of board images (png, jpg, bmp, tif)")->required();
  intrinsics->add_option("--board", in->board, "Inner corners, COLSxROWS (default 9x6)");
  intrinsics->add_option("--square", in->square_m, "Square edge in metres (default 0.025)");
  intrinsics->add_flag("--k3", in->k3, "Also estimate k3 (default: fixed at 0)");
  AddFileOptions(intrinsics, &in->file);
  intrinsics->callback([in] { jobs::RunIntrinsicsStep(*in); });

  auto he = std::make_shared<jobs::HandEyeStepOptions>();
  auto* hand_eye = calibrate->add_subcommand("hand-eye", "T_H_C from board views with the robot's hand pose for each");
  hand_eye->add_option("--frames", he->frames, "Frame directory, .oni file or device URI (IR images of the board)");
  hand_eye->add_option("--images", he->images,
                       "Folder of board images (any bit depth), paired in name order with --poses FILE");
  auto* he_offset = AddPoseOptions(hand_eye, &he->poses,
                                   "With --frames: CSV pose log of T_B_H by time; with --images: one pose per image "
                                   "(16 numbers per line, row-major, or the CSV pose log)");
  hand_eye->add_option("--pose-units", he->pose_units, "Units of the poses' translations: m or mm (default m)")
      ->check(CLI::IsMember({"m", "mm"}));
  hand_eye
      ->add_option("--poses-are", he->poses_are,
                   "hand-in-base (T_B_H, default) or base-in-hand (T_H_B: inverted on reading)")
      ->check(CLI::IsMember({"hand-in-base", "base-in-hand"}));
  hand_eye->add_option("--board", he->board, "Inner corners, COLSxROWS (default 9x6)");
  hand_eye->add_option("--square", he->square_m, "Square edge in metres (default 0.025)");
  hand_eye->add_option("--intrinsics", he->intrinsics, "Calibration file with the camera (default: --output)");
  hand_eye->add_flag("--refine-intrinsics", he->refine_intrinsics,
                     "Refine the camera with the robot's known motion (pins the focal length down)");
  AddFileOptions(hand_eye, &he->file);
  hand_eye->callback([he, he_offset] {
    he->poses.offset_given = he_offset->count() > 0;
    jobs::RunHandEyeStep(*he);
  });

  auto de = std::make_shared<jobs::DepthStepOptions>();
  auto* depth = calibrate->add_subcommand("depth", "Per-pixel depth correction from raw depth of the board plane");
  depth->add_option("--frames", de->frames, "Frame directory, .oni file or device URI (raw depth of the plane)")
      ->required();
  auto* de_offset = AddPoseOptions(depth, &de->poses);
  depth->add_option("--model", de->model, "exact (1/Z affine in raw) or affine (paper eq. 3)")
      ->check(CLI::IsMember({"exact", "affine"}));
  AddFileOptions(depth, &de->file);
  depth->callback([de, de_offset] {
    de->poses.offset_given = de_offset->count() > 0;
    jobs::RunDepthStep(*de);
  });
}

}  // namespace romunect::tools
