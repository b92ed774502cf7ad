#include "romunect/tools/jobs/info.h"

#include <algorithm>
#include <limits>

#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/tools/jobs/text.h"

namespace romunect::jobs {

FrameDirectoryInfo InspectFrameDirectory(const std::filesystem::path& dir) {
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir);
  FrameDirectoryInfo info;
  info.dir = dir;
  info.camera = manifest.camera;
  info.frames = manifest.frames.size();
  info.region_W = manifest.region_W;
  info.color_camera = manifest.color_camera;
  if (info.frames > 0) {
    info.first_time_s = manifest.frames.front().time_s;
    info.last_time_s = manifest.frames.back().time_s;
  }
  double valid_sum = 0.0, raw_valid_sum = 0.0;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  std::optional<Eigen::Vector3d> previous;
  for (size_t i = 0; i < info.frames; ++i) {
    const FrameRecord& r = manifest.frames[i];
    const Frame frame = LoadFrame(dir, manifest, i);  // throws on any bad image
    info.with_depth += !r.depth.empty();
    info.with_ir += !r.ir.empty();
    info.with_raw += !r.raw.empty();
    info.with_gt_depth += !r.gt_depth.empty();
    info.with_color += !r.color.empty();
    info.with_hand_pose += r.T_B_H.has_value();
    if (!frame.depth_m.empty()) {
      const double valid = static_cast<double>(cv::countNonZero(frame.depth_m)) / frame.depth_m.total();
      valid_sum += valid;
      info.valid_min = std::min(info.valid_min, valid);
      info.valid_max = std::max(info.valid_max, valid);
    }
    if (!frame.raw.empty()) {
      const double valid = static_cast<double>(cv::countNonZero(frame.raw < kRawInvalid)) / frame.raw.total();
      raw_valid_sum += valid;
      info.raw_valid_min = std::min(info.raw_valid_min, valid);
      info.raw_valid_max = std::max(info.raw_valid_max, valid);
    }
    if (r.T_W_C) {
      ++info.with_pose;
      const Eigen::Vector3d p = r.T_W_C->translation();
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
      if (previous) info.path_m += (p - *previous).norm();
      previous = p;
    }
  }
  if (info.with_depth > 0) info.valid_mean = valid_sum / info.with_depth;
  if (info.with_raw > 0) info.raw_valid_mean = raw_valid_sum / info.with_raw;
  if (info.with_pose > 0) {
    info.cameras_min_W = lo;
    info.cameras_max_W = hi;
  }
  return info;
}

std::string FrameDirectoryInfoText(const FrameDirectoryInfo& info) {
  const CameraModel& c = info.camera;
  std::string text = "frame directory: " + info.dir.string() + "\n";
  text += Format("camera: %d x %d px, fx %.3f fy %.3f cx %.3f cy %.3f, distortion [%g %g %g %g %g]\n", c.width,
                 c.height, c.fx, c.fy, c.cx, c.cy, c.distortion[0], c.distortion[1], c.distortion[2], c.distortion[3],
                 c.distortion[4]);
  text += Format("frames: %zu", info.frames);
  if (info.frames > 0) {
    const double t0 = info.first_time_s, t1 = info.last_time_s;
    text += Format(", time %.3f .. %.3f s", t0, t1);
    if (info.frames > 1 && t1 > t0) text += Format(" (%.1f Hz)", (info.frames - 1) / (t1 - t0));
  }
  text += "\n";
  if (const std::optional<ColorCamera>& rgb = info.color_camera) {
    const Eigen::Vector3d t = rgb->T_C_RGB.translation();
    text += Format("colour camera: %d x %d px, fx %.3f fy %.3f cx %.3f cy %.3f, at (%.4f, %.4f, %.4f) m in C\n",
                   rgb->camera.width, rgb->camera.height, rgb->camera.fx, rgb->camera.fy, rgb->camera.cx,
                   rgb->camera.cy, t.x(), t.y(), t.z());
  }
  text += Format("images: depth %zu, ir %zu, raw %zu, gt_depth %zu, color %zu; poses T_W_C %zu, T_B_H %zu\n",
                 info.with_depth, info.with_ir, info.with_raw, info.with_gt_depth, info.with_color, info.with_pose,
                 info.with_hand_pose);
  if (info.with_depth > 0) {
    text += Format("valid depth pixels: mean %.1f %% (min %.1f %%, max %.1f %%)\n", 100.0 * info.valid_mean,
                   100.0 * info.valid_min, 100.0 * info.valid_max);
  }
  if (info.with_raw > 0) {
    text += Format("valid raw pixels (11-bit, below 2047): mean %.1f %% (min %.1f %%, max %.1f %%)%s\n",
                   100.0 * info.raw_valid_mean, 100.0 * info.raw_valid_min, 100.0 * info.raw_valid_max,
                   info.raw_valid_max == 0.0 ? "; warning: no raw measurement in any frame" : "");
  }
  if (info.with_pose > 0) {
    const Eigen::Vector3d& lo = info.cameras_min_W;
    const Eigen::Vector3d& hi = info.cameras_max_W;
    text += Format("camera positions (world, m): x %.4f .. %.4f, y %.4f .. %.4f, z %.4f .. %.4f; path %.4f m\n", lo.x(),
                   hi.x(), lo.y(), hi.y(), lo.z(), hi.z(), info.path_m);
  }
  if (const std::optional<WorldBox>& r = info.region_W) {
    text += Format("region (world, m; fuse's default box): x %.4f .. %.4f, y %.4f .. %.4f, z %.4f .. %.4f\n",
                   r->min_W.x(), r->max_W.x(), r->min_W.y(), r->max_W.y(), r->min_W.z(), r->max_W.z());
  }
  return text + Format("valid: all %zu frames read and checked\n", info.frames);
}

}  // namespace romunect::jobs
