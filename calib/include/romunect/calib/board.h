// The planar calibration target (frame K) and its observations. K: origin at the first inner
// corner, x along a row of corners, y down the columns, z = 0 on the board (pointing into it).
// Corner order is OpenCV's findChessboardCorners order: row by row, `cols` corners per row.
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/pose.h"

namespace romunect::calib {

struct BoardSpec {
  int cols = 9;             // inner corners per row
  int rows = 6;             // inner corners per column
  double square_m = 0.025;  // edge of one square, metres

  // Why the spec is unusable, or "": at least 3 x 3 inner corners, a positive finite square.
  std::string Problem() const;
  // Corner positions p_K in metres, OpenCV's order (row-major, cols per row).
  std::vector<Eigen::Vector3d> CornersK() const;
  // The board centre (centre of the inner-corner grid) in K.
  Eigen::Vector3d CentreK() const;
  int corner_count() const { return cols * rows; }
};

// Parses "9x6" (cols x rows of inner corners). Throws InputError naming `source` on bad text.
BoardSpec ParseBoardSize(const std::string& text, double square_m, const std::string& source);

// The corners of one view of the board, in pixels, OpenCV's order.
struct BoardView {
  std::string name;                     // image file or station label, for messages
  std::vector<cv::Point2f> corners_px;  // corner_count() points
};

// Projects the board's corners through `camera` seen from T_C_K (pose of K in C). Returns
// false (and leaves *corners_px partial) if any corner is behind the camera or off the image.
bool ProjectBoard(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K,
                  std::vector<cv::Point2f>* corners_px);

}  // namespace romunect::calib
