#include "analytic_geometry.h"

#include <cmath>
#include <limits>

#include <Eigen/Geometry>

namespace romunect::testing {

AnalyticScene AnalyticScene::TiltedPlane(double depth_m, double tilt_rad, const IrMaterial& material) {
  AnalyticScene scene;
  scene.materials = {material};
  scene.planes.push_back(
      {Eigen::Vector3d(0, 0, depth_m), Eigen::Vector3d(std::sin(tilt_rad), 0, -std::cos(tilt_rad)), 0, 1});
  return scene;
}

double FirstHit(const AnalyticScene& scene, const Eigen::Vector3d& o, const Eigen::Vector3d& d, double t_min,
                Eigen::Vector3d* normal, int* material, int* id) {
  double best = std::numeric_limits<double>::infinity();
  auto take = [&](double t, const Eigen::Vector3d& n, int m, int i) {
    if (t > t_min && t < best) {
      best = t;
      if (normal) *normal = n;
      if (material) *material = m;
      if (id) *id = i;
    }
  };
  for (const auto& p : scene.planes) {
    const double denom = p.normal_C.dot(d);
    if (std::abs(denom) < 1e-15) continue;
    take((p.point_C - o).dot(p.normal_C) / denom, p.normal_C, p.material, p.id);
  }
  for (const auto& b : scene.boxes) {
    // Slabs: the entry is the largest of the per-axis near planes.
    double t0 = -std::numeric_limits<double>::infinity(), t1 = std::numeric_limits<double>::infinity();
    int axis = -1;
    double sign = 0;
    bool miss = false;
    for (int k = 0; k < 3 && !miss; ++k) {
      if (std::abs(d[k]) < 1e-15) {
        miss = o[k] < b.min_C[k] || o[k] > b.max_C[k];
        continue;
      }
      double ta = (b.min_C[k] - o[k]) / d[k], tb = (b.max_C[k] - o[k]) / d[k];
      double s = -1;  // entering through the min face: outward normal -axis
      if (ta > tb) {
        std::swap(ta, tb);
        s = 1;
      }
      if (ta > t0) {
        t0 = ta;
        axis = k;
        sign = s;
      }
      t1 = std::min(t1, tb);
    }
    if (miss || t0 > t1 || axis < 0) continue;
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    n[axis] = sign;
    take(t0, n, b.material, b.id);
  }
  for (const auto& s : scene.spheres) {
    const Eigen::Vector3d oc = o - s.centre_C;
    const double a = d.squaredNorm(), hb = oc.dot(d), c = oc.squaredNorm() - s.radius_m * s.radius_m;
    const double disc = hb * hb - a * c;
    if (disc < 0) continue;
    const double t = (-hb - std::sqrt(disc)) / a;
    take(t, (o + t * d - s.centre_C).normalized(), s.material, s.id);
  }
  return best;
}

GeometryBuffer RenderAnalytic(const AnalyticScene& scene, const CameraModel& camera,
                              const Eigen::Vector3d& projector_centre_C) {
  GeometryBuffer buffer;
  buffer.materials = scene.materials;
  GeometryLayer layer;
  const cv::Size size(camera.width, camera.height);
  const float nan = std::numeric_limits<float>::quiet_NaN();
  layer.p_C = cv::Mat(size, CV_32FC3, cv::Scalar(nan, nan, nan));
  layer.normal_C = cv::Mat(size, CV_32FC3, cv::Scalar(0, 0, 0));
  layer.material = cv::Mat(size, CV_32S, cv::Scalar(-1));
  layer.object_id = cv::Mat(size, CV_32S, cv::Scalar(-1));
  layer.lit = cv::Mat(size, CV_8U, cv::Scalar(0));
  const cv::Mat rays = camera.RayTable();
  for (int y = 0; y < size.height; ++y) {
    for (int x = 0; x < size.width; ++x) {
      const cv::Vec2f r = rays.at<cv::Vec2f>(y, x);
      const Eigen::Vector3d dir(r[0], r[1], 1.0);
      Eigen::Vector3d n;
      int m = -1, id = -1;
      const double t = FirstHit(scene, Eigen::Vector3d::Zero(), dir, 1e-9, &n, &m, &id);
      if (!std::isfinite(t)) continue;
      const Eigen::Vector3d p = t * dir;
      if (n.dot(dir) > 0) n = -n;  // facing the camera
      layer.p_C.at<cv::Vec3f>(y, x) = cv::Vec3f(p.x(), p.y(), p.z());
      layer.normal_C.at<cv::Vec3f>(y, x) = cv::Vec3f(n.x(), n.y(), n.z());
      layer.material.at<int>(y, x) = m;
      layer.object_id.at<int>(y, x) = id;
      // Shadow ray: anything between the hit and the projector centre (segment t in (0, 1)).
      const Eigen::Vector3d to_p = projector_centre_C - p;
      const double blocker = FirstHit(scene, p, to_p, 1e-7, nullptr, nullptr, nullptr);
      layer.lit.at<uint8_t>(y, x) = (blocker < 1.0 || n.dot(to_p) <= 0) ? 0 : 1;
    }
  }
  buffer.layers.push_back(std::move(layer));
  return buffer;
}

cv::Mat TruthDepth(const GeometryBuffer& buffer) {
  const cv::Mat& p = buffer.layers.at(0).p_C;
  cv::Mat depth(p.size(), CV_32F, cv::Scalar(0));
  for (int y = 0; y < p.rows; ++y) {
    for (int x = 0; x < p.cols; ++x) {
      const float z = p.at<cv::Vec3f>(y, x)[2];
      if (std::isfinite(z)) depth.at<float>(y, x) = z;
    }
  }
  return depth;
}

}  // namespace romunect::testing
