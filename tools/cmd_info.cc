// romunect info DIR: summarize and validate a frame directory (every image is opened).
#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <string>

#include <Eigen/Core>

#include "commands.h"
#include "romunect/sensor/frame_io.h"

namespace romunect::tools {
namespace {

double ValidFraction(const cv::Mat& depth_m) {
  return depth_m.empty() ? 0.0 : static_cast<double>(cv::countNonZero(depth_m)) / depth_m.total();
}

void RunInfo(const std::filesystem::path& dir) {
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir);
  const CameraModel& c = manifest.camera;
  std::printf("frame directory: %s\n", dir.string().c_str());
  std::printf("camera: %d x %d px, fx %.3f fy %.3f cx %.3f cy %.3f, distortion [%g %g %g %g %g]\n",
              c.width, c.height, c.fx, c.fy, c.cx, c.cy, c.distortion[0], c.distortion[1],
              c.distortion[2], c.distortion[3], c.distortion[4]);
  const size_t n = manifest.frames.size();
  std::printf("frames: %zu", n);
  if (n > 0) {
    const double t0 = manifest.frames.front().time_s, t1 = manifest.frames.back().time_s;
    std::printf(", time %.3f .. %.3f s", t0, t1);
    if (n > 1 && t1 > t0) std::printf(" (%.1f Hz)", (n - 1) / (t1 - t0));
  }
  std::printf("\n");

  size_t with[5] = {0, 0, 0, 0, 0};  // depth, ir, raw, gt_depth, T_W_C
  double valid_sum = 0.0, valid_min = 1.0, valid_max = 0.0;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  double path_m = 0.0;
  std::optional<Eigen::Vector3d> previous;
  for (size_t i = 0; i < n; ++i) {
    const FrameRecord& r = manifest.frames[i];
    const Frame frame = LoadFrame(dir, manifest, i);  // throws on any bad image
    with[0] += !r.depth.empty();
    with[1] += !r.ir.empty();
    with[2] += !r.raw.empty();
    with[3] += !r.gt_depth.empty();
    if (!frame.depth_m.empty()) {
      const double valid = ValidFraction(frame.depth_m);
      valid_sum += valid;
      valid_min = std::min(valid_min, valid);
      valid_max = std::max(valid_max, valid);
    }
    if (r.T_W_C) {
      ++with[4];
      const Eigen::Vector3d p = r.T_W_C->translation();
      lo = lo.cwiseMin(p);
      hi = hi.cwiseMax(p);
      if (previous) path_m += (p - *previous).norm();
      previous = p;
    }
  }
  std::printf("images: depth %zu, ir %zu, raw %zu, gt_depth %zu; poses T_W_C %zu\n", with[0],
              with[1], with[2], with[3], with[4]);
  if (with[0] > 0) {
    std::printf("valid depth pixels: mean %.1f %% (min %.1f %%, max %.1f %%)\n",
                100.0 * valid_sum / with[0], 100.0 * valid_min, 100.0 * valid_max);
  }
  if (with[4] > 0) {
    std::printf("camera positions (world, m): x %.4f .. %.4f, y %.4f .. %.4f, z %.4f .. %.4f; path %.4f m\n",
                lo.x(), hi.x(), lo.y(), hi.y(), lo.z(), hi.z(), path_m);
  }
  if (const std::optional<WorldBox>& r = manifest.region_W) {
    std::printf("region (world, m; fuse's default box): x %.4f .. %.4f, y %.4f .. %.4f, z %.4f .. %.4f\n",
                r->min_W.x(), r->max_W.x(), r->min_W.y(), r->max_W.y(), r->min_W.z(), r->max_W.z());
  }
  std::printf("valid: all %zu frames read and checked\n", n);
}

}  // namespace

void AddInfoCommand(CLI::App& app) {
  auto* cmd = app.add_subcommand("info", "Summarize and validate a frame directory");
  auto dir = std::make_shared<std::string>();
  cmd->add_option("DIR", *dir, "Frame directory (holds frames.json)")->required();
  cmd->callback([dir] { RunInfo(*dir); });
}

}  // namespace romunect::tools
