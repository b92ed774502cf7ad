#include "romunect/calib/board.h"

#include <cmath>
#include <cstdio>

#include "romunect/sensor/errors.h"

namespace romunect::calib {

std::string BoardSpec::Problem() const {
  // Up to 100 corners a side: OpenCV's corner search has no use for more, and the count fits.
  if (cols < 3 || rows < 3 || cols > 100 || rows > 100) {
    return "board has " + std::to_string(cols) + " x " + std::to_string(rows) + " inner corners; need 3 to 100 a side";
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
  // Digits, 'x', digits: sscanf's %d would overflow on long numbers (undefined behaviour).
  const size_t x = text.find_first_of("xX");
  auto side = [&](const std::string& digits, int* value) {
    if (digits.empty() || digits.size() > 6 || digits.find_first_not_of("0123456789") != std::string::npos)
      return false;
    *value = std::stoi(digits);
    return true;
  };
  if (x == std::string::npos || !side(text.substr(0, x), &board.cols) || !side(text.substr(x + 1), &board.rows)) {
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
