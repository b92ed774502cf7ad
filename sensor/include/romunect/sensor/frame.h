// The one frame type that every source delivers (simulator, OpenNI2 device, frame directory)
// and that calib and fusion consume without knowing where it came from.
#pragma once

#include <optional>

#include <opencv2/core.hpp>

#include "romunect/sensor/pose.h"

namespace romunect {

struct Frame {
  int index = 0;        // position in its stream, from 0
  double time_s = 0.0;  // capture time, seconds since the stream's start

  // Every image is height x width of the source's camera; an empty Mat means "not present".
  cv::Mat ir;          // CV_16U, IR image as the sensor sees it (10-bit values in 16 bits)
  cv::Mat raw;         // CV_16U, device raw depth (see depth_engine.h); 2047 = invalid
  cv::Mat depth_m;     // CV_32F, metric depth along the optical axis (m), 0 = no measurement
  cv::Mat gt_depth_m;  // CV_32F, ground-truth depth (m) where the source knows it, 0 = none
  // CV_8UC3, the colour camera's image (color_camera.h), R, G, B order, its own size; empty
  // without a colour camera.
  cv::Mat color;

  std::optional<Pose> T_W_C;  // camera to world, when known
  std::optional<Pose> T_B_H;  // hand (flange) to robot base, when known
};

}  // namespace romunect
