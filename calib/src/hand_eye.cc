#include "romunect/calib/hand_eye.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <limits>

#include <ceres/ceres.h>
#include <ceres/rotation.h>
#include <opencv2/calib3d.hpp>

#include "projection.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect::calib {
namespace {

constexpr const char* kSource = "hand-eye";
constexpr double kDeg = M_PI / 180.0;

cv::Mat ToCv(const Eigen::Matrix3d& R) {
  cv::Mat m(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) m.at<double>(r, c) = R(r, c);
  }
  return m;
}
cv::Mat ToCv(const Eigen::Vector3d& t) { return (cv::Mat_<double>(3, 1) << t.x(), t.y(), t.z()); }

Pose FromCv(const cv::Mat& R, const cv::Mat& t) {
  Eigen::Matrix3d R_e;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) R_e(r, c) = R.at<double>(r, c);
  }
  return MakePose(R_e, Eigen::Vector3d(t.at<double>(0), t.at<double>(1), t.at<double>(2)));
}

// Chordal L2 mean of poses: rotation from the SVD of the summed matrices, mean translation.
Pose MeanPose(const std::vector<Pose>& poses) {
  Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();
  for (const Pose& T : poses) {
    sum += T.linear();
    t += T.translation();
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(sum, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return MakePose(svd.matrixU() * D * svd.matrixV().transpose(), t / poses.size());
}

double ReprojectionRms(const std::vector<HandEyeStation>& stations, const CameraModel& camera, const BoardSpec& board,
                       const Pose& T_H_C, const Pose& T_B_K) {
  const std::vector<Eigen::Vector3d> corners = board.CornersK();
  double sum = 0.0;
  size_t n = 0;
  for (const HandEyeStation& s : stations) {
    const Pose T_C_K = T_H_C.inverse() * s.T_B_H.inverse() * T_B_K;
    for (size_t i = 0; i < corners.size(); ++i) {
      const Eigen::Vector3d p_C = T_C_K * corners[i];
      double u = 0, v = 0;
      internal::ProjectPoint(camera, p_C.data(), &u, &v);
      const double du = u - s.view.corners_px[i].x, dv = v - s.view.corners_px[i].y;
      sum += du * du + dv * dv;
      ++n;
    }
  }
  return std::sqrt(sum / n);
}

// A board corner p_K in C: board -> base (b_K) -> hand (the robot's T_H_B) -> camera (c_H);
// c_H and b_K as angle-axis (3) + translation (3).
template <typename T>
void CornerInCamera(const T* c_H, const T* b_K, const Eigen::Matrix4d& T_H_B, const Eigen::Vector3d& p_K_d, T* p_C) {
  const T p_K[3] = {T(p_K_d.x()), T(p_K_d.y()), T(p_K_d.z())};
  T p_B[3];
  ceres::AngleAxisRotatePoint(b_K, p_K, p_B);
  for (int i = 0; i < 3; ++i) p_B[i] += b_K[3 + i];
  T p_H[3];
  for (int r = 0; r < 3; ++r) {
    p_H[r] = T(T_H_B(r, 3));
    for (int c = 0; c < 3; ++c) p_H[r] += T_H_B(r, c) * p_B[c];
  }
  ceres::AngleAxisRotatePoint(c_H, p_H, p_C);
  for (int i = 0; i < 3; ++i) p_C[i] += c_H[3 + i];
}

struct CornerResidual {
  CornerResidual(const CameraModel& camera, const Pose& T_H_B, const Eigen::Vector3d& p_K, cv::Point2f observed)
      : camera_(camera), T_H_B_(T_H_B.matrix()), p_K_(p_K), observed_(observed) {}

  // c_H: T_C_H as angle-axis (3) + translation (3); b_K: T_B_K the same way.
  template <typename T>
  bool operator()(const T* c_H, const T* b_K, T* residual) const {
    T p_C[3];
    CornerInCamera(c_H, b_K, T_H_B_, p_K_, p_C);
    T u, v;
    internal::ProjectPoint(camera_, p_C, &u, &v);
    residual[0] = u - T(observed_.x);
    residual[1] = v - T(observed_.y);
    return true;
  }

  const CameraModel& camera_;
  Eigen::Matrix4d T_H_B_;
  Eigen::Vector3d p_K_;
  cv::Point2f observed_;
};

// The same corner with the camera's intrinsics as parameters too: k = fx, fy, cx, cy, k1, k2,
// p1, p2 (k3 fixed at the given camera's).
struct JointCornerResidual {
  JointCornerResidual(double k3, const Pose& T_H_B, const Eigen::Vector3d& p_K, cv::Point2f observed)
      : k3_(k3), T_H_B_(T_H_B.matrix()), p_K_(p_K), observed_(observed) {}

  template <typename T>
  bool operator()(const T* c_H, const T* b_K, const T* k, T* residual) const {
    T p_C[3];
    CornerInCamera(c_H, b_K, T_H_B_, p_K_, p_C);
    // camera_model.h's pinhole + Brown-Conrady with the parameters as unknowns
    const T x = p_C[0] / p_C[2], y = p_C[1] / p_C[2];
    const T r2 = x * x + y * y;
    const T radial = 1.0 + r2 * (k[4] + r2 * (k[5] + r2 * k3_));
    const T xd = x * radial + 2.0 * k[6] * x * y + k[7] * (r2 + 2.0 * x * x);
    const T yd = y * radial + k[6] * (r2 + 2.0 * y * y) + 2.0 * k[7] * x * y;
    residual[0] = k[0] * xd + k[2] - T(observed_.x);
    residual[1] = k[1] * yd + k[3] - T(observed_.y);
    return true;
  }

  double k3_;
  Eigen::Matrix4d T_H_B_;
  Eigen::Vector3d p_K_;
  cv::Point2f observed_;
};

void PoseToParams(const Pose& T, double* params) {
  const Eigen::AngleAxisd aa(T.linear());
  const Eigen::Vector3d v = aa.angle() * aa.axis();
  for (int i = 0; i < 3; ++i) {
    params[i] = v[i];
    params[3 + i] = T.translation()[i];
  }
}
Pose ParamsToPose(const double* params) {
  const Eigen::Vector3d v(params[0], params[1], params[2]);
  const double angle = v.norm();
  const Eigen::Matrix3d R = angle < 1e-15 ? Eigen::Matrix3d::Identity()
                                          : Eigen::AngleAxisd(angle, v / angle).toRotationMatrix();
  return MakePose(R, Eigen::Vector3d(params[3], params[4], params[5]));
}

void CheckMotion(const std::vector<HandEyeStation>& stations, const HandEyeOptions& options,
                 double* max_pair_rotation_rad) {
  std::vector<Eigen::Vector3d> axes;
  *max_pair_rotation_rad = 0.0;
  for (size_t i = 0; i < stations.size(); ++i) {
    for (size_t j = i + 1; j < stations.size(); ++j) {
      const Eigen::AngleAxisd aa(stations[i].T_B_H.linear().transpose() * stations[j].T_B_H.linear());
      *max_pair_rotation_rad = std::max(*max_pair_rotation_rad, aa.angle());
      if (aa.angle() >= options.min_rotation_rad) axes.push_back(aa.axis());
    }
  }
  if (axes.empty()) {
    throw InputError(kSource, "stations",
                     "the hand does not rotate between stations (pure translation): the camera's "
                     "rotation and position in the hand are unobservable; rotate the hand by "
                     "more than " +
                         std::to_string(options.min_rotation_rad / kDeg) + " deg about at least two different axes");
  }
  double spread = 0.0;
  for (size_t i = 0; i < axes.size(); ++i) {
    for (size_t j = i + 1; j < axes.size(); ++j) {
      spread = std::max(spread, std::acos(std::min(1.0, std::abs(axes[i].dot(axes[j])))));
    }
  }
  if (spread < options.min_axis_spread_rad) {
    throw InputError(kSource, "stations",
                     "all hand rotations are about one axis (axes within " + std::to_string(spread / kDeg) +
                         " deg): the camera's position along that "
                         "axis is unobservable; add stations rotated about a second axis, at "
                         "least " +
                         std::to_string(options.min_axis_spread_rad / kDeg) + " deg apart");
  }
}

}  // namespace

std::string HandEyeOptions::Problem() const {
  if (min_stations < 3) return "min_stations is " + std::to_string(min_stations) + "; need at least 3";
  if (!(max_pair_rotation_rad > 0.0 && max_pair_rotation_rad <= M_PI)) {
    return "max_pair_rotation_rad must be in (0, pi]";
  }
  if (!(min_rotation_rad > 0.0)) return "min_rotation_rad must be positive";
  if (!(min_axis_spread_rad > 0.0)) return "min_axis_spread_rad must be positive";
  if (max_iterations < 1) return "max_iterations must be >= 1";
  return "";
}

std::string HandEyeResult::BriefReport() const {
  char line[300];
  const Eigen::Vector3d t = T_H_C.translation();
  std::snprintf(line, sizeof(line),
                "hand-eye: initial %s (largest station-pair rotation %.1f deg), RMS %.3f px -> %.3f px "
                "after %d iterations; T_H_C translation [%.5f %.5f %.5f] m, rotation %.3f deg",
                initial_method.c_str(), max_pair_rotation_rad / kDeg, initial_rms_px, rms_px, iterations, t.x(), t.y(),
                t.z(), RotationAngleRad(T_H_C) / kDeg);
  return line;
}

Pose EstimateBoardPose(const BoardView& view, const CameraModel& camera, const BoardSpec& board) {
  std::vector<cv::Point3f> object;
  for (const Eigen::Vector3d& p : board.CornersK()) object.emplace_back(p.x(), p.y(), p.z());
  cv::Mat rvec, tvec;
  cv::solvePnP(object, view.corners_px, cv::Mat(camera.CameraMatrix()), camera.DistortionVector(), rvec, tvec, false,
               cv::SOLVEPNP_ITERATIVE);
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  return FromCv(R, tvec);
}

Pose OpenCvHandEye(const std::vector<HandEyeStation>& stations, const CameraModel& camera, const BoardSpec& board,
                   HandEyeInitialMethod method) {
  std::vector<cv::Mat> R_B_H, t_B_H, R_C_K, t_C_K;
  for (const HandEyeStation& s : stations) {
    R_B_H.push_back(ToCv(Eigen::Matrix3d(s.T_B_H.linear())));
    t_B_H.push_back(ToCv(Eigen::Vector3d(s.T_B_H.translation())));
    const Pose T_C_K = EstimateBoardPose(s.view, camera, board);
    R_C_K.push_back(ToCv(Eigen::Matrix3d(T_C_K.linear())));
    t_C_K.push_back(ToCv(Eigen::Vector3d(T_C_K.translation())));
  }
  cv::Mat R_H_C, t_H_C;
  cv::HandEyeCalibrationMethod cv_method = cv::CALIB_HAND_EYE_TSAI;
  switch (method) {
    case HandEyeInitialMethod::kAuto:
    case HandEyeInitialMethod::kTsai: cv_method = cv::CALIB_HAND_EYE_TSAI; break;
    case HandEyeInitialMethod::kPark: cv_method = cv::CALIB_HAND_EYE_PARK; break;
    case HandEyeInitialMethod::kHoraud: cv_method = cv::CALIB_HAND_EYE_HORAUD; break;
    case HandEyeInitialMethod::kAndreff: cv_method = cv::CALIB_HAND_EYE_ANDREFF; break;
    case HandEyeInitialMethod::kDaniilidis: cv_method = cv::CALIB_HAND_EYE_DANIILIDIS; break;
  }
  cv::calibrateHandEye(R_B_H, t_B_H, R_C_K, t_C_K, R_H_C, t_H_C, cv_method);
  return FromCv(R_H_C, t_H_C);
}

std::vector<OpenCvHandEyeResult> OpenCvHandEyeAll(const std::vector<HandEyeStation>& stations,
                                                  const CameraModel& camera, const BoardSpec& board) {
  const std::pair<const char*, HandEyeInitialMethod> methods[] = {{"tsai", HandEyeInitialMethod::kTsai},
                                                                  {"park", HandEyeInitialMethod::kPark},
                                                                  {"horaud", HandEyeInitialMethod::kHoraud},
                                                                  {"andreff", HandEyeInitialMethod::kAndreff},
                                                                  {"daniilidis", HandEyeInitialMethod::kDaniilidis}};
  std::vector<Pose> T_C_K;
  for (const HandEyeStation& s : stations) T_C_K.push_back(EstimateBoardPose(s.view, camera, board));
  std::vector<OpenCvHandEyeResult> out;
  for (const auto& [name, method] : methods) {
    OpenCvHandEyeResult r;
    r.method = name;
    try {
      r.fit.T_H_C = OpenCvHandEye(stations, camera, board, method);
    } catch (const cv::Exception&) {
      continue;
    }
    if (!r.fit.T_H_C.matrix().allFinite()) continue;
    std::vector<Pose> T_B_K;
    for (size_t i = 0; i < stations.size(); ++i) T_B_K.push_back(stations[i].T_B_H * r.fit.T_H_C * T_C_K[i]);
    r.fit.T_B_K = MeanPose(T_B_K);
    r.fit.T_H_C_initial = r.fit.T_H_C;
    r.fit.camera = camera;
    r.fit.initial_method = name;
    r.fit.rms_px = ReprojectionRms(stations, camera, board, r.fit.T_H_C, r.fit.T_B_K);
    r.fit.initial_rms_px = r.fit.rms_px;
    out.push_back(r);
  }
  return out;
}

HandEyeResult CalibrateHandEye(const std::vector<HandEyeStation>& stations, const CameraModel& camera,
                               const BoardSpec& board, const HandEyeOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  if (const std::string p = board.Problem(); !p.empty()) throw InputError(kSource, "board", p);
  if (const std::string p = camera.Problem(); !p.empty()) throw InputError(kSource, "camera", p);
  if (static_cast<int>(stations.size()) < options.min_stations) {
    throw InputError(kSource, "stations",
                     std::to_string(stations.size()) + " stations with the board found; need at least " +
                         std::to_string(options.min_stations) + " (15 or more for 0.1 mm)");
  }
  for (size_t i = 0; i < stations.size(); ++i) {
    if (static_cast<int>(stations[i].view.corners_px.size()) != board.corner_count()) {
      throw InputError(kSource, "stations[" + std::to_string(i) + "]",
                       std::to_string(stations[i].view.corners_px.size()) + " corners; the board has " +
                           std::to_string(board.corner_count()));
    }
  }
  HandEyeResult result;
  result.camera = camera;
  CheckMotion(stations, options, &result.max_pair_rotation_rad);

  std::vector<Pose> T_C_K;
  for (const HandEyeStation& s : stations) T_C_K.push_back(EstimateBoardPose(s.view, camera, board));

  // Initial candidates; the guard drops Tsai when a pair rotates past OpenCV 4.6's limit.
  std::vector<std::pair<std::string, HandEyeInitialMethod>> candidates;
  switch (options.initial) {
    case HandEyeInitialMethod::kTsai: candidates = {{"tsai", HandEyeInitialMethod::kTsai}}; break;
    case HandEyeInitialMethod::kPark: candidates = {{"park", HandEyeInitialMethod::kPark}}; break;
    case HandEyeInitialMethod::kHoraud: candidates = {{"horaud", options.initial}}; break;
    case HandEyeInitialMethod::kAndreff: candidates = {{"andreff", options.initial}}; break;
    case HandEyeInitialMethod::kDaniilidis: candidates = {{"daniilidis", options.initial}}; break;
    case HandEyeInitialMethod::kAuto:
      candidates = {{"park", HandEyeInitialMethod::kPark}};
      if (result.max_pair_rotation_rad <= options.max_pair_rotation_rad) {
        candidates.insert(candidates.begin(), {"tsai", HandEyeInitialMethod::kTsai});
      }
      break;
  }
  double best_rms = std::numeric_limits<double>::infinity();
  Pose best_T_B_K = Pose::Identity();
  for (const auto& [name, method] : candidates) {
    Pose T_H_C;
    try {
      T_H_C = OpenCvHandEye(stations, camera, board, method);
    } catch (const cv::Exception& e) {
      continue;  // another candidate may still work; none working is reported below
    }
    if (!T_H_C.matrix().allFinite()) continue;
    std::vector<Pose> T_B_K;
    for (size_t i = 0; i < stations.size(); ++i) T_B_K.push_back(stations[i].T_B_H * T_H_C * T_C_K[i]);
    const Pose mean = MeanPose(T_B_K);
    const double rms = ReprojectionRms(stations, camera, board, T_H_C, mean);
    if (rms < best_rms) {
      best_rms = rms;
      best_T_B_K = mean;
      result.T_H_C_initial = T_H_C;
      result.initial_method = name;
    }
  }
  if (!std::isfinite(best_rms)) {
    throw InputError(kSource, "stations", "OpenCV's calibrateHandEye found no solution for these stations");
  }
  result.initial_rms_px = best_rms;
  result.T_H_C = result.T_H_C_initial;
  result.T_B_K = best_T_B_K;
  result.rms_px = best_rms;
  if (!options.refine) return result;

  double c_H[6], b_K[6];
  PoseToParams(result.T_H_C.inverse(), c_H);
  PoseToParams(result.T_B_K, b_K);
  const std::array<double, 5>& d = camera.distortion;
  double k[8] = {camera.fx, camera.fy, camera.cx, camera.cy, d[0], d[1], d[2], d[3]};
  ceres::Problem problem;
  const std::vector<Eigen::Vector3d> corners = board.CornersK();
  for (const HandEyeStation& s : stations) {
    const Pose T_H_B = s.T_B_H.inverse();
    for (size_t i = 0; i < corners.size(); ++i) {
      if (options.refine_intrinsics) {
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<JointCornerResidual, 2, 6, 6, 8>(
                                     new JointCornerResidual(d[4], T_H_B, corners[i], s.view.corners_px[i])),
                                 nullptr, c_H, b_K, k);
      } else {
        problem.AddResidualBlock(new ceres::AutoDiffCostFunction<CornerResidual, 2, 6, 6>(
                                     new CornerResidual(camera, T_H_B, corners[i], s.view.corners_px[i])),
                                 nullptr, c_H, b_K);
      }
    }
  }
  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::DENSE_QR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = 1e-12;
  solver_options.parameter_tolerance = 1e-12;
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);
  const Pose T_H_C = ParamsToPose(c_H).inverse();
  const Pose T_B_K = ParamsToPose(b_K);
  CameraModel refined = camera;
  if (options.refine_intrinsics) {
    refined.fx = k[0], refined.fy = k[1], refined.cx = k[2], refined.cy = k[3];
    refined.distortion = {k[4], k[5], k[6], k[7], d[4]};
  }
  const bool camera_ok = refined.Problem().empty();
  const double rms = camera_ok ? ReprojectionRms(stations, refined, board, T_H_C, T_B_K) : best_rms + 1.0;
  result.iterations = static_cast<int>(summary.iterations.size());
  if (summary.IsSolutionUsable() && camera_ok && rms <= best_rms) {
    result.T_H_C = T_H_C;
    result.T_B_K = T_B_K;
    result.rms_px = rms;
    result.camera = refined;
  }
  return result;
}

}  // namespace romunect::calib
