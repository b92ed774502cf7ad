#include "romunect/sensor/pose.h"

#include <cmath>
#include <sstream>

#include "romunect/sensor/check.h"
#include "romunect/sensor/frames.h"

namespace romunect {

Pose MakePose(const Eigen::Matrix3d& R_a_b, const Eigen::Vector3d& t_a_b) {
  Pose T_a_b = Pose::Identity();
  T_a_b.linear() = R_a_b;
  T_a_b.translation() = t_a_b;
  return T_a_b;
}

Pose MakePoseWxyz(const std::array<double, 4>& q_a_b_wxyz, const Eigen::Vector3d& t_a_b) {
  return MakePose(QuaternionFromWxyz(q_a_b_wxyz).toRotationMatrix(), t_a_b);
}

std::array<double, 16> PoseToRowMajor(const Pose& T_a_b) {
  std::array<double, 16> out{};
  const Eigen::Matrix4d m = T_a_b.matrix();
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) out[4 * r + c] = m(r, c);
  }
  return out;
}

std::string RigidityProblem(const Eigen::Matrix4d& m, double tolerance) {
  if (!m.allFinite()) return "has a non-finite entry";
  if (m.row(3).cwiseAbs().head<3>().maxCoeff() > tolerance || std::abs(m(3, 3) - 1.0) > tolerance) {
    return "last row is not (0 0 0 1)";
  }
  const Eigen::Matrix3d R = m.topLeftCorner<3, 3>();
  const double orthonormality = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  if (orthonormality > tolerance) {
    std::ostringstream s;
    s << "rotation is not orthonormal (max |R^T R - I| = " << orthonormality << ", tolerance " << tolerance << ")";
    return s.str();
  }
  if (R.determinant() < 0.0) return "rotation is a reflection (determinant -1)";
  return "";
}

Pose PoseFromRowMajor(const std::array<double, 16>& row_major) {
  Eigen::Matrix4d m;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) m(r, c) = row_major[4 * r + c];
  }
  ROMUNECT_CHECK(RigidityProblem(m).empty());
  // Kept exactly as given (no re-orthonormalization) so files round-trip bit for bit.
  Pose T_a_b = Pose::Identity();
  T_a_b.matrix() = m;
  return T_a_b;
}

double RotationAngleRad(const Pose& T_a_b) { return Eigen::AngleAxisd(T_a_b.rotation()).angle(); }

PoseError ComparePoses(const Pose& T_a_b, const Pose& T_a_b_other) {
  const Pose delta = T_a_b.inverse() * T_a_b_other;
  return {RotationAngleRad(delta), (T_a_b.translation() - T_a_b_other.translation()).norm()};
}

Pose InterpolatePose(const Pose& T_a_b0, const Pose& T_a_b1, double alpha) {
  const Eigen::Quaterniond q0(T_a_b0.rotation()), q1(T_a_b1.rotation());
  return MakePose(q0.slerp(alpha, q1).toRotationMatrix(),
                  (1.0 - alpha) * T_a_b0.translation() + alpha * T_a_b1.translation());
}

}  // namespace romunect
