// Robot hand poses from a file, one per board image, as robot controllers and public hand-eye
// datasets deliver them: 16 numbers per line (a 4x4 matrix, row-major, separated by spaces or
// commas), or the CSV pose log (pose_log.h; times ignored, order kept). Lines starting with '#'
// and blank lines are skipped.
#pragma once

#include <filesystem>
#include <string>
#include <vector>

#include "romunect/sensor/pose.h"

namespace romunect::jobs {

struct RobotPoseFileOptions {
  double metres_per_unit = 1.0;  // 1e-3 for translations in millimetres
  bool base_in_hand = false;     // the file holds T_H_B: inverted on reading
  // Rotations off orthonormal (max |R^T R - I|) up to this are re-orthonormalized (poses
  // rounded to a few decimals) with a warning; beyond it the line is refused.
  double orthonormal_tolerance = 1e-4;
};

struct RobotPoses {
  std::vector<Pose> T_B_H;
  int reorthonormalized = 0;  // poses whose rotation was re-orthonormalized
  double worst_orthonormality = 0.0;
};

// Throws InputError naming the file, the line and what was expected.
RobotPoses ReadRobotPoses(const std::filesystem::path& path, const RobotPoseFileOptions& options);

}  // namespace romunect::jobs
