#include "robot_poses.h"

#include <cmath>
#include <fstream>
#include <sstream>

#include <Eigen/SVD>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/openni2/pose_log.h"

namespace romunect::jobs {
namespace {

// The numbers of one line, split at spaces, tabs and commas; false when a cell is no number.
bool Numbers(const std::string& line, std::vector<double>* values) {
  std::string text = line;
  for (char& c : text) {
    if (c == ',' || c == '\t' || c == ';') c = ' ';
  }
  std::istringstream cells(text);
  std::string cell;
  values->clear();
  while (cells >> cell) {
    char* end = nullptr;
    const double v = std::strtod(cell.c_str(), &end);
    if (*end != '\0' || !std::isfinite(v)) return false;
    values->push_back(v);
  }
  return true;
}

bool IsPoseLog(const std::filesystem::path& path) {
  std::ifstream in(path);
  std::string line;
  std::vector<double> values;
  while (std::getline(in, line)) {
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    if (line.compare(start, 6, "time_s") == 0) return true;
    return Numbers(line, &values) && values.size() == 8;
  }
  return false;
}

// Re-orthonormalizes (nearest rotation, SVD) within the tolerance; throws beyond it.
Eigen::Matrix3d Orthonormal(const Eigen::Matrix3d& R, const std::string& source, const std::string& where,
                            const RobotPoseFileOptions& options, RobotPoses* out) {
  const double off = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (off > options.orthonormal_tolerance || !(R.determinant() > 0.0)) {
    throw InputError(source, where,
                     "rotation is not orthonormal (max |R^T R - I| = " + std::to_string(off) + ", determinant " +
                         std::to_string(R.determinant()) + "); up to " + std::to_string(options.orthonormal_tolerance) +
                         " (rounded values) is re-orthonormalized");
  }
  if (off <= 1e-12) return R;
  ++out->reorthonormalized;
  out->worst_orthonormality = std::max(out->worst_orthonormality, off);
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
  return svd.matrixU() * svd.matrixV().transpose();
}

}  // namespace

RobotPoses ReadRobotPoses(const std::filesystem::path& path, const RobotPoseFileOptions& options) {
  const std::string source = path.string();
  std::ifstream in(path);
  if (!in) throw InputError(source, "", "cannot be read (a pose file: 16 numbers per line, or a CSV pose log)");
  RobotPoses out;
  const auto add = [&](const Eigen::Matrix3d& R, const Eigen::Vector3d& t, const std::string& where) {
    const Pose T = MakePose(Orthonormal(R, source, where, options, &out), t * options.metres_per_unit);
    out.T_B_H.push_back(options.base_in_hand ? T.inverse() : T);
  };
  if (IsPoseLog(path)) {
    const openni2::PoseLog log = openni2::PoseLog::Load(path);
    for (size_t i = 0; i < log.poses().size(); ++i) {
      const Pose& T = log.poses()[i].T_B_H;
      add(T.linear(), T.translation(), "pose " + std::to_string(i + 1));
    }
    return out;
  }
  std::string line;
  std::vector<double> v;
  for (int number = 1; std::getline(in, line); ++number) {
    const size_t start = line.find_first_not_of(" \t\r");
    if (start == std::string::npos || line[start] == '#') continue;
    const std::string where = "line " + std::to_string(number);
    if (!Numbers(line, &v) || v.size() != 16) {
      throw InputError(source, where,
                       "expected 16 numbers (a 4x4 hand pose, row-major) or the CSV pose log's 8 columns "
                       "(time_s, x_m, y_m, z_m, qw, qx, qy, qz)");
    }
    if (std::abs(v[12]) > 1e-6 || std::abs(v[13]) > 1e-6 || std::abs(v[14]) > 1e-6 || std::abs(v[15] - 1.0) > 1e-6) {
      throw InputError(source, where, "the last row is not 0 0 0 1: is the matrix row-major?");
    }
    Eigen::Matrix3d R;
    R << v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10];
    add(R, Eigen::Vector3d(v[3], v[7], v[11]), where);
  }
  if (out.T_B_H.empty()) throw InputError(source, "", "holds no poses");
  return out;
}

}  // namespace romunect::jobs
