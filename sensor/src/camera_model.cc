#include "romunect/sensor/camera_model.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <sstream>

#include <Eigen/LU>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/input_limits.h"

namespace romunect {
namespace {

// Distorted coordinates and their 2x2 Jacobian with respect to (x_n, y_n).
Eigen::Vector2d DistortWithJacobian(const std::array<double, 5>& d, const Eigen::Vector2d& xy, Eigen::Matrix2d* J) {
  const double k1 = d[0], k2 = d[1], p1 = d[2], p2 = d[3], k3 = d[4];
  const double x = xy.x(), y = xy.y();
  const double r2 = x * x + y * y;
  const double radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3));
  const Eigen::Vector2d out(x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                            y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y);
  if (J != nullptr) {
    // d(radial)/d(r2), and d(r2)/dx = 2x, d(r2)/dy = 2y.
    const double dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2);
    (*J)(0, 0) = radial + x * dradial * 2.0 * x + 2.0 * p1 * y + p2 * 6.0 * x;
    (*J)(0, 1) = x * dradial * 2.0 * y + 2.0 * p1 * x + p2 * 2.0 * y;
    (*J)(1, 0) = y * dradial * 2.0 * x + p1 * 2.0 * x + 2.0 * p2 * y;
    (*J)(1, 1) = radial + y * dradial * 2.0 * y + p1 * 6.0 * y + 2.0 * p2 * x;
  }
  return out;
}

double ReadNumber(const cv::FileNode& node, const char* key, const std::string& source) {
  const cv::FileNode n = node[key];
  if (n.empty() || (!n.isReal() && !n.isInt())) {
    throw InputError(source, key, "missing or not a number");
  }
  return static_cast<double>(n);
}

}  // namespace

std::string CameraModel::Problem() const {
  std::ostringstream s;
  // Physical bounds: focal lengths for fields of view from ~0.1 to ~179 degrees, a principal point
  // within 10 image sizes or 10 focal lengths of the image (a window cut from a larger image, as
  // the dataset check renders, keeps its optical axis outside it), distortion far beyond any lens's (|k| <= 100, |p| <= 1).
  const double side_px = std::max(width, height);
  if (width <= 0 || height <= 0) {
    s << "image size " << width << " x " << height << " must be positive";
  } else if (width > kMaxImageSidePx || height > kMaxImageSidePx ||
             static_cast<int64_t>(width) * height > kMaxImagePixels) {
    s << "image size " << width << " x " << height << " is beyond " << kMaxImageSidePx << " pixels a side or "
      << kMaxImagePixels << " pixels";
  } else if (!(std::isfinite(fx) && std::isfinite(fy) && fx > 0 && fy > 0)) {
    s << "focal lengths fx = " << fx << ", fy = " << fy << " must be positive and finite";
  } else if (!(fx >= 0.005 * side_px && fy >= 0.005 * side_px && fx <= 1000 * side_px && fy <= 1000 * side_px)) {
    s << "focal lengths fx = " << fx << ", fy = " << fy << " px must lie in [" << 0.005 * side_px << ", "
      << 1000 * side_px << "] (0.005 to 1000 times the image's longer side)";
  } else if (!(std::isfinite(cx) && std::isfinite(cy))) {
    s << "principal point must be finite";
  } else if (const double reach_px = 10.0 * std::max({side_px, fx, fy});
             !(std::abs(cx) <= reach_px && std::abs(cy) <= reach_px)) {
    s << "principal point (" << cx << ", " << cy << ") must lie within 10 image sizes or focal lengths of the image";
  } else {
    for (double k : distortion) {
      if (!std::isfinite(k)) return "distortion coefficients must be finite";
    }
    for (int i : {0, 1, 4}) {
      if (std::abs(distortion[i]) > 100.0) return "radial distortion k1, k2, k3 must lie in [-100, 100]";
    }
    for (int i : {2, 3}) {
      if (std::abs(distortion[i]) > 1.0) return "tangential distortion p1, p2 must lie in [-1, 1]";
    }
    // Distortion must stay invertible over the image: every border pixel has an undistorted
    // preimage, and the Jacobian of Distort stays positive on the way out to it.
    for (double u : {0.0, 0.5 * (width - 1), width - 1.0}) {
      for (double v : {0.0, 0.5 * (height - 1), height - 1.0}) {
        const Eigen::Vector2d xy_d((u - cx) / fx, (v - cy) / fy);
        const Eigen::Vector2d xy = Undistort(xy_d);
        bool folds = !((Distort(xy) - xy_d).norm() < 1e-9);
        for (int k = 1; k <= 64 && !folds; ++k) {
          Eigen::Matrix2d J;
          DistortWithJacobian(distortion, xy * (k / 64.0), &J);
          folds = !(J.determinant() > 0.0);
        }
        if (folds) {
          s << "distortion is not invertible out to pixel (" << u << ", " << v << ")";
          return s.str();
        }
      }
    }
  }
  return s.str();
}

