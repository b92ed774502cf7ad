// Robot pose logs: on real hardware the flange pose T_B_H comes from the robot controller as a
// timestamped log, and frames get their pose by interpolation at their capture time.
//
// Format (CSV, docs/hardware.md): one pose per line, '#' starts a comment, an optional header
// line starting with "time_s"; columns
//     time_s, x_m, y_m, z_m, qw, qx, qy, qz
// = time (s, the frames' clock: seconds since the first frame, shifted by time_offset_s),
// the position of H's origin in B (m) and the rotation R_B_H as a unit quaternion, w first.
// Times strictly increase; quaternions are normalized (rejected if |q| is off by more than 1e-3).
#pragma once

#include <filesystem>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "romunect/sensor/frame_source.h"
#include "romunect/sensor/pose.h"

namespace romunect::openni2 {

struct TimedPose {
  double time_s = 0.0;
  Pose T_B_H = Pose::Identity();
};

class PoseLog {
 public:
  // Reads and validates a CSV pose log; throws InputError naming the file, line and column.
  static PoseLog Load(const std::filesystem::path& path);
  // From poses in memory (times strictly increasing; checked).
  explicit PoseLog(std::vector<TimedPose> poses);

  // T_B_H at time t_s: slerp/lerp between the two neighbouring entries (InterpolatePose);
  // nullopt when t_s lies outside [first time, last time].
  std::optional<Pose> At(double t_s) const;

  const std::vector<TimedPose>& poses() const { return poses_; }
  double begin_s() const { return poses_.front().time_s; }
  double end_s() const { return poses_.back().time_s; }

  // Writes the log in the format above (17 significant digits, so it reads back exactly).
  void Save(const std::filesystem::path& path) const;

 private:
  std::vector<TimedPose> poses_;
};

struct PoseLogSourceOptions {
  double time_offset_s = 0.0;     // log time = frame time + offset (aligns the two clocks)
  std::optional<Pose> T_H_C;      // hand-eye pose; with it, frames also get T_W_C
  Pose T_W_B = Pose::Identity();  // robot base in the world (used with T_H_C)
  std::string Problem() const;
};

struct PoseLogSourceStats {
  int frames = 0;       // frames that got a pose
  int outside_log = 0;  // frames whose time fell outside the log (kBadFrame)
};

// Wraps any FrameSource and sets each frame's T_B_H (and T_W_C = T_W_B T_B_H T_H_C when the
// hand-eye pose is given) from a pose log. A frame outside the log is kBadFrame, with its images
// still filled in and *error saying "frame N at t s lies outside the pose log [a, b] s".
class PoseLogSource : public FrameSource {
 public:
  PoseLogSource(std::unique_ptr<FrameSource> inner, PoseLog log, const PoseLogSourceOptions& options = {});

  const CameraModel& camera() const override { return inner_->camera(); }
  std::string Describe() const override;
  FrameStatus Next(Frame* frame, std::string* error) override;

  const PoseLogSourceStats& stats() const { return stats_; }
  FrameSource& inner() { return *inner_; }

 private:
  std::unique_ptr<FrameSource> inner_;
  PoseLog log_;
  PoseLogSourceOptions options_;
  PoseLogSourceStats stats_;
};

}  // namespace romunect::openni2
