// `romunect info DIR`: summarizes and validates a frame directory (every image is opened).
#pragma once

#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>

#include <Eigen/Core>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/world_box.h"

namespace romunect::jobs {

struct FrameDirectoryInfo {
  std::filesystem::path dir;
  CameraModel camera;
  size_t frames = 0;
  double first_time_s = 0.0, last_time_s = 0.0;
  size_t with_depth = 0, with_ir = 0, with_raw = 0, with_gt_depth = 0, with_color = 0, with_pose = 0;
  std::optional<ColorCamera> color_camera;  // frames.json's color_camera
  size_t with_hand_pose = 0;  // frames with the robot's T_B_H (what calibrate hand-eye and depth read)
  double valid_mean = 0.0, valid_min = 1.0, valid_max = 0.0;  // share of valid depth pixels per frame
  // Share of raw pixels with a measurement (below 2047) per frame with raw; raw above 2047 (not
  // 11 bits) is refused when the frame is read.
  double raw_valid_mean = 0.0, raw_valid_min = 1.0, raw_valid_max = 0.0;
  Eigen::Vector3d cameras_min_W = Eigen::Vector3d::Zero(), cameras_max_W = Eigen::Vector3d::Zero();
  double path_m = 0.0;  // the cameras' path, frame to frame
  std::optional<WorldBox> region_W;
};

// Reads frames.json and every frame (InputError naming the file and field on anything bad).
FrameDirectoryInfo InspectFrameDirectory(const std::filesystem::path& dir);

// The summary for the terminal, ending with "valid: all N frames read and checked".
std::string FrameDirectoryInfoText(const FrameDirectoryInfo& info);

}  // namespace romunect::jobs
