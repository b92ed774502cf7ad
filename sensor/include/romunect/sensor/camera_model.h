// The camera model: OpenCV's pinhole with Brown-Conrady distortion (k1, k2, p1, p2, k3), so a
// calibration loads into OpenCV, ROS and Open3D unchanged. Frame C (frames.h): x right,
// y down, z forward; pixel centres at integer coordinates; depth is z in C, in metres.
//
//   x_n = X/Z, y_n = Y/Z, r^2 = x_n^2 + y_n^2
//   x_d = x_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x_n y_n + p2 (r^2 + 2 x_n^2)
//   y_d = y_n (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y_n^2) + 2 p2 x_n y_n
//   u = fx x_d + cx, v = fy y_d + cy
#pragma once

#include <array>
#include <filesystem>
#include <optional>
#include <string>

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace romunect {

struct CameraModel {
  int width = 640;                     // image width in pixels
  int height = 480;                    // image height in pixels
  double fx = 525.0, fy = 525.0;       // focal lengths, px
  double cx = 319.5, cy = 239.5;       // principal point, px (319.5 = centre of a 640-px row)
  std::array<double, 5> distortion{};  // k1, k2, p1, p2, k3 (OpenCV order)

  // Why the model is unusable, or "" when it is valid: positive size and focal lengths,
  // finite numbers, and a distortion that stays invertible over the image.
  std::string Problem() const;

  bool HasDistortion() const;

  // Applies the distortion to normalized coordinates (x_n, y_n).
  Eigen::Vector2d Distort(const Eigen::Vector2d& xy_n) const;
  // Inverts Distort by Gauss-Newton to machine precision; returns undistorted (x_n, y_n).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& xy_d) const;

  // Projects a point in C to pixels; nullopt when the point is not in front of the camera.
  // The result may lie outside the image: check with Contains().
  std::optional<Eigen::Vector2d> Project(const Eigen::Vector3d& p_C) const;
  // The point in C seen at pixel u_px with depth (z in C) depth_m.
  Eigen::Vector3d Unproject(const Eigen::Vector2d& u_px, double depth_m) const;
  // The ray through pixel u_px, scaled so that its z is 1: p_C = depth_m * Ray(u_px).
  Eigen::Vector3d Ray(const Eigen::Vector2d& u_px) const;
  // Undistorts a pixel to the pixel an ideal (distortion-free) camera would see.
  Eigen::Vector2d UndistortPixel(const Eigen::Vector2d& u_px) const;

  // Whether a pixel position lies on the image (pixel-centre convention: [-0.5, w-0.5)).
  bool Contains(const Eigen::Vector2d& u_px) const;

  // Per-pixel rays, CV_32FC2 (height x width): (x_n, y_n) of each pixel centre, so that
  // p_C = depth_m * (x_n, y_n, 1). Computed once per camera and reused every frame.
  cv::Mat RayTable() const;

  cv::Matx33d CameraMatrix() const;
  cv::Mat DistortionVector() const;  // 1x5 CV_64F, OpenCV order

  // Writes OpenCV's calibration names (image_width, image_height, camera_matrix,
  // distortion_coefficients) into an open cv::FileStorage node.
  void Write(cv::FileStorage& fs) const;
  // Reads what Write wrote. Throws InputError naming `source` and the field on bad input.
  static CameraModel Read(const cv::FileNode& node, const std::string& source);

  // Saves to / loads from a YAML or JSON file that cv::FileStorage reads (by extension).
  void Save(const std::filesystem::path& path) const;
  static CameraModel Load(const std::filesystem::path& path);

  bool operator==(const CameraModel&) const = default;
};

}  // namespace romunect
