// Frames, units and conventions of romunect, in one place (docs/design.md, "Frames and poses" and "Units").
//
// Frames (one capital letter each; names carry them: p_C is a point in C, T_W_C a pose):
//   W  world, z up.
//   B  robot base.
//   H  hand (flange).
//   C  camera, OpenCV optical frame: x right, y down, z forward.
//   P  projector, same axes as C.
//   O  object.
//   K  calibration target (board).
//   G  fusion grid.
//   M  MuJoCo's camera frame (looks down -z, y up). It never leaves sim/src/.
//
// Poses: T_a_b is an Eigen::Isometry3d that maps points from frame b into frame a:
//   p_a = T_a_b * p_b, and T_a_c = T_a_b * T_b_c (inner letters cancel).
//
// Units: SI everywhere in code and files (metres, radians, seconds). Scalars whose type does
// not say the unit carry a suffix: _m, _rad, _s, _px; _mm only for device-raw values.
//
// Pixels: OpenCV's convention. Pixel (u, v) = (column, row) has its centre at integer
// coordinates: the pixel at column 0 covers u in [-0.5, 0.5). The renderer's ray generator
// and the calibration use this same convention, or every depth is biased by half a pixel.
//
// Depth images in memory: CV_32F, metres along the optical axis (z in C), 0 = no measurement.
// IR images and device raw depth: CV_16U. Device raw depth is documented in depth_engine.h.
//
// Quaternions: MuJoCo and Ceres store (w, x, y, z); Eigen stores (x, y, z, w) in memory.
// Convert only through the named functions below, never through Eigen::Map on raw arrays.
#pragma once

#include <array>

#include <Eigen/Geometry>

namespace romunect {

// Builds a unit quaternion from a w-first array {w, x, y, z} (MuJoCo, Ceres order).
inline Eigen::Quaterniond QuaternionFromWxyz(const std::array<double, 4>& wxyz) {
  return Eigen::Quaterniond(wxyz[0], wxyz[1], wxyz[2], wxyz[3]).normalized();
}

// Returns the w-first array {w, x, y, z} (MuJoCo, Ceres order) of a quaternion.
inline std::array<double, 4> QuaternionToWxyz(const Eigen::Quaterniond& q) { return {q.w(), q.x(), q.y(), q.z()}; }

}  // namespace romunect
