#include "romunect/testing/analytic_bin.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

#include <Eigen/Geometry>

namespace romunect::testing {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kEpsilonT = 1e-12;  // hits at t <= this are behind the origin

// Bin: outer 120 x 55 x 35 mm, 3 mm walls and floor, standing on the table (z = 0) at the origin.
constexpr double kBinHalfX = 0.060, kBinHalfY = 0.0275, kBinHeight = 0.035, kWall = 0.003;

// Ray against an axis-aligned box [lo, hi]; entry t or +inf.
double SlabHit(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& lo,
               const Eigen::Vector3d& hi) {
  double t0 = -kInf, t1 = kInf;
  for (int a = 0; a < 3; ++a) {
    if (d[a] == 0.0) {
      if (o[a] < lo[a] || o[a] > hi[a]) return kInf;
      continue;
    }
    double ta = (lo[a] - o[a]) / d[a], tb = (hi[a] - o[a]) / d[a];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
  }
  if (t0 > t1 || t1 <= kEpsilonT) return kInf;
  return t0 > kEpsilonT ? t0 : kInf;  // origins inside a solid do not occur here
}

double SolidHit(const AnalyticBin::Solid& s, const Eigen::Vector3d& o_W, const Eigen::Vector3d& d_W) {
  const Eigen::Vector3d o = s.R_W_L.transpose() * (o_W - s.centre_W);
  const Eigen::Vector3d d = s.R_W_L.transpose() * d_W;
  switch (s.kind) {
    case AnalyticBin::Solid::kBox: return SlabHit(o, d, -s.half_size, s.half_size);
    case AnalyticBin::Solid::kSphere: {
      const double r = s.half_size.x();
      const double a = d.squaredNorm(), b = o.dot(d), c = o.squaredNorm() - r * r;
      const double disc = b * b - a * c;
      if (disc < 0.0) return kInf;
      const double t = (-b - std::sqrt(disc)) / a;
      return t > kEpsilonT ? t : kInf;
    }
    case AnalyticBin::Solid::kCylinder: {
      const double r = s.half_size.x(), h = s.half_size.z();
      double best = kInf;
      const double a = d.x() * d.x() + d.y() * d.y();
      if (a > 0.0) {  // the side
        const double b = o.x() * d.x() + o.y() * d.y(), c = o.x() * o.x() + o.y() * o.y() - r * r;
        const double disc = b * b - a * c;
        if (disc >= 0.0) {
          const double t = (-b - std::sqrt(disc)) / a;
          if (t > kEpsilonT && std::abs(o.z() + t * d.z()) <= h) best = t;
        }
      }
      if (d.z() != 0.0) {  // the caps
        for (double cap : {-h, h}) {
          const double t = (cap - o.z()) / d.z();
          if (t <= kEpsilonT || t >= best) continue;
          const double x = o.x() + t * d.x(), y = o.y() + t * d.y();
          if (x * x + y * y <= r * r) best = t;
        }
      }
      return best;
    }
  }
  return kInf;
}

AnalyticBin::Solid Box(const Eigen::Vector3d& centre, const Eigen::Vector3d& half, double yaw_rad = 0.0) {
  return {AnalyticBin::Solid::kBox, centre, Eigen::AngleAxisd(yaw_rad, Eigen::Vector3d::UnitZ()).toRotationMatrix(),
          half};
}

}  // namespace

