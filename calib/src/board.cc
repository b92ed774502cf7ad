#include "romunect/calib/board.h"

#include <cmath>
#include <cstdio>

#include "romunect/sensor/errors.h"

namespace romunect::calib {

std::string BoardSpec::Problem() const {
  if (cols < 3 || rows < 3) {
    return "board has " + std::to_string(cols) + " x " + std::to_string(rows) +
           " inner corners; need at least 3 x 3";
  }
  if (!std::isfinite(square_m) || square_m <= 0.0) {
    return "square_m is " + std::to_string(square_m) + "; must be a positive length in metres";
  }
  return "";
}

std::vector<Eigen::Vector3d> BoardSpec::CornersK() const {
  std::vector<Eigen::Vector3d> corners;
  corners.reserve(corner_count());
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) corners.emplace_back(c * square_m, r * square_m, 0.0);
  }
  return corners;
}

Eigen::Vector3d BoardSpec::CentreK() const {
  return Eigen::Vector3d(0.5 * (cols - 1) * square_m, 0.5 * (rows - 1) * square_m, 0.0);
}

BoardSpec ParseBoardSize(const std::string& text, double square_m, const std::string& source) {
  BoardSpec board;
  char x = 0;
  char extra = 0;
  if (std::sscanf(text.c_str(), "%d%c%d%c", &board.cols, &x, &board.rows, &extra) != 3 ||
      (x != 'x' && x != 'X')) {
    throw InputError(source, "board", "'" + text + "' is not COLSxROWS of inner corners, e.g. 9x6");
  }
  board.square_m = square_m;
  if (const std::string problem = board.Problem(); !problem.empty()) {
    throw InputError(source, "board", problem);
  }
  return board;
}

bool ProjectBoard(const CameraModel& camera, const BoardSpec& board, const Pose& T_C_K,
                  std::vector<cv::Point2f>* corners_px) {
  corners_px->clear();
  for (const Eigen::Vector3d& p_K : board.CornersK()) {
    const auto u = camera.Project(T_C_K * p_K);
    if (!u || !camera.Contains(*u)) return false;
    corners_px->emplace_back(static_cast<float>(u->x()), static_cast<float>(u->y()));
  }
  return true;
}

}  // namespace romunect::calib
