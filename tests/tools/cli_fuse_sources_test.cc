// `romunect fuse` on the hardware path's sources, run as a user would: an .oni recording of the
// virtual device with its pose log, and the live virtual device, each fused to the same map as
// the frame directory they came from; a device that stops mid-scan (outputs kept, exit 2); and
// the options only those sources take.
#include <algorithm>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/calib/calibration_file.h"
#include "romunect/sensor/depth_engine.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/pose_log.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/analytic_bin.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using ::testing::HasSubstr;
using testing::ImagesBitEqual;
using testing::ReadText;
using testing::RunRomunect;
using testing::ScratchDir;

constexpr int kFrames = 6;
// Coarse voxels and small images: the test is about the source path, not resolution.
const std::string kFuseArgs = " --voxel 0.001";

std::string Quote(const std::string& s) { return "'" + s + "'"; }

// The time OpenNI2Source gives frame i: the device sends whole microseconds since the first.
double WireTime(double t_s, double t0_s) { return static_cast<double>(std::llround((t_s - t0_s) * 1e6)) * 1e-6; }

// A capture of the analytic bin as the hardware path sees it: depth at the wire's 100 um,
// times in whole microseconds, and T_W_C exactly what the pose log (T_B_H, world = base) and
// an identity hand-eye give at those times. Writes DIR (the first `frames` frames), the pose
// log (covering the first `logged` frames) and a calibration file (camera, T_H_C = identity).
// With `raw_model`, frames also hold the chip's raw shifts, the calibration a depth model of
// them (1/Z = a raw + b) that puts depth 5 % farther than the device's metric depth, and
// model_dir holds the same frames with the model's depth.
struct Capture {
  std::filesystem::path dir, poses, calibration, model_dir;
};

// A chip whose raw shifts span the bin's 0.2-0.4 m: raw = offset - K / Z (1/8 px units).
constexpr double kRawOffset = 2000.0, kRawScalePxM = 348.0;
// The model's depth over the device's: 10-20 mm at the bin, many 1 mm voxels, so fusing the
// wrong one cannot go unnoticed.
constexpr double kModelScale = 1.05;

Capture WriteCapture(const std::filesystem::path& root, int frames, int logged, bool raw_model = false) {
  testing::AnalyticBinOptions options;
  options.width = 96;
  options.height = 72;
  options.frames = kFrames;
  options.seed = 5;
  const testing::AnalyticBin bin(options);
  std::filesystem::create_directories(root);
  Capture c{root / "capture", root / "poses.csv", root / "calibration.yml", root / "model"};

  std::vector<Frame> rendered;
  std::vector<TimedPose> log;
  for (int i = 0; i < kFrames; ++i) {
    rendered.push_back(bin.RenderFrame(i));
    if (i < logged) log.push_back({WireTime(rendered[i].time_s, rendered[0].time_s), *rendered[i].T_W_C});
  }
  PoseLog(log).Save(c.poses);
  const PoseLog loaded = PoseLog::Load(c.poses);  // the poses as fuse reads them

  calib::Calibration calibration;
  calibration.camera = bin.camera();
  if (raw_model) {
    const cv::Size size(bin.camera().width, bin.camera().height);
    calibration.depth = DepthCorrection{DepthCorrectionModel::kInverseAffineInRaw,
                                        cv::Mat(size, CV_64F, cv::Scalar(-1.0 / (kModelScale * kRawScalePxM))),
                                        cv::Mat(size, CV_64F, cv::Scalar(kRawOffset / (kModelScale * kRawScalePxM)))};
  }
  calib::SaveCalibration(c.calibration, calibration);
  const calib::Calibration model = calib::LoadCalibration(c.calibration);  // as fuse reads it

  FrameDirectoryWriter writer(c.dir, bin.camera());
  std::optional<FrameDirectoryWriter> model_writer;
  if (raw_model) model_writer.emplace(c.model_dir, bin.camera());
  for (int i = 0; i < frames; ++i) {
    Frame f = rendered[i];
    f.time_s = WireTime(f.time_s, rendered[0].time_s);
    if (i < logged) f.T_W_C = *loaded.At(f.time_s);
    if (raw_model) {
      f.raw.create(f.depth_m.size(), CV_16U);
      f.raw.forEach<uint16_t>([&](uint16_t& r, const int* p) {
        const double z = f.depth_m.at<float>(p[0], p[1]);
        r = z > 0.0 ? static_cast<uint16_t>(std::clamp(std::lround(kRawOffset - kRawScalePxM / z), 0L, 2046L))
                    : kRawInvalid;
      });
      Frame m = f;
      m.depth_m = ApplyDepthCorrection(*model.depth, f.raw, model.chip);
      model_writer->Add(m);
    }
    f.depth_m.forEach<float>(
        [](float& d, const int*) { d = DequantizeDepth(QuantizeDepth(d, DepthUnit::k100um), DepthUnit::k100um); });
    writer.Add(f);
  }
  writer.Finish();
  if (model_writer) model_writer->Finish();
  return c;
}

