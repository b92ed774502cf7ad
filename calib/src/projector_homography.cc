#include "romunect/calib/projector_homography.h"

#include <cmath>
#include <cstdio>

#include <ceres/ceres.h>
#include <opencv2/calib3d.hpp>

#include "projection.h"
#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"

namespace romunect::calib {
namespace {

constexpr const char* kSource = "projector homography";

template <typename T>
void ApplyHomography(const T* h, const T& x, const T& y, T* out_x, T* out_y) {
  // h: 8 entries, row-major, H(2,2) = 1.
  const T w = h[6] * x + h[7] * y + 1.0;
  *out_x = (h[0] * x + h[1] * y + h[2]) / w;
  *out_y = (h[3] * x + h[4] * y + h[5]) / w;
}

// F_img: projector pixel -> ideal camera pixel (homography F), then the camera's distortion.
struct TargetResidual {
  TargetResidual(const CameraModel& camera, const Eigen::Matrix3d& F, Eigen::Vector2d x_P, Eigen::Vector2d x_C)
      : camera_(camera), F_(F), x_P_(x_P), x_C_(x_C) {}
  template <typename T>
  bool operator()(const T* h, T* residual) const {
    T q[2];
    ApplyHomography(h, T(x_P_.x()), T(x_P_.y()), &q[0], &q[1]);
    // F maps projector pixels to undistorted camera pixels; to normalized, then distort.
    const T w = F_(2, 0) * q[0] + F_(2, 1) * q[1] + F_(2, 2);
    const T u_ideal = (F_(0, 0) * q[0] + F_(0, 1) * q[1] + F_(0, 2)) / w;
    const T v_ideal = (F_(1, 0) * q[0] + F_(1, 1) * q[1] + F_(1, 2)) / w;
    T u, v;
    internal::DistortAndProject(camera_, (u_ideal - camera_.cx) / camera_.fx, (v_ideal - camera_.cy) / camera_.fy, &u,
                                &v);
    residual[0] = u - x_C_.x();
    residual[1] = v - x_C_.y();
    return true;
  }
  const CameraModel& camera_;
  Eigen::Matrix3d F_;
  Eigen::Vector2d x_P_, x_C_;
};

Eigen::Vector2d Map(const Eigen::Matrix3d& H, const Eigen::Vector2d& x) {
  const Eigen::Vector3d y = H * x.homogeneous();
  return y.hnormalized();
}

Eigen::Matrix3d ToEigen(const cv::Mat& m) {
  Eigen::Matrix3d out;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) out(r, c) = m.at<double>(r, c);
  }
  return out;
}

Eigen::Vector2d PredictCamera(const CameraModel& camera, const Eigen::Matrix3d& F, const Eigen::Matrix3d& H,
                              const Eigen::Vector2d& x_P) {
  const Eigen::Vector2d ideal = Map(F * H, x_P);
  double u, v;
  internal::DistortAndProject(camera, (ideal.x() - camera.cx) / camera.fx, (ideal.y() - camera.cy) / camera.fy, &u, &v);
  return {u, v};
}

}  // namespace

std::string ProjectorHomographyOptions::Problem() const {
  if (max_captures < 1) return "max_captures must be >= 1";
  if (!(tolerance_px > 0.0)) return "tolerance_px must be positive";
  if (min_points < 4) return "min_points is " + std::to_string(min_points) + "; a homography needs 4";
  if (max_iterations < 1) return "max_iterations must be >= 1";
  return "";
}

std::string ProjectorHomographyResult::BriefReport() const {
  char line[200];
  std::snprintf(line, sizeof(line),
                "projector homography: %d captures, last observed RMS %.3f px, "
                "predicted %.3f px, %s",
                captures, observed_rms_px.empty() ? -1.0 : observed_rms_px.back(), predicted_rms_px,
                converged ? "converged" : "not converged");
  return line;
}