bool CameraModel::HasDistortion() const {
  for (double k : distortion) {
    if (k != 0.0) return true;
  }
  return false;
}

Eigen::Vector2d CameraModel::Distort(const Eigen::Vector2d& xy_n) const {
  return DistortWithJacobian(distortion, xy_n, nullptr);
}

Eigen::Vector2d CameraModel::Undistort(const Eigen::Vector2d& xy_d) const {
  if (!HasDistortion()) return xy_d;
  // Gauss-Newton on Distort(xy) = xy_d, started at xy_d. Converges in a handful of steps
  // for lens distortions of real cameras; capped so a pathological model cannot hang.
  Eigen::Vector2d xy = xy_d;
  for (int iteration = 0; iteration < 50; ++iteration) {
    Eigen::Matrix2d J;
    const Eigen::Vector2d residual = DistortWithJacobian(distortion, xy, &J) - xy_d;
    const Eigen::Vector2d step = J.partialPivLu().solve(residual);
    xy -= step;
    if (step.squaredNorm() < 1e-32) break;
  }
  return xy;
}

std::optional<Eigen::Vector2d> CameraModel::Project(const Eigen::Vector3d& p_C) const {
  if (!(p_C.z() > 0.0)) return std::nullopt;
  const Eigen::Vector2d xy_d = Distort(p_C.head<2>() / p_C.z());
  return Eigen::Vector2d(fx * xy_d.x() + cx, fy * xy_d.y() + cy);
}

Eigen::Vector3d CameraModel::Ray(const Eigen::Vector2d& u_px) const {
  const Eigen::Vector2d xy_n = Undistort(Eigen::Vector2d((u_px.x() - cx) / fx, (u_px.y() - cy) / fy));
  return Eigen::Vector3d(xy_n.x(), xy_n.y(), 1.0);
}

Eigen::Vector3d CameraModel::Unproject(const Eigen::Vector2d& u_px, double depth_m) const {
  return depth_m * Ray(u_px);
}

Eigen::Vector2d CameraModel::UndistortPixel(const Eigen::Vector2d& u_px) const {
  const Eigen::Vector3d ray = Ray(u_px);
  return Eigen::Vector2d(fx * ray.x() + cx, fy * ray.y() + cy);
}

bool CameraModel::Contains(const Eigen::Vector2d& u_px) const {
  return u_px.x() >= -0.5 && u_px.y() >= -0.5 && u_px.x() < width - 0.5 && u_px.y() < height - 0.5;
}

cv::Mat CameraModel::RayTable() const {
  cv::Mat table(height, width, CV_32FC2);
  for (int v = 0; v < height; ++v) {
    auto* row = table.ptr<cv::Vec2f>(v);
    for (int u = 0; u < width; ++u) {
      const Eigen::Vector3d ray = Ray(Eigen::Vector2d(u, v));
      row[u] = cv::Vec2f(static_cast<float>(ray.x()), static_cast<float>(ray.y()));
    }
  }
  return table;
}

cv::Matx33d CameraModel::CameraMatrix() const { return cv::Matx33d(fx, 0, cx, 0, fy, cy, 0, 0, 1); }

