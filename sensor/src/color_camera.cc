#include "romunect/sensor/color_camera.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "romunect/sensor/check.h"

namespace romunect {

std::string ColorCamera::Problem() const {
  if (const std::string p = camera.Problem(); !p.empty()) return "camera: " + p;
  if (const std::string p = RigidityProblem(T_C_RGB.matrix()); !p.empty()) return "T_C_RGB: " + p;
  return "";
}

ColorCamera StockColorCamera() {
  ColorCamera c;
  c.camera.width = 640;
  c.camera.height = 480;
  c.camera.fx = c.camera.fy = 525.0;
  c.camera.cx = 319.5;
  c.camera.cy = 239.5;
  c.T_C_RGB = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.025, 0.0, 0.0));
  return c;
}

CameraModel ScaledCamera(const CameraModel& camera, int width, int height) {
  const double sx = static_cast<double>(width) / camera.width, sy = static_cast<double>(height) / camera.height;
  CameraModel out = camera;
  out.width = width;
  out.height = height;
  out.fx *= sx;
  out.fy *= sy;
  out.cx = (camera.cx + 0.5) * sx - 0.5;
  out.cy = (camera.cy + 0.5) * sy - 0.5;
  return out;
}

cv::Mat RegisterDepthToColor(const cv::Mat& depth_m, const CameraModel& depth_camera, const ColorCamera& color,
                             const cv::Size& out_size) {
  ROMUNECT_CHECK(depth_m.type() == CV_32F && depth_m.cols == depth_camera.width && depth_m.rows == depth_camera.height);
  const CameraModel target = ScaledCamera(color.camera, out_size.width, out_size.height);
  const cv::Mat rays = depth_camera.RayTable();
  const Pose T_RGB_C = color.T_C_RGB.inverse();
  const Eigen::Matrix3f R = T_RGB_C.linear().cast<float>();
  const Eigen::Vector3f t = T_RGB_C.translation().cast<float>();
  cv::Mat out(out_size, CV_32F, cv::Scalar(0.0f));
  for (int v = 0; v < depth_m.rows; ++v) {
    const float* d = depth_m.ptr<float>(v);
    const auto* ray = rays.ptr<cv::Vec2f>(v);
    for (int u = 0; u < depth_m.cols; ++u) {
      if (!(d[u] > 0.0f)) continue;
      const Eigen::Vector3f p_RGB = R * Eigen::Vector3f(ray[u][0] * d[u], ray[u][1] * d[u], d[u]) + t;
      const auto px = target.Project(p_RGB.cast<double>());
      if (!px || !target.Contains(*px)) continue;
      const int x = static_cast<int>(std::lround(px->x())), y = static_cast<int>(std::lround(px->y()));
      float& cell = out.at<float>(y, x);
      if (cell == 0.0f || p_RGB.z() < cell) cell = p_RGB.z();
    }
  }
  return out;
}

std::optional<Eigen::Vector2d> DepthPixelToColor(const Eigen::Vector2d& u_px, double depth_m,
                                                 const CameraModel& depth_camera, const ColorCamera& color) {
  const Eigen::Vector3d p_C = depth_camera.Unproject(u_px, depth_m);
  return color.camera.Project(color.T_C_RGB.inverse() * p_C);
}

cv::Mat ShadeColorImage(const GeometryBuffer& geometry, double exposure_distance_m) {
  ROMUNECT_CHECK(!geometry.layers.empty() && exposure_distance_m > 0.0);
  // Eight tints far apart in hue, light enough that shading shows on each.
  static constexpr std::array<std::array<float, 3>, 8> kTints = {{{1.00f, 0.85f, 0.70f},
                                                                  {0.55f, 0.75f, 1.00f},
                                                                  {0.65f, 1.00f, 0.60f},
                                                                  {1.00f, 0.60f, 0.60f},
                                                                  {0.95f, 0.95f, 0.55f},
                                                                  {0.85f, 0.60f, 1.00f},
                                                                  {0.55f, 1.00f, 0.95f},
                                                                  {1.00f, 1.00f, 1.00f}}};
  const GeometryLayer& g = geometry.layers[0];
  const float exposure2 = static_cast<float>(exposure_distance_m * exposure_distance_m);
  cv::Mat rgb(g.p_C.size(), CV_8UC3, cv::Scalar(0, 0, 0));
  for (int v = 0; v < rgb.rows; ++v) {
    const auto* p = g.p_C.ptr<cv::Vec3f>(v);
    const auto* n = g.normal_C.ptr<cv::Vec3f>(v);
    const int* material = g.material.ptr<int>(v);
    const int* id = g.object_id.ptr<int>(v);
    auto* out = rgb.ptr<cv::Vec3b>(v);
    for (int u = 0; u < rgb.cols; ++u) {
      if (material[u] < 0 || !std::isfinite(p[u][0])) continue;
      const float r2 = p[u].dot(p[u]);
      // The light comes from the camera centre: the cosine is the normal against the way back.
      const float cosine = std::max(0.0f, -n[u].dot(p[u]) / std::sqrt(r2));
      const float albedo = geometry.materials[static_cast<size_t>(material[u])].albedo;
      const float level = albedo * cosine * exposure2 / r2;
      const auto& tint = kTints[static_cast<size_t>(std::max(id[u], 0)) % kTints.size()];
      for (int c = 0; c < 3; ++c) {
        out[u][c] = static_cast<uint8_t>(std::lround(255.0f * std::clamp(level * tint[c], 0.0f, 1.0f)));
      }
    }
  }
  return rgb;
}

}  // namespace romunect
