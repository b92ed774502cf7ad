#include "romunect/tools/jobs/perturbation.h"

#include <cmath>
#include <cstdio>
#include <sstream>

#include <Eigen/Geometry>

#include "romunect/sensor/errors.h"

namespace romunect::jobs {
namespace {

constexpr double kDeg = M_PI / 180.0;

// "name_x" -> axis 0 (x); "name" -> default_axis; -1 when the name is not base or base_[xyz].
int AxisOf(const std::string& name, const std::string& base, int default_axis, int axes) {
  if (name == base) return default_axis;
  if (name.size() == base.size() + 2 && name.compare(0, base.size(), base) == 0 && name[base.size()] == '_') {
    const int axis = name.back() - 'x';
    if (axis >= 0 && axis < axes) return axis;
  }
  return -1;
}

}  // namespace

bool CalibrationPerturbation::empty() const {
  return hand_eye_rotation_C.isZero() && hand_eye_translation_C.isZero() && focal_fraction == 0.0 &&
         principal_px.isZero() && depth_scale_fraction == 0.0 && depth_offset_m == 0.0;
}

std::string CalibrationPerturbation::Text() const {
  std::ostringstream s;
  const char* axes = "xyz";
  const auto add = [&](const std::string& name, double value) {
    if (value != 0.0) s << (s.tellp() > 0 ? "," : "") << name << '=' << value;
  };
  for (int a = 0; a < 3; ++a) add(std::string("hand_eye_deg_") + axes[a], hand_eye_rotation_C[a] / kDeg);
  for (int a = 0; a < 3; ++a) add(std::string("hand_eye_mm_") + axes[a], hand_eye_translation_C[a] * 1e3);
  add("focal_pct", focal_fraction * 100.0);
  add("principal_px_x", principal_px.x());
  add("principal_px_y", principal_px.y());
  add("depth_scale_pct", depth_scale_fraction * 100.0);
  add("depth_offset_mm", depth_offset_m * 1e3);
  return s.tellp() > 0 ? s.str() : "none";
}

Pose CalibrationPerturbation::T_C_Cp() const {
  const double angle = hand_eye_rotation_C.norm();
  const Eigen::Matrix3d R = angle > 0.0 ? Eigen::AngleAxisd(angle, hand_eye_rotation_C / angle).toRotationMatrix()
                                        : Eigen::Matrix3d::Identity();
  return MakePose(R, hand_eye_translation_C);
}

CameraModel CalibrationPerturbation::Apply(const CameraModel& camera) const {
  CameraModel out = camera;
  out.fx *= 1.0 + focal_fraction;
  out.fy *= 1.0 + focal_fraction;
  out.cx += principal_px.x();
  out.cy += principal_px.y();
  return out;
}

void CalibrationPerturbation::ApplyToDepth(cv::Mat* depth_m) const {
  if (depth_scale_fraction == 0.0 && depth_offset_m == 0.0) return;
  const float gain = static_cast<float>(1.0 + depth_scale_fraction), offset = static_cast<float>(depth_offset_m);
  depth_m->forEach<float>([&](float& z, const int*) {
    if (z > 0.0f) z = std::max(0.0f, gain * z + offset);
  });
}

CalibrationPerturbation ParsePerturbation(const std::string& text, const std::string& source) {
  CalibrationPerturbation p;
  std::istringstream items(text);
  std::string item;
  while (std::getline(items, item, ',')) {
    const size_t eq = item.find('=');
    const std::string name = item.substr(0, eq);
    char* end = nullptr;
    const std::string value_text = eq == std::string::npos ? "" : item.substr(eq + 1);
    const double v = std::strtod(value_text.c_str(), &end);
    if (eq == std::string::npos || value_text.empty() || *end != '\0' || !std::isfinite(v)) {
      throw InputError(source, item, "expected NAME=VALUE with a finite number, e.g. hand_eye_deg=0.5");
    }
    int axis = -1;
    if ((axis = AxisOf(name, "hand_eye_deg", 0, 3)) >= 0) {
      p.hand_eye_rotation_C[axis] += v * kDeg;
    } else if ((axis = AxisOf(name, "hand_eye_mm", 2, 3)) >= 0) {
      p.hand_eye_translation_C[axis] += v * 1e-3;
    } else if ((axis = AxisOf(name, "principal_px", 0, 2)) >= 0) {
      p.principal_px[axis] += v;
    } else if (name == "focal_pct" && v > -50.0 && v < 50.0) {
      p.focal_fraction = v / 100.0;
    } else if (name == "depth_scale_pct" && v > -50.0 && v < 50.0) {
      p.depth_scale_fraction = v / 100.0;
    } else if (name == "depth_offset_mm") {
      p.depth_offset_m = v * 1e-3;
    } else {
      throw InputError(source, name,
                       "unknown (or a percentage beyond +-50); names: hand_eye_deg[_x|_y|_z], hand_eye_mm[_x|_y|_z], "
                       "focal_pct, principal_px[_x|_y], depth_scale_pct, depth_offset_mm");
    }
  }
  return p;
}

CalibrationErrors CompareCalibration(const Pose& T_H_C, const CameraModel& camera, const Pose& T_H_C_truth,
                                     const CameraModel& camera_truth) {
  CalibrationErrors e;
  const PoseError pose = ComparePoses(T_H_C, T_H_C_truth);
  e.hand_eye_deg = pose.angle_rad / kDeg;
  e.hand_eye_mm = pose.translation_m * 1e3;
  e.focal_pct = 100.0 * ((camera.fx + camera.fy) / (camera_truth.fx + camera_truth.fy) - 1.0);
  e.principal_px = std::hypot(camera.cx - camera_truth.cx, camera.cy - camera_truth.cy);
  return e;
}

}  // namespace romunect::jobs
