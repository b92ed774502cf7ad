// The colour (RGB) camera beside the depth camera, as on a Kinect, and what the device makes of
// it: a shaded RGB image of the scene and depth registered to the colour camera's view
// (OpenNI2's ONI_IMAGE_REGISTRATION_DEPTH_TO_COLOR).
#pragma once

#include <optional>
#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/geometry_buffer.h"
#include "romunect/sensor/pose.h"

namespace romunect {

struct ColorCamera {
  CameraModel camera;               // the colour image's pinhole and distortion
  Pose T_C_RGB = Pose::Identity();  // the colour camera's pose in the depth camera's frame C

  // Why the camera is unusable, or "" ("camera: ..." or "T_C_RGB: ...").
  std::string Problem() const;
  bool operator==(const ColorCamera& other) const {
    return camera == other.camera && T_C_RGB.matrix() == other.T_C_RGB.matrix();
  }
};

// The Kinect's colour camera, kept on both presets (the modified device changes only the IR
// camera's lens and the projector): VGA (640 x 480) with a 62.7 degree horizontal field of view
// (fx = fy = 525 px), parallel to the IR camera and 25 mm beside it on the projector's side (+x).
ColorCamera StockColorCamera();

// The colour camera at another image size with the same field of view (pixel centres at integer
// coordinates): how the device serves QVGA, and how registered depth meets a depth image size.
CameraModel ScaledCamera(const CameraModel& camera, int width, int height);

// Depth (CV_32F, m, 0 = none) seen by depth_camera, reprojected into the colour camera's view at
// out_size (the colour camera scaled to it): each measured pixel's point lands on the colour pixel
// nearest its projection, the nearest point wins where several land (z-buffer), pixels no point
// reaches stay 0. Values are depth along the colour camera's optical axis (m).
cv::Mat RegisterDepthToColor(const cv::Mat& depth_m, const CameraModel& depth_camera, const ColorCamera& color,
                             const cv::Size& out_size);

// The colour pixel (at the colour camera's own size) that a depth pixel with depth depth_m lands
// on, or nullopt behind the colour camera.
std::optional<Eigen::Vector2d> DepthPixelToColor(const Eigen::Vector2d& u_px, double depth_m,
                                                 const CameraModel& depth_camera, const ColorCamera& color);

// A plain RGB image (CV_8UC3, R first) of what a colour camera's render hit (geometry's layer 0,
// in the colour camera's frame): Lambert shading under a headlight at the camera centre whose
// light falls off with the square of the distance, a surface of albedo 1 facing the camera at
// exposure_distance_m shown at full scale; each object tinted by its id, so that objects of one
// material stay apart; black where the ray missed.
cv::Mat ShadeColorImage(const GeometryBuffer& geometry, double exposure_distance_m);

}  // namespace romunect
