// Templated pinhole + Brown-Conrady projection (camera_model.h's formulas), usable with
// ceres::Jet so the Ceres residuals share one definition with CameraModel::Project.
#pragma once

#include "romunect/sensor/camera_model.h"

namespace romunect::calib::internal {

// Normalized (x, y) -> distorted pixel (u, v) with the camera's intrinsics and distortion.
template <typename T>
void DistortAndProject(const CameraModel& camera, const T& x, const T& y, T* u, T* v) {
  const double k1 = camera.distortion[0], k2 = camera.distortion[1], p1 = camera.distortion[2],
               p2 = camera.distortion[3], k3 = camera.distortion[4];
  const T r2 = x * x + y * y;
  const T radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  const T xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
  const T yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
  *u = camera.fx * xd + camera.cx;
  *v = camera.fy * yd + camera.cy;
}

// A point in C -> distorted pixel (no visibility check: the caller's points are in front).
template <typename T>
void ProjectPoint(const CameraModel& camera, const T* p_C, T* u, T* v) {
  DistortAndProject(camera, p_C[0] / p_C[2], p_C[1] / p_C[2], u, v);
}

}  // namespace romunect::calib::internal