std::string DeviceUri(const std::filesystem::path& dir, int stop_after = -1) {
  VirtualDeviceOptions o;
  o.pace = VirtualDeviceOptions::Pace::kStep;
  o.stop_after = stop_after;
  return VirtualDeviceUri(dir, o);
}

std::string PoseArgs(const Capture& c) {
  return " --poses " + c.poses.string() + " --calibration " + c.calibration.string();
}

nlohmann::json Report(const std::filesystem::path& out) { return nlohmann::json::parse(ReadText(out / "report.json")); }

TEST(FuseSourcesCli, OniWithPoseLogAndLiveDeviceFuseToTheDirectorysMap) {
  ScratchDir scratch("fuse_sources_same");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames);
  const auto rec = RunRomunect("record " + Quote(DeviceUri(c.dir)) + " " + (scratch / "rec").string() +
                               " --no-ir --oni " + (scratch / "scan.oni").string());
  ASSERT_EQ(rec.exit_code, 0) << rec.output;

  const auto from_dir = RunRomunect("fuse " + c.dir.string() + kFuseArgs + " --out " + (scratch / "dir").string());
  ASSERT_EQ(from_dir.exit_code, 0) << from_dir.output;
  const auto from_oni = RunRomunect("fuse " + (scratch / "scan.oni").string() + kFuseArgs + PoseArgs(c));
  ASSERT_EQ(from_oni.exit_code, 0) << from_oni.output;
  const auto live = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) + " --out " +
                                (scratch / "live").string());
  ASSERT_EQ(live.exit_code, 0) << live.output;

  const cv::Mat expected = ReadDepthExr(scratch / "dir" / "fused_depth.exr");
  // The fixture must fill a good part of the map, or equality would prove little.
  constexpr double kMinCompleteness = 0.3;  // measured 0.5 with 6 frames of 96 x 72 at 1 mm
  EXPECT_GT(Report(scratch / "dir")["completeness"].get<double>(), kMinCompleteness);
  // Default output beside the .oni file, as beside a directory.
  for (const std::filesystem::path& out : {scratch / "scan_fused", scratch / "live"}) {
    EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(out / "fused_depth.exr"), expected)) << out;
    const nlohmann::json report = Report(out);
    EXPECT_EQ(report["frames"], kFrames) << out;
    EXPECT_EQ(report["bad_frames"], 0) << out;
    EXPECT_EQ(report["stopped_early"], false) << out;
  }
  EXPECT_EQ(Report(scratch / "live")["input"], DeviceUri(c.dir));
}

// An integrator's calibration file of camera and T_H_C alone (no depth model, no residuals):
// record took it and fuse refused it ("date: missing"); both take it now, and fuse gives the map
// of the whole calibration file with the same camera and T_H_C.
TEST(FuseSourcesCli, RecordAndFuseTakeTheSameCameraAndHandEyeFile) {
  ScratchDir scratch("fuse_sources_minimal_calibration");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames);
  const std::filesystem::path minimal = scratch / "camera_and_hand_eye.yml";
  {
    cv::FileStorage fs(minimal.string(), cv::FileStorage::WRITE);
    fs << "format" << calib::kCalibrationFormat << "version" << calib::kCalibrationVersion;
    calib::LoadCalibration(c.calibration).camera.Write(fs);
    fs << "T_H_C" << cv::Mat::eye(4, 4, CV_64F);
  }
  const std::string minimal_args = " --poses " + c.poses.string() + " --calibration " + minimal.string();
  const auto fused = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + minimal_args + " --out " +
                                 (scratch / "minimal").string());
  ASSERT_EQ(fused.exit_code, 0) << fused.output;
  EXPECT_THAT(fused.output, HasSubstr("T_H_C is the identity and has no hand-eye residual"));
  const auto whole = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) + " --out " +
                                 (scratch / "whole").string());
  ASSERT_EQ(whole.exit_code, 0) << whole.output;
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(scratch / "minimal" / "fused_depth.exr"),
                             ReadDepthExr(scratch / "whole" / "fused_depth.exr")));
  const auto recorded = RunRomunect("record " + Quote(DeviceUri(c.dir)) + " " + (scratch / "rec").string() +
                                    " --no-ir --pose-log " + c.poses.string() + " --calibration " + minimal.string());
  ASSERT_EQ(recorded.exit_code, 0) << recorded.output;
}