ProjectorHomographyStep SolveProjectorHomography(const std::vector<Eigen::Vector2d>& pattern_P,
                                                 const std::vector<Eigen::Vector2d>& target_C,
                                                 const std::vector<ProjectorCapture>& captures,
                                                 const CameraModel& camera, const ProjectorHomographyOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  if (pattern_P.size() != target_C.size()) {
    throw InputError(kSource, "target_C",
                     std::to_string(target_C.size()) + " targets for " + std::to_string(pattern_P.size()) +
                         " pattern points");
  }
  if (captures.empty()) throw InputError(kSource, "captures", "none; project the pattern once first");
  // F_img from every capture: shown projector pixel -> undistorted camera pixel.
  std::vector<cv::Point2d> shown, seen;
  for (size_t k = 0; k < captures.size(); ++k) {
    const ProjectorCapture& cap = captures[k];
    if (cap.detected_px.size() != pattern_P.size()) {
      throw InputError(kSource, "captures[" + std::to_string(k) + "]",
                       std::to_string(cap.detected_px.size()) + " detections for " + std::to_string(pattern_P.size()) +
                           " pattern points (use NaN for missed ones)");
    }
    for (size_t i = 0; i < pattern_P.size(); ++i) {
      const cv::Point2f d = cap.detected_px[i];
      if (!std::isfinite(d.x) || !std::isfinite(d.y)) continue;
      const Eigen::Vector2d q = Map(cap.H_shown, pattern_P[i]);
      const Eigen::Vector2d ideal = camera.UndistortPixel(Eigen::Vector2d(d.x, d.y));
      shown.emplace_back(q.x(), q.y());
      seen.emplace_back(ideal.x(), ideal.y());
    }
  }
  if (static_cast<int>(shown.size()) < options.min_points) {
    throw InputError(kSource, "captures",
                     std::to_string(shown.size()) + " detected features; need at least " +
                         std::to_string(options.min_points) + ": is the projected grid on the plane and in focus?");
  }
  const cv::Mat F_cv = cv::findHomography(shown, seen, 0);
  if (F_cv.empty()) throw InputError(kSource, "captures", "the detected features do not define a homography");
  const Eigen::Matrix3d F = ToEigen(F_cv);
  ProjectorHomographyStep step;
  step.F_img = F;
  double fit_sum = 0.0;
  for (size_t i = 0; i < shown.size(); ++i) {
    const Eigen::Vector2d p = Map(F, Eigen::Vector2d(shown[i].x, shown[i].y));
    fit_sum += (p - Eigen::Vector2d(seen[i].x, seen[i].y)).squaredNorm();
  }
  step.mapping_fit_rms_px = std::sqrt(fit_sum / shown.size());
  step.points_used = static_cast<int>(shown.size());

  // Initial H: the homography that would be exact without distortion, F^-1 * G.
  std::vector<cv::Point2d> from, to;
  for (size_t i = 0; i < pattern_P.size(); ++i) {
    const Eigen::Vector2d ideal = camera.UndistortPixel(target_C[i]);
    from.emplace_back(pattern_P[i].x(), pattern_P[i].y());
    to.emplace_back(ideal.x(), ideal.y());
  }
  const cv::Mat G_cv = cv::findHomography(from, to, 0);
  if (G_cv.empty()) throw InputError(kSource, "target_C", "the targets do not define a homography with the pattern");
  Eigen::Matrix3d H0 = F.inverse() * ToEigen(G_cv);
  H0 /= H0(2, 2);
  double h[8] = {H0(0, 0), H0(0, 1), H0(0, 2), H0(1, 0), H0(1, 1), H0(1, 2), H0(2, 0), H0(2, 1)};
  ceres::Problem problem;
  for (size_t i = 0; i < pattern_P.size(); ++i) {
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<TargetResidual, 2, 8>(
                                 new TargetResidual(camera, F, pattern_P[i], target_C[i])),
                             nullptr, h);
  }
  ceres::Solver::Options solver_options;
  solver_options.minimizer_type = ceres::TRUST_REGION;
  solver_options.trust_region_strategy_type = ceres::LEVENBERG_MARQUARDT;
  solver_options.linear_solver_type = ceres::DENSE_QR;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = 1e-14;
  solver_options.parameter_tolerance = 1e-14;
  solver_options.num_threads = 1;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary summary;
  ceres::Solve(solver_options, &problem, &summary);
  step.iterations = static_cast<int>(summary.iterations.size());
  step.H_P_rec << h[0], h[1], h[2], h[3], h[4], h[5], h[6], h[7], 1.0;
  double sum = 0.0;
  for (size_t i = 0; i < pattern_P.size(); ++i) {
    sum += (PredictCamera(camera, F, step.H_P_rec, pattern_P[i]) - target_C[i]).squaredNorm();
  }
  step.predicted_rms_px = std::sqrt(sum / pattern_P.size());
  return step;
}

ProjectorHomographyResult CalibrateProjectorHomography(
    const std::vector<Eigen::Vector2d>& pattern_P, const std::vector<Eigen::Vector2d>& target_C,
    const CameraModel& camera, const Eigen::Matrix3d& H_initial,
    const std::function<std::vector<cv::Point2f>(const Eigen::Matrix3d& H)>& observe,
    const ProjectorHomographyOptions& options) {
  if (const std::string p = options.Problem(); !p.empty()) throw InputError(kSource, "options", p);
  ProjectorHomographyResult result;
  std::vector<ProjectorCapture> captures;
  Eigen::Matrix3d H = H_initial / H_initial(2, 2);
  for (int k = 0; k < options.max_captures; ++k) {
    ProjectorCapture capture{H, observe(H)};
    // Observed residual with H shown: detected features vs targets.
    double sum = 0.0;
    int n = 0;
    for (size_t i = 0; i < capture.detected_px.size() && i < target_C.size(); ++i) {
      const cv::Point2f d = capture.detected_px[i];
      if (!std::isfinite(d.x) || !std::isfinite(d.y)) continue;
      sum += (Eigen::Vector2d(d.x, d.y) - target_C[i]).squaredNorm();
      ++n;
    }
    result.observed_rms_px.push_back(n > 0 ? std::sqrt(sum / n) : -1.0);
    captures.push_back(std::move(capture));
    result.captures = k + 1;
    const ProjectorHomographyStep step = SolveProjectorHomography(pattern_P, target_C, captures, camera, options);
    result.predicted_rms_px = step.predicted_rms_px;
    const double change_px = [&] {
      double worst = 0.0;
      for (const Eigen::Vector2d& x : pattern_P) {
        worst = std::max(
            worst,
            (PredictCamera(camera, step.F_img, step.H_P_rec, x) - PredictCamera(camera, step.F_img, H, x)).norm());
      }
      return worst;
    }();
    H = step.H_P_rec;
    result.H_P_rec = H;
    // Converged when the update moves no feature in the camera image by more than the tolerance.
    if (change_px < options.tolerance_px) {
      result.converged = true;
      break;
    }
  }
  return result;
}

}  // namespace romunect::calib