AnalyticBin::AnalyticBin(const AnalyticBinOptions& options) : options_(options) {
  camera_.width = options.width;
  camera_.height = options.height;
  camera_.fx = options.width * 0.200 / 0.060;   // 60 mm across at 200 mm
  camera_.fy = options.height * 0.200 / 0.045;  // 45 mm down at 200 mm
  camera_.cx = (options.width - 1) / 2.0;
  camera_.cy = (options.height - 1) / 2.0;
  camera_.distortion = options.distortion;

  // The bin: floor and four walls.
  solids_.push_back(Box({0, 0, kWall / 2}, {kBinHalfX, kBinHalfY, kWall / 2}));
  for (double sx : {-1.0, 1.0}) {
    solids_.push_back(Box({sx * (kBinHalfX - kWall / 2), 0, kBinHeight / 2}, {kWall / 2, kBinHalfY, kBinHeight / 2}));
  }
  for (double sy : {-1.0, 1.0}) {
    solids_.push_back(Box({0, sy * (kBinHalfY - kWall / 2), kBinHeight / 2}, {kBinHalfX, kWall / 2, kBinHeight / 2}));
  }
  // Objects on the bin floor, placed from the seed.
  std::mt19937 rng(options.seed);
  auto uniform = [&](double lo, double hi) { return std::uniform_real_distribution<double>(lo, hi)(rng); };
  const double floor_z = kWall;
  const double x_lo = -kBinHalfX + kWall + 0.012, x_hi = kBinHalfX - kWall - 0.012;
  const double y_lo = -kBinHalfY + kWall + 0.008, y_hi = kBinHalfY - kWall - 0.008;
  for (int i = 0; i < 3; ++i) {  // boxes
    const Eigen::Vector3d half(uniform(0.004, 0.010), uniform(0.003, 0.008), uniform(0.003, 0.010));
    solids_.push_back(Box({uniform(x_lo, x_hi), uniform(y_lo, y_hi), floor_z + half.z()}, half, uniform(0.0, M_PI)));
  }
  for (int i = 0; i < 3; ++i) {  // spheres
    const double r = uniform(0.004, 0.009);
    solids_.push_back({Solid::kSphere, Eigen::Vector3d(uniform(x_lo, x_hi), uniform(y_lo, y_hi), floor_z + r),
                       Eigen::Matrix3d::Identity(), Eigen::Vector3d::Constant(r)});
  }
  for (int i = 0; i < 2; ++i) {  // standing cylinders
    const double r = uniform(0.003, 0.007), h = uniform(0.004, 0.012);
    solids_.push_back({Solid::kCylinder, Eigen::Vector3d(uniform(x_lo, x_hi), uniform(y_lo, y_hi), floor_z + h),
                       Eigen::Matrix3d::Identity(), Eigen::Vector3d(r, r, h)});
  }
  {  // a lying cylinder (axis horizontal)
    const double r = uniform(0.003, 0.006), h = uniform(0.008, 0.014);
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(uniform(0.0, M_PI), Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(M_PI / 2, Eigen::Vector3d::UnitX()))
                                  .toRotationMatrix();
    solids_.push_back({Solid::kCylinder, Eigen::Vector3d(uniform(x_lo, x_hi), uniform(y_lo, y_hi), floor_z + r), R,
                       Eigen::Vector3d(r, r, h)});
  }

  // Poses: descending, sweeping in x, weaving in y, tilting a few degrees.
  const int n = options.frames;
  for (int i = 0; i < n; ++i) {
    const double s = n > 1 ? static_cast<double>(i) / (n - 1) : 0.0;
    const double z = options.start_height_m + (options.end_height_m - options.start_height_m) * s;
    const Eigen::Vector3d t(-0.035 + 0.07 * s, 0.010 * std::sin(2 * M_PI * s), z);
    const double deg = M_PI / 180.0;
    const Eigen::Matrix3d R = (Eigen::AngleAxisd(4 * deg * std::sin(3 * s), Eigen::Vector3d::UnitZ()) *
                               Eigen::AngleAxisd(3 * deg * std::sin(2 * M_PI * s + 1.0), Eigen::Vector3d::UnitY()) *
                               Eigen::AngleAxisd(3 * deg * std::cos(2 * M_PI * s), Eigen::Vector3d::UnitX()) *
                               Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()))  // C looks down
                                  .toRotationMatrix();
    poses_.push_back(MakePose(R, t));
  }
}