cv::Mat CameraModel::DistortionVector() const {
  cv::Mat d(1, 5, CV_64F);
  for (int i = 0; i < 5; ++i) d.at<double>(0, i) = distortion[i];
  return d;
}

void CameraModel::Write(cv::FileStorage& fs) const {
  fs << "image_width" << width << "image_height" << height;
  fs << "camera_matrix" << cv::Mat(CameraMatrix());
  fs << "distortion_coefficients" << DistortionVector();
}

CameraModel CameraModel::Read(const cv::FileNode& node, const std::string& source) {
  CameraModel camera;
  const double width = ReadNumber(node, "image_width", source);
  const double height = ReadNumber(node, "image_height", source);
  if (width != std::floor(width) || height != std::floor(height)) {
    throw InputError(source, "image_width/image_height", "must be whole numbers");
  }
  // Checked before the cast: a double beyond int's range (1e300) has no int.
  if (!(width >= 1 && height >= 1 && width <= kMaxImageSidePx && height <= kMaxImageSidePx)) {
    throw InputError(source, "image_width/image_height",
                     "must lie in [1, " + std::to_string(kMaxImageSidePx) + "] pixels");
  }
  camera.width = static_cast<int>(width);
  camera.height = static_cast<int>(height);
  cv::Mat K, d;
  CheckMatrixNode(node["camera_matrix"], 3, 3, source, "camera_matrix");
  CheckMatrixNode(node["distortion_coefficients"], 14, 14, source, "distortion_coefficients");
  try {
    node["camera_matrix"] >> K;
    node["distortion_coefficients"] >> d;
  } catch (const cv::Exception& e) {
    throw InputError(source, "camera_matrix", std::string("cannot be read: ") + e.what());
  }
  if (K.rows != 3 || K.cols != 3) {
    throw InputError(source, "camera_matrix", "expected a 3x3 matrix");
  }
  K.convertTo(K, CV_64F);
  if (K.at<double>(0, 1) != 0.0 || K.at<double>(1, 0) != 0.0 || K.at<double>(2, 0) != 0.0 ||
      K.at<double>(2, 1) != 0.0 || K.at<double>(2, 2) != 1.0) {
    throw InputError(source, "camera_matrix", "expected [fx 0 cx; 0 fy cy; 0 0 1] (no skew)");
  }
  camera.fx = K.at<double>(0, 0);
  camera.fy = K.at<double>(1, 1);
  camera.cx = K.at<double>(0, 2);
  camera.cy = K.at<double>(1, 2);
  if (d.total() != 5 && d.total() != 4) {
    throw InputError(source, "distortion_coefficients",
                     "expected 5 numbers k1 k2 p1 p2 k3 (or 4), got " + std::to_string(d.total()));
  }
  d.convertTo(d, CV_64F);
  for (size_t i = 0; i < d.total(); ++i) camera.distortion[i] = d.at<double>(static_cast<int>(i));
  if (const std::string problem = camera.Problem(); !problem.empty()) {
    throw InputError(source, "camera", problem);
  }
  return camera;
}

void CameraModel::Save(const std::filesystem::path& path) const {
  ROMUNECT_CHECK(Problem().empty());
  WriteAtomically(path, [&](const std::filesystem::path& tmp) {
    // FileStorage picks its format from the extension: keep the real one on the temporary.
    cv::FileStorage fs(tmp.string(), cv::FileStorage::WRITE | cv::FileStorage::FORMAT_AUTO);
    if (!fs.isOpened()) throw InputError(path.string(), "", "cannot open for writing");
    Write(fs);
  });
}

CameraModel CameraModel::Load(const std::filesystem::path& path) {
  const cv::FileStorage fs = OpenFileStorage(path, "YAML/JSON/XML camera file");
  try {
    return Read(fs.root(), path.string());
  } catch (const InputError&) {
    throw;
  } catch (const std::exception& e) {  // OpenCV's: a node of another kind than asked for (a list for a map)
    throw InputError(path.string(), "", std::string("not a valid camera file: ") + e.what());
  }
}

}  // namespace romunect
