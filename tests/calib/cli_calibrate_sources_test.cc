// `romunect calibrate hand-eye` and `depth` on recorded captures of the hardware path: the frame
// directories of cli_calibrate_test.cc recorded through the virtual OpenNI2 device to .oni files
// (IR, raw shifts) with a CSV pose log of T_B_H, giving the calibration of the directories.
#include <filesystem>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <opencv2/core.hpp>

#include "romunect/calib/calibration_file.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/pose_log.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"
#include "synthetic.h"

namespace romunect::calib {
namespace {

namespace fs = std::filesystem;
using romunect::testing::RunRomunect;
using romunect::testing::ScratchDir;

// The .oni holds the same 16-bit IR and raw shifts bit for bit and the pose log 17 digits, so
// the two runs solve the same problem; what is left is the pose log's interpolation at the
// frame times (microseconds on the wire) and float printing: far below any calibration error.
constexpr double kSameAngleRad = 1e-9;
constexpr double kSameTranslationM = 1e-9;
constexpr double kSameDepthMapAbs = 1e-9;

// The frames' T_B_H as a pose log, then the directory recorded through the virtual device with
// the raw shifts (`record --raw`, as a real calibration capture for the depth step).
fs::path RecordOni(const fs::path& dir, const fs::path& oni, const fs::path& poses, const std::string& flags) {
  std::vector<openni2::TimedPose> log;
  FrameDirectorySource source(dir);
  Frame frame;
  std::string error;
  while (source.Next(&frame, &error) == FrameStatus::kOk) log.push_back({frame.time_s, *frame.T_B_H});
  openni2::PoseLog(log).Save(poses);
  openni2::VirtualDeviceOptions device;
  device.pace = openni2::VirtualDeviceOptions::Pace::kStep;
  const auto rec = RunRomunect("record '" + openni2::VirtualDeviceUri(dir, device) + "' " + (oni.string() + ".dir") +
                               " --oni " + oni.string() + " --raw" + flags);
  EXPECT_EQ(rec.exit_code, 0) << rec.output;
  return oni;
}

TEST(CalibrateSourcesCliTest, OniWithPoseLogCalibratesAsItsFrameDirectory) {
  ScratchDir dir("cli_sources");
  CameraModel camera = testing::TruthCamera();
  camera.distortion = {};
  const BoardSpec board{9, 6, 0.025};
  const testing::HandEyeRig rig = testing::MakeHandEyeRig(camera, board, 12, 0.0, 0.5, 0.8, 3);
  testing::WriteBoardFrames(dir / "board", camera, board, rig);
  testing::WritePlaneFrames(dir / "plane", camera, rig, 8, 5);
  const fs::path board_oni = RecordOni(dir / "board", dir / "board.oni", dir / "board_poses.csv", "");
  const fs::path plane_oni = RecordOni(dir / "plane", dir / "plane.oni", dir / "plane_poses.csv", " --no-ir");

  // the same steps on each: the directory (T_B_H in frames.json) and the .oni with --poses
  Calibration start;
  start.camera = camera;
  start.residuals.intrinsics_rms_px = 0.05;
  const std::string common = " --board 9x6 --square 0.025";
  // The pose logs again on a clock 100 s ahead of the frames', as a robot's log would be:
  // --pose-offset 100 maps the frame times onto it.
  constexpr double kClockOffsetS = 100.0;
  for (const char* name : {"board_poses", "plane_poses"}) {
    std::vector<openni2::TimedPose> shifted = openni2::PoseLog::Load(dir / (std::string(name) + ".csv")).poses();
    for (openni2::TimedPose& p : shifted) p.time_s += kClockOffsetS;
    openni2::PoseLog(shifted).Save(dir / (std::string(name) + "_ahead.csv"));
  }
  const std::string offset = " --pose-offset " + std::to_string(kClockOffsetS);
  std::vector<Calibration> results;
  for (const auto& [board_source, plane_source] :
       {std::pair{(dir / "board").string(), (dir / "plane").string()},
        std::pair{board_oni.string() + " --poses " + (dir / "board_poses.csv").string(),
                  plane_oni.string() + " --poses " + (dir / "plane_poses.csv").string()},
        std::pair{board_oni.string() + " --poses " + (dir / "board_poses_ahead.csv").string() + offset,
                  plane_oni.string() + " --poses " + (dir / "plane_poses_ahead.csv").string() + offset}}) {
    const fs::path file = dir / ("calibration" + std::to_string(results.size()) + ".yaml");
    SaveCalibration(file, start);
    const auto hand_eye = RunRomunect("calibrate hand-eye --frames " + board_source + common + " --output " +
                                      file.string());
    ASSERT_EQ(hand_eye.exit_code, 0) << hand_eye.output;
    const auto depth = RunRomunect("calibrate depth --frames " + plane_source + " --output " + file.string());
    ASSERT_EQ(depth.exit_code, 0) << depth.output;
    results.push_back(LoadCalibration(file));
  }
  const Calibration& from_dir = results[0];
  for (size_t i = 1; i < results.size(); ++i) {
    SCOPED_TRACE(i == 1 ? "the .oni with its pose log" : "the .oni with a pose log 100 s ahead and --pose-offset");
    const Calibration& from_oni = results[i];
    EXPECT_TRUE(romunect::testing::PosesNear(from_oni.T_H_C, from_dir.T_H_C, kSameAngleRad, kSameTranslationM));
    EXPECT_TRUE(romunect::testing::PosesNear(from_oni.T_B_K, from_dir.T_B_K, kSameAngleRad, kSameTranslationM));
    ASSERT_TRUE(from_dir.depth.has_value() && from_oni.depth.has_value());
    EXPECT_EQ(from_oni.depth->model, from_dir.depth->model);
    EXPECT_LE(cv::norm(from_oni.depth->a, from_dir.depth->a, cv::NORM_INF), kSameDepthMapAbs);
    EXPECT_LE(cv::norm(from_oni.depth->b, from_dir.depth->b, cv::NORM_INF), kSameDepthMapAbs);
    // and the calibration itself is right (the frame-directory test's tolerance)
    EXPECT_TRUE(romunect::testing::PosesNear(from_oni.T_H_C, rig.T_H_C, 0.05 * M_PI / 180.0, 0.3e-3));
  }

  // Without the offset the ahead log holds no frame time; an offset without a log is refused.
  const fs::path file = dir / "calibration_refused.yaml";
  SaveCalibration(file, results[0]);
  const auto unshifted = RunRomunect("calibrate hand-eye --frames " + board_oni.string() + " --poses " +
                                     (dir / "board_poses_ahead.csv").string() + common + " --output " + file.string());
  EXPECT_NE(unshifted.exit_code, 0) << unshifted.output;
  for (const char* step : {"hand-eye", "depth"}) {
    const auto no_log = RunRomunect(std::string("calibrate ") + step + " --frames " + board_oni.string() + offset +
                                    (std::string(step) == "hand-eye" ? common : "") + " --output " + file.string());
    EXPECT_EQ(no_log.exit_code, 2) << step;
    EXPECT_NE(no_log.output.find("--pose-offset: applies with --poses"), std::string::npos) << no_log.output;
  }

  // A calibration of another camera mode is refused before any work, naming both sizes and the
  // file, which keeps its contents.
  Calibration other_mode = start;
  other_mode.camera.width *= 2;
  other_mode.camera.height *= 2;
  const fs::path other_file = dir / "calibration_other_mode.yaml";
  SaveCalibration(other_file, other_mode);
  for (const std::string& source :
       {(dir / "board").string(), board_oni.string() + " --poses " + (dir / "board_poses.csv").string()}) {
    const auto mismatch = RunRomunect("calibrate hand-eye --frames " + source + common + " --output " +
                                      other_file.string());
    EXPECT_EQ(mismatch.exit_code, 2) << mismatch.output;
    const std::string expected = "image size " + std::to_string(camera.width) + " x " + std::to_string(camera.height) +
                                 " differs from " + std::to_string(other_mode.camera.width) + " x " +
                                 std::to_string(other_mode.camera.height) + " in " + other_file.string();
    EXPECT_NE(mismatch.output.find(expected), std::string::npos) << mismatch.output;
  }
  EXPECT_EQ(LoadCalibration(other_file).camera.width, other_mode.camera.width);
}

}  // namespace
}  // namespace romunect::calib