// With a depth model in the calibration, fuse reads the chip's raw shifts and applies the model,
// as the simulated pipeline does; --device-depth fuses the device's own metric depth instead.
TEST(FuseSourcesCli, TheCalibrationsDepthModelIsAppliedToTheDevicesRawShifts) {
  ScratchDir scratch("fuse_sources_model");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames, /*raw_model=*/true);
  for (const auto& [dir, out] : {std::pair{c.model_dir, "model_dir"}, std::pair{c.dir, "device_dir"}}) {
    const auto r = RunRomunect("fuse " + dir.string() + kFuseArgs + " --out " + (scratch / out).string());
    ASSERT_EQ(r.exit_code, 0) << r.output;
  }
  const cv::Mat model_map = ReadDepthExr(scratch / "model_dir" / "fused_depth.exr");
  const cv::Mat device_map = ReadDepthExr(scratch / "device_dir" / "fused_depth.exr");
  ASSERT_FALSE(ImagesBitEqual(model_map, device_map)) << "the fixture must tell the two depths apart";

  const auto live = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) + " --out " +
                                (scratch / "live").string());
  ASSERT_EQ(live.exit_code, 0) << live.output;
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(scratch / "live" / "fused_depth.exr"), model_map));
  EXPECT_THAT(Report(scratch / "live")["depth_from"].get<std::string>(),
              HasSubstr("the calibration's depth model (inverse_affine_in_raw) on the device's raw shifts"));
  // Not an empty map: measured 0.11 (depth 5 % off the truth makes the frames disagree).
  constexpr double kMinModelCompleteness = 0.05;
  EXPECT_GT(Report(scratch / "live")["completeness"].get<double>(), kMinModelCompleteness);

  const auto device = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) +
                                  " --device-depth --out " + (scratch / "device").string());
  ASSERT_EQ(device.exit_code, 0) << device.output;
  EXPECT_EQ(Report(scratch / "device")["depth_from"], "the device's metric depth");
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(scratch / "device" / "fused_depth.exr"), device_map));
}

// A raw-only frame directory (a recording of the chip's raw shifts) fuses with --calibration's
// depth model: the map of the directory holding the model's depth, bit for bit.
TEST(FuseSourcesCli, ARawOnlyFrameDirectoryFusesWithTheCalibrationsDepthModel) {
  ScratchDir scratch("fuse_sources_raw_only");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames, /*raw_model=*/true);
  const std::filesystem::path raw_only = scratch / "raw_only";
  {
    const FrameDirectorySource source(c.dir);
    FrameDirectoryWriter writer(raw_only, source.manifest().camera);
    for (size_t i = 0; i < source.manifest().frames.size(); ++i) {
      Frame f = LoadFrame(c.dir, source.manifest(), i);
      f.depth_m.release();
      writer.Add(f);
    }
    writer.Finish();
  }
  const auto model = RunRomunect("fuse " + c.model_dir.string() + kFuseArgs + " --out " + (scratch / "model_fused").string());
  ASSERT_EQ(model.exit_code, 0) << model.output;
  const auto fused = RunRomunect("fuse " + raw_only.string() + kFuseArgs + " --calibration " + c.calibration.string() +
                                 " --out " + (scratch / "fused").string());
  ASSERT_EQ(fused.exit_code, 0) << fused.output;
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(scratch / "fused" / "fused_depth.exr"),
                             ReadDepthExr(scratch / "model_fused" / "fused_depth.exr")));
  EXPECT_THAT(Report(scratch / "fused")["depth_from"].get<std::string>(),
              HasSubstr("the calibration's depth model (inverse_affine_in_raw) on the frame directory's raw images"));
  // Without the calibration there is no depth to fuse; with one that has no depth model, neither.
  const auto bare = RunRomunect("fuse " + raw_only.string() + kFuseArgs + " --out " + (scratch / "bare").string());
  EXPECT_NE(bare.exit_code, 0);
  EXPECT_THAT(bare.output, HasSubstr("missing: fuse needs depth"));
  calib::Calibration no_model = calib::LoadCalibration(c.calibration);
  no_model.depth.reset();
  calib::SaveCalibration(scratch / "no_model.yml", no_model);
  const auto refused = RunRomunect("fuse " + raw_only.string() + kFuseArgs + " --calibration " +
                                   (scratch / "no_model.yml").string() + " --out " + (scratch / "refused").string());
  EXPECT_EQ(refused.exit_code, 2) << refused.output;
  EXPECT_THAT(refused.output, HasSubstr("no_model.yml: depth_model: missing"));
  // A frame directory's poses are its own: --poses stays refused.
  const auto poses = RunRomunect("fuse " + raw_only.string() + kFuseArgs + PoseArgs(c) + " --out " +
                                 (scratch / "poses").string());
  EXPECT_NE(poses.exit_code, 0);
  EXPECT_THAT(poses.output, HasSubstr("--poses"));
}

