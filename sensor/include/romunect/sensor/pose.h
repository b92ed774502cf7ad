// Pose helpers on Eigen::Isometry3d (frames.h: T_a_b maps points from b into a).
// Files hold poses as 16 numbers, a row-major 4x4 matrix; these helpers convert and check.
#pragma once

#include <array>
#include <string>

#include <Eigen/Geometry>

namespace romunect {

using Pose = Eigen::Isometry3d;

// Builds T_a_b from a rotation and the position of b's origin in a.
Pose MakePose(const Eigen::Matrix3d& R_a_b, const Eigen::Vector3d& t_a_b);

// Builds T_a_b from a w-first quaternion array {w, x, y, z} and a translation.
Pose MakePoseWxyz(const std::array<double, 4>& q_a_b_wxyz, const Eigen::Vector3d& t_a_b);

// The 16 numbers of the row-major 4x4 matrix of a pose (the file format of frames.json).
std::array<double, 16> PoseToRowMajor(const Pose& T_a_b);

// Why a 4x4 matrix is not a rigid transform, or "" when it is one: every entry finite,
// last row (0 0 0 1), rotation orthonormal within `tolerance` and with determinant +1.
std::string RigidityProblem(const Eigen::Matrix4d& matrix, double tolerance = 1e-6);

// The pose of a row-major 4x4 matrix, kept exactly (so files round-trip bit for bit). The
// matrix must be rigid: RigidityProblem() is "" (check it first on outside input).
Pose PoseFromRowMajor(const std::array<double, 16>& row_major);

// The rotation angle of a pose, in radians, in [0, pi].
double RotationAngleRad(const Pose& T_a_b);

// Angle (rad) and distance (m) between two poses of the same pair of frames.
struct PoseError {
  double angle_rad = 0.0;
  double translation_m = 0.0;
};
PoseError ComparePoses(const Pose& T_a_b, const Pose& T_a_b_other);

// Interpolates between two poses: rotation by slerp, translation linearly; alpha in [0, 1].
Pose InterpolatePose(const Pose& T_a_b0, const Pose& T_a_b1, double alpha);

}  // namespace romunect