double AnalyticBin::Intersect(const Eigen::Vector3d& o, const Eigen::Vector3d& d) const {
  double best = d.z() < 0.0 && o.z() > 0.0 ? (0.0 - o.z()) / d.z() : kInf;  // the table
  if (SlabHit(o, d, Eigen::Vector3d(-kBinHalfX, -kBinHalfY, 0.0), Eigen::Vector3d(kBinHalfX, kBinHalfY, kBinHeight)) ==
          kInf &&
      !(std::abs(o.x()) <= kBinHalfX && std::abs(o.y()) <= kBinHalfY && o.z() <= kBinHeight)) {
    return best;  // misses the bin and everything in it
  }
  for (const Solid& s : solids_) best = std::min(best, SolidHit(s, o, d));
  return best;
}

double AnalyticBin::HeightAt(double x_m, double y_m) const {
  const double top = 1.0;
  return top - Intersect(Eigen::Vector3d(x_m, y_m, top), Eigen::Vector3d(0, 0, -1));
}

Frame AnalyticBin::RenderFrame(int i) const {
  Frame f;
  f.index = i;
  f.time_s = i / 30.0;
  f.T_W_C = poses_.at(i);
  const int w = camera_.width, h = camera_.height;
  f.depth_m.create(h, w, CV_32F);
  f.gt_depth_m.create(h, w, CV_32F);
  std::mt19937 rng(options_.seed * 7919u + 104729u * static_cast<uint32_t>(i + 1));
  std::normal_distribution<double> noise(0.0, options_.noise_m);
  const double invalid = std::uniform_real_distribution<double>(options_.min_invalid, options_.max_invalid)(rng);
  // Blobs: a coarse random field, bilinearly upsampled, thresholded at the invalid share.
  constexpr int kGw = 9, kGh = 7;
  double field[kGh][kGw];
  for (auto& row : field) {
    for (double& value : row) value = std::uniform_real_distribution<double>(0.0, 1.0)(rng);
  }
  cv::Mat blob(h, w, CV_32F);
  for (int v = 0; v < h; ++v) {
    const double gy = (kGh - 1) * (v + 0.5) / h;
    const int y0 = std::min(static_cast<int>(gy), kGh - 2);
    const double fy = gy - y0;
    for (int u = 0; u < w; ++u) {
      const double gx = (kGw - 1) * (u + 0.5) / w;
      const int x0 = std::min(static_cast<int>(gx), kGw - 2);
      const double fx = gx - x0;
      blob.at<float>(v, u) = static_cast<float>((1 - fy) * ((1 - fx) * field[y0][x0] + fx * field[y0][x0 + 1]) +
                                                fy * ((1 - fx) * field[y0 + 1][x0] + fx * field[y0 + 1][x0 + 1]));
    }
  }
  std::vector<float> sorted(blob.begin<float>(), blob.end<float>());
  const size_t k = std::min(sorted.size() - 1, static_cast<size_t>(invalid * sorted.size()));
  std::nth_element(sorted.begin(), sorted.begin() + k, sorted.end());
  const float threshold = sorted[k];

  const Eigen::Matrix3d R = f.T_W_C->linear();
  const Eigen::Vector3d o = f.T_W_C->translation();
  for (int v = 0; v < h; ++v) {
    for (int u = 0; u < w; ++u) {
      const Eigen::Vector3d ray_C = camera_.Ray(Eigen::Vector2d(u, v));  // z = 1: t is depth
      const double t = Intersect(o, R * ray_C);
      const double noisy = t + noise(rng);  // drawn for every pixel, so blobs do not shift the noise
      const bool valid = std::isfinite(t) && blob.at<float>(v, u) >= threshold;
      f.gt_depth_m.at<float>(v, u) = std::isfinite(t) ? static_cast<float>(t) : 0.0f;
      f.depth_m.at<float>(v, u) = valid && noisy > 0.0 ? static_cast<float>(noisy) : 0.0f;
    }
  }
  return f;
}

cv::Mat AnalyticBin::GroundTruthHeightMap(const Eigen::Vector3d& min_W, double voxel_m, int nx, int ny) const {
  cv::Mat height(ny, nx, CV_32F);
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      height.at<float>(j, i) = static_cast<float>(
          HeightAt(min_W.x() + (i + 0.5) * voxel_m, min_W.y() + (j + 0.5) * voxel_m));
    }
  }
  return height;
}

}  // namespace romunect::testing