// Recording first, then fusing the directory, applies the calibration's depth model too: record
// reads the raw shifts and writes the model's metric depth beside them, so the directory fuses
// to the map of fusing the device directly (it fused the chip's uncorrected depth before).
TEST(FuseSourcesCli, RecordingWithADepthModelWritesItsMetricDepth) {
  ScratchDir scratch("fuse_sources_record_model");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames, /*raw_model=*/true);
  const auto rec = RunRomunect("record " + Quote(DeviceUri(c.dir)) + " " + (scratch / "rec").string() + " --pose-log " +
                               c.poses.string() + " --calibration " + c.calibration.string() + " --no-ir");
  ASSERT_EQ(rec.exit_code, 0) << rec.output;
  // A recording's frames against a directory's: the same depth, bit for bit, raw shifts kept or not.
  auto expect_frames = [](const std::filesystem::path& recorded_dir, const std::filesystem::path& source_dir,
                          bool raw) {
    const FrameDirectorySource recorded(recorded_dir), source(source_dir);
    ASSERT_EQ(recorded.manifest().frames.size(), static_cast<size_t>(kFrames));
    for (int i = 0; i < kFrames; ++i) {
      const Frame a = LoadFrame(recorded_dir, recorded.manifest(), i), b = LoadFrame(source_dir, source.manifest(), i);
      EXPECT_EQ(a.raw.empty(), !raw) << i;
      EXPECT_TRUE(ImagesBitEqual(a.depth_m, b.depth_m)) << "frame " << i;
    }
  };
  expect_frames(scratch / "rec", c.model_dir, /*raw=*/true);
  const auto doc = nlohmann::json::parse(ReadText(scratch / "rec" / "frames.json"));
  EXPECT_THAT(doc["recording"]["depth_from"].get<std::string>(), HasSubstr("the calibration's depth model"));

  // --device-depth records the device's own depth, as fuse --device-depth fuses it.
  const auto dev = RunRomunect("record " + Quote(DeviceUri(c.dir)) + " " + (scratch / "dev").string() + " --pose-log " +
                               c.poses.string() + " --calibration " + c.calibration.string() +
                               " --no-ir --device-depth");
  ASSERT_EQ(dev.exit_code, 0) << dev.output;
  expect_frames(scratch / "dev", c.dir, /*raw=*/false);
  EXPECT_EQ(nlohmann::json::parse(ReadText(scratch / "dev" / "frames.json"))["recording"]["depth_from"],
            "the device's depth (--device-depth: the calibration's depth model not applied)");
  const auto copy = RunRomunect("record " + c.dir.string() + " " + (scratch / "copy").string() + " --device-depth");
  EXPECT_NE(copy.exit_code, 0);
  EXPECT_THAT(copy.output, HasSubstr("--device-depth: only an OpenNI2 source"));
}

TEST(FuseSourcesCli, ADeviceThatStopsKeepsTheFramesFusedSoFarAndExitsNonZero) {
  ScratchDir scratch("fuse_sources_stop");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames);
  constexpr int kSent = 3;
  const auto r = RunRomunect("fuse " + Quote(DeviceUri(c.dir, kSent)) + kFuseArgs + PoseArgs(c) +
                             " --timeout 0.3 --out " + (scratch / "out").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_THAT(r.output, HasSubstr("stopped early after 3 fused frames"));
  EXPECT_THAT(r.output, HasSubstr("no frame for 0.3 s (device unplugged or stalled)"));
  const nlohmann::json report = Report(scratch / "out");
  EXPECT_EQ(report["frames"], kSent);
  EXPECT_EQ(report["stopped_early"], true);
  EXPECT_THAT(report["stop_reason"].get<std::string>(), HasSubstr("3 frames were delivered before"));

  // What was kept is exactly the fusion of the frames the device sent.
  const Capture first = WriteCapture(scratch / "first", kSent, kFrames);
  const auto expected = RunRomunect("fuse " + first.dir.string() + kFuseArgs + " --out " + (scratch / "ref").string());
  ASSERT_EQ(expected.exit_code, 0) << expected.output;
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(scratch / "out" / "fused_depth.exr"),
                             ReadDepthExr(scratch / "ref" / "fused_depth.exr")));
  for (const char* file : {"fused_depth.png", "fused_points.ply", "completeness.png"}) {
    EXPECT_TRUE(std::filesystem::exists(scratch / "out" / file)) << file;
  }
}

