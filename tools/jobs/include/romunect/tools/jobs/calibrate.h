// `romunect calibrate`: the calibration chain (calib/chain.h).
// - CalibrateInTheLoop: the whole chain with the simulated rig (sim/calibration_rig.h), writing
//   DIR/calibration.yaml, DIR/report.json, DIR/report.md and its plots, with every error against
//   the rig's ground truth and the goals the chain is held to.
// - The steps alone, on recorded input, each updating one calibration file
//   (calib/calibration_file.h): intrinsics from a folder of board images; hand-eye from IR
//   images of the board with T_B_H per frame; depth from raw depth of the reference plane (the
//   board's plane z = 0 of K). Frame sources are what OpenSource opens (a frame directory, an
//   .oni file, a device URI); T_B_H comes from frames.json or a pose log.
// Progress and each step's findings go to stdout.
#pragma once

#include <filesystem>
#include <string>

#include "romunect/calib/calibration_file.h"

namespace romunect::jobs {

// The calibration file a step updates.
struct CalibrationFileOptions {
  std::string output = "calibration.yaml";
  bool overwrite_worse = false;
  bool maps_as_exr = false;
};

// Where the hand-eye and depth steps take T_B_H from when the frames do not carry it.
struct PoseLogOptions {
  std::string log;        // CSV pose log of T_B_H; empty: the frames' own (frames.json)
  double offset_s = 0.0;  // added to frame times to get pose-log times
  bool offset_given = false;
};

struct IntrinsicsStepOptions {
  std::string images, board = "9x6";
  double square_m = 0.025;
  bool k3 = false;
  CalibrationFileOptions file;
};

// Hand-eye input is either `frames` (a frame source with T_B_H per frame, or --poses LOG by
// time) or `images` with `poses.log` (a folder of board images of any bit depth, paired in name
// order with a pose file: 16 numbers per line, row-major, or the CSV pose log; counts must match).
struct HandEyeStepOptions {
  std::string frames, images, board = "9x6";
  PoseLogOptions poses;
  std::string pose_units = "m";            // m or mm: the translations of the poses
  std::string poses_are = "hand-in-base";  // or base-in-hand (T_H_B: inverted on reading)
  double square_m = 0.025;
  std::string intrinsics;          // calibration file with the camera; empty: file.output
  bool refine_intrinsics = false;  // refine the camera with the robot's motion
  CalibrationFileOptions file;
};

struct DepthStepOptions {
  std::string frames, model = "exact";  // exact (1/Z affine in raw) or affine (paper eq. 3)
  PoseLogOptions poses;
  CalibrationFileOptions file;
};

// Each step returns the calibration it saved. The hand-eye step refuses (InputError, nothing
// written) a fit whose RMS exceeds max(1 px, 5 x the intrinsics' RMS), naming the likely cause.
calib::Calibration RunIntrinsicsStep(const IntrinsicsStepOptions& options);
calib::Calibration RunHandEyeStep(const HandEyeStepOptions& options);
calib::Calibration RunDepthStep(const DepthStepOptions& options);

struct InTheLoopOptions {
  std::string out = "calibration";
  std::string rig = "romunect";
  unsigned seed = 1;
  int views = 20, stations = 15, planes = 12;
  int board_samples = 3;
  int threads = 2;
  bool overwrite_worse = false;
  // The rig's nominal errors (CAD mount, plate placement, projector, datasheet focal length and
  // principal point) scaled by this: 0 = nominal values exact, 1 = the rig's defaults.
  double nominal_errors = 1.0;
  // When set: the captures as inputs of the single steps, re-runnable with `calibrate
  // intrinsics|hand-eye|depth`: DIR/intrinsics/ (board images), DIR/hand_eye/ and DIR/depth/
  // (frame directories with T_B_H per frame).
  std::string save_captures;
};

struct InTheLoopSummary {
  std::filesystem::path out, calibration_file;
  std::string goals_table;  // Markdown: each goal, the value against ground truth, met or not
  bool all_met = false;
};

// Validates the options and the existing-file rules first (InputError), runs the chain, compares
// with ground truth and writes the calibration and the reports into options.out.
InTheLoopSummary CalibrateInTheLoop(const InTheLoopOptions& options);

// The goals table and where the files are, for the terminal.
std::string InTheLoopSummaryText(const InTheLoopSummary& summary);

}  // namespace romunect::jobs
