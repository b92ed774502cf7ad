// Hand-eye on data from outside (a folder of board images and a robot's pose file): the checks
// that keep a wrong input from becoming a calibration file. The fit (hand_eye.h) is followed by
// per-station residuals, outlier stations dropped once (as the chain in the loop does), and a
// limit on the RMS relative to what the camera alone reaches on the same corners. A refused fit
// is refitted with the usual mistakes undone (poses in millimetres read as metres or the other
// way, inverted poses, images paired one pose off, another square size) and the alternative that
// fits is named. Frames: B base, H hand (flange), C camera, K board.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "romunect/calib/board.h"
#include "romunect/calib/hand_eye.h"
#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib {

// The observations in capture order: the robot's pose i and the board found in image i (none
// where the board was not found). Pairing by index is what a shifted pairing breaks.
struct HandEyeCaptures {
  std::vector<Pose> T_B_H;
  std::vector<std::optional<BoardView>> views;  // same size as T_B_H
  std::vector<HandEyeStation> Stations() const;
};

struct HandEyeCheckOptions {
  HandEyeOptions hand_eye;
  // The camera's own reprojection RMS on its board views (the intrinsics step's); < 0 unknown.
  // The same corners through the robot's poses reach little more when poses and images agree.
  double intrinsics_rms_px = -1.0;
  double min_limit_px = 1.0;  // the limit is max(min_limit_px, limit_factor * intrinsics_rms_px)
  double limit_factor = 5.0;
  double outlier_factor = 3.0;  // stations above this times the median station RMS are dropped
  double LimitPx() const;
};

// One refit with a usual mistake undone, tried when the fit is refused.
enum class HandEyeMistake {
  kPosesInMillimetres,  // translations read as metres were millimetres (refit: / 1000)
  kPosesInMetres,       // translations read as millimetres were metres (refit: x 1000)
  kInvertedPoses,       // the poses are T_H_B, base in hand (refit: inverted)
  kPairedOneLate,       // image i belongs to pose i + 1 (refit: shifted)
  kPairedOneEarly,      // image i belongs to pose i - 1
  kSquareSize,          // the board's squares have another size (refit: square_m searched)
};
struct HandEyeAlternative {
  HandEyeMistake mistake = HandEyeMistake::kPosesInMillimetres;
  std::string description;  // what the refit assumed, for the message
  double square_m = 0.0;    // kSquareSize: the square edge that fits best
  double rms_px = -1.0;     // the refit's corner RMS; < 0 when the refit had no solution
  bool fits = false;        // rms_px within the limit
};

struct CheckedHandEye {
  HandEyeResult fit;                                    // of the kept stations
  std::vector<HandEyeStation> used;                     // the kept stations
  std::vector<double> station_rms_px;                   // per kept station, through `fit`
  std::vector<std::pair<std::string, double>> dropped;  // outlier stations: (name, RMS px)
  double limit_px = 0.0;
  bool accepted = false;
  // When refused: the likely cause (the best alternative that fits) or that none explains it.
  std::string cause;
  std::vector<HandEyeAlternative> alternatives;  // tried only when refused
  std::string StationTable() const;              // one line per station: name, RMS px, kept or dropped
};

// Corner reprojection RMS (px) of each station through a fit (its camera, T_H_C, T_B_K); a
// corner behind the camera counts 1000 px.
std::vector<double> HandEyeStationRmsPx(const std::vector<HandEyeStation>& stations, const HandEyeResult& fit,
                                        const BoardSpec& board);

// Fits, drops outliers, checks the limit and, when refused, tries the alternatives. Throws
// InputError (source "hand-eye") as CalibrateHandEye does for unusable input (too few stations,
// degenerate motion); a refused fit is returned with accepted = false, never thrown.
CheckedHandEye CalibrateHandEyeChecked(const HandEyeCaptures& captures, const CameraModel& camera,
                                       const BoardSpec& board, const HandEyeCheckOptions& options = {});

// The relative change of the focal length when the robot's motion refines the camera: a large
// one says the intrinsics' views constrained the focal length weakly (too little tilt or depth
// spread). fit must come from refine_intrinsics. Positive: the refit's focal length is longer.
double FocalChangeFraction(const CameraModel& before, const HandEyeResult& refined_fit);

}  // namespace romunect::calib