TEST(FuseSourcesCli, FramesOutsideThePoseLogAreSkippedAndCounted) {
  ScratchDir scratch("fuse_sources_outside");
  constexpr int kLogged = 4;
  const Capture c = WriteCapture(scratch.path(), kFrames, kLogged);
  const auto r = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) + " --out " +
                             (scratch / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_THAT(r.output, HasSubstr("lies outside the pose log"));
  // The fixture's hand-eye pose is the identity with no hand-eye residual, as `calibrate
  // intrinsics` leaves a file: fuse says it looks uncalibrated (and uses it).
  EXPECT_THAT(r.output, HasSubstr("T_H_C is the identity and has no hand-eye residual"));
  const nlohmann::json report = Report(scratch / "out");
  EXPECT_EQ(report["frames"], kLogged);
  EXPECT_EQ(report["bad_frames"], kFrames - kLogged);
}

// A device faster than fuse loses frames (OpenNI2 keeps the newest): the report and the summary
// account for every frame sent, fused, skipped or dropped.
TEST(FuseSourcesCli, FramesTheDeviceDroppedAreCounted) {
  ScratchDir scratch("fuse_sources_dropped");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames);
  VirtualDeviceOptions fast;
  fast.fps = 1000.0;  // a frame every millisecond, at its own pace
  const auto r = RunRomunect("fuse " + Quote(VirtualDeviceUri(c.dir, fast)) + kFuseArgs + PoseArgs(c) + " --out " +
                             (scratch / "out").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const nlohmann::json report = Report(scratch / "out");
  ASSERT_TRUE(report.contains("dropped_frames"));
  EXPECT_EQ(report["frames"].get<int>() + report["bad_frames"].get<int>() + report["dropped_frames"].get<int>(),
            kFrames);
  EXPECT_THAT(r.output, HasSubstr(std::to_string(report["dropped_frames"].get<int>()) + " dropped by the device"));
}

// Every frame outside the pose log: nothing to fuse is an error, and nothing is written (a rerun
// with the right offset into the same --out is not refused).
TEST(FuseSourcesCli, NoFrameToFuseIsAnErrorThatWritesNothing) {
  ScratchDir scratch("fuse_sources_none");
  const Capture c = WriteCapture(scratch.path(), kFrames, kFrames);
  const auto r = RunRomunect("fuse " + Quote(DeviceUri(c.dir)) + kFuseArgs + PoseArgs(c) + " --pose-offset 100 --out " +
                             (scratch / "out").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_THAT(r.output, HasSubstr("nothing to fuse: all 6 frames were skipped"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "out"));
}

TEST(FuseSourcesCli, RejectsMissingOrMisplacedSourceOptions) {
  ScratchDir scratch("fuse_sources_bad");
  const Capture c = WriteCapture(scratch.path(), 1, 1);
  const std::string device = Quote(DeviceUri(c.dir));
  struct Case {
    std::string args, expected;
  };
  for (const Case& k : std::vector<Case>{
           {device + " --out " + (scratch / "o").string(), "--poses: missing"},
           {device + " --out " + (scratch / "o").string() + " --poses " + c.poses.string(), "--calibration: missing"},
           {device + PoseArgs(c), "--out: missing: fusing a live device"},
           {c.dir.string() + PoseArgs(c), "--poses: applies to .oni files and devices"},
           // Ignored for a directory before: exit 0 as if they had taken effect.
           {c.dir.string() + " --pose-offset 1", "--pose-offset: applies to .oni files and devices"},
           {c.dir.string() + " --timeout 3", "--timeout: applies to .oni files and devices"},
           {c.dir.string() + " --device-depth", "--device-depth: applies to .oni files and devices"},
           {(scratch / "none.oni").string() + PoseArgs(c), "no such .oni file"},
           {Quote("romunect:" + (scratch / "nowhere").string()) + PoseArgs(c) + " --out " + (scratch / "o").string(),
            "no frames.json"},
       }) {
    const auto r = RunRomunect("fuse " + k.args + kFuseArgs);
    EXPECT_EQ(r.exit_code, 2) << k.args << "\n" << r.output;
    EXPECT_THAT(r.output, HasSubstr(k.expected)) << k.args;
    EXPECT_FALSE(std::filesystem::exists(scratch / "o" / "report.json")) << k.args;
  }
}

}  // namespace
}  // namespace romunect::openni2
