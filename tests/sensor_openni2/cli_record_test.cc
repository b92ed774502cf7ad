// `romunect record`, run as a user would: the virtual device to a frame directory and an .oni
// file, the .oni back to a frame directory, a device that stops, and bad input.
#include <sys/wait.h>

#include <cstdio>
#include <fstream>
#include <map>
#include <sstream>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::ImagesBitEqual;
using testing::RunRomunect;
using testing::RunShell;
using testing::ScratchDir;

std::string Quote(const std::string& s) { return "'" + s + "'"; }

// The quoted URI of `dir` as a step-paced virtual device that stops after stop_after frames.
std::string StepDevice(const std::filesystem::path& dir, int stop_after = -1) {
  VirtualDeviceOptions step;
  step.pace = VirtualDeviceOptions::Pace::kStep;
  step.stop_after = stop_after;
  return Quote(VirtualDeviceUri(dir, step));
}

// Every frame of `recorded` equals the source directory's, depth after 100 um quantization.
void ExpectSameFrames(const std::filesystem::path& recorded, const std::filesystem::path& truth, size_t count) {
  FrameDirectorySource a(recorded), b(truth);
  ASSERT_EQ(a.manifest().frames.size(), count);
  for (size_t i = 0; i < count; ++i) {
    const Frame fa = LoadFrame(recorded, a.manifest(), i), fb = LoadFrame(truth, b.manifest(), i);
    cv::Mat expected(fb.depth_m.size(), CV_32F);
    for (int v = 0; v < expected.rows; ++v) {
      for (int u = 0; u < expected.cols; ++u) {
        expected.at<float>(v, u) = DequantizeDepth(QuantizeDepth(fb.depth_m.at<float>(v, u), DepthUnit::k100um),
                                                   DepthUnit::k100um);
      }
    }
    EXPECT_EQ(fa.index, static_cast<int>(i));
    EXPECT_TRUE(ImagesBitEqual(fa.depth_m, expected)) << i;
    EXPECT_TRUE(ImagesBitEqual(fa.ir, fb.ir)) << i;
  }
}

TEST(CliRecord, Help) {
  const auto r = RunRomunect("record --help");
  EXPECT_EQ(r.exit_code, 0);
  for (const char* word :
       {"SOURCE", "OUT_DIR", "--oni", "--pose-log", "--frames", "--list-devices", "romunect:DIR", "--resume"}) {
    EXPECT_NE(r.output.find(word), std::string::npos) << word << "\n" << r.output;
  }
}

TEST(CliRecord, RecordsTheVirtualDeviceToAFrameDirectoryAndOniAndPlaysTheOniBack) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 4, 31);
  const std::string uri = StepDevice(dir.path());
  const auto r = RunRomunect("record " + uri + " " + (out / "live").string() + " --oni " + (out / "live.oni").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_NE(r.output.find("recorded 4 frames (0 skipped, 0 dropped by the device)"), std::string::npos) << r.output;
  ExpectSameFrames(out / "live", dir.path(), 4);
  const auto doc = nlohmann::json::parse(testing::ReadText(out / "live" / "frames.json"));
  EXPECT_EQ(doc["ps1080"]["zero_plane_distance_mm"], 120);
  EXPECT_EQ(doc["recording"]["depth_unit"], "100 um");

  const auto back = RunRomunect("record " + (out / "live.oni").string() + " " + (out / "replayed").string());
  ASSERT_EQ(back.exit_code, 0) << back.output;
  ExpectSameFrames(out / "replayed", dir.path(), 4);
  EXPECT_EQ(RunRomunect("info " + (out / "replayed").string()).exit_code, 0);

  const auto modes = RunRomunect("record " + uri + " --list-modes");
  EXPECT_EQ(modes.exit_code, 0);
  EXPECT_NE(modes.output.find("depth 80x60 @30 Hz 100um"), std::string::npos) << modes.output;
}

// Copying a frame directory keeps the region its frames are of (their world poses are kept) and
// its unknown keys, top level (the chip's "ps1080" among them) and per entry, as the format says.
TEST(CliRecord, AFrameDirectoryCopyKeepsItsRegionAndUnknownKeys) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 31);
  nlohmann::json manifest = nlohmann::json::parse(testing::ReadText(dir / "frames.json"));
  const nlohmann::json region = {0.375, -0.04, -0.004, 0.525, 0.04, 0.065};
  manifest["region_W"] = region;
  manifest["ps1080"] = {{"zero_plane_distance_mm", 120}};
  manifest["my_top_key"] = 7;
  manifest["frames"][1]["my_frame_key"] = "x";
  testing::WriteText(dir / "frames.json", manifest.dump());
  const auto r = RunRomunect("record " + dir.path().string() + " " + (out / "copy").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const auto copy = nlohmann::json::parse(testing::ReadText(out / "copy" / "frames.json"));
  EXPECT_EQ(copy["region_W"], region);
  EXPECT_EQ(copy["ps1080"], manifest["ps1080"]);
  EXPECT_EQ(copy["my_top_key"], 7);
  EXPECT_EQ(copy["frames"][1]["my_frame_key"], "x");
  EXPECT_FALSE(copy["frames"][0].contains("my_frame_key"));
  EXPECT_EQ(copy["recording"]["source"], dir.path().string());
}

TEST(CliRecord, RawShiftsGoToTheFrameDirectorysRawImages) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 33);
  const auto r = RunRomunect("record " + StepDevice(dir.path()) + " " + (out / "raw").string() + " --raw --no-ir");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  FrameDirectorySource recorded(out / "raw"), truth(dir.path());
  ASSERT_EQ(recorded.manifest().frames.size(), 3u);
  for (size_t i = 0; i < 3; ++i) {
    const Frame a = LoadFrame(out / "raw", recorded.manifest(), i), b = LoadFrame(dir.path(), truth.manifest(), i);
    EXPECT_TRUE(ImagesBitEqual(a.raw, b.raw)) << i;
    EXPECT_TRUE(a.depth_m.empty()) << i;
  }
  const auto doc = nlohmann::json::parse(testing::ReadText(out / "raw" / "frames.json"));
  EXPECT_EQ(doc["recording"]["depth_unit"], "raw shift9.2");
}

// Runs `romunect <arguments>` in `cwd` with ROMUNECT_VIRTUAL_DEVICE set to `device`.
testing::CommandResult RunWithDeviceVariable(const std::filesystem::path& cwd, const std::string& device,
                                             const std::string& arguments) {
  return RunShell("cd " + Quote(cwd.string()) + " && ROMUNECT_VIRTUAL_DEVICE=" + Quote(device) + " " +
                  testing::RomunectBinary().string() + " " + arguments);
}

// libOpenNI2 changes its working directory while the driver reads the variable: a relative
// directory used to give no device at all ("no devices found").
TEST(CliRecord, ARelativeDirectoryInTheDeviceVariableOrTheUriMeansTheWorkingDirectorys) {
  ScratchDir work("work");
  testing::WriteSampleFrameDirectory(work / "frames", testing::SmallCamera(), 3, 35);
  for (const std::string device : {"frames", "romunect:frames?pace=step"}) {
    SCOPED_TRACE(device);
    const auto r = RunWithDeviceVariable(work.path(), device, "record oni:// out_" + std::to_string(device.size()));
    ASSERT_EQ(r.exit_code, 0) << r.output;
    EXPECT_NE(r.output.find("romunect:" + (work / "frames").string()), std::string::npos) << r.output;
    ExpectSameFrames(work / ("out_" + std::to_string(device.size())), work / "frames", 3);
  }
  const auto r = RunWithDeviceVariable(work.path(), "", "record 'romunect:frames?pace=step' direct");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  ExpectSameFrames(work / "direct", work / "frames", 3);
}

// What the driver knows about a refused device reaches the user, instead of "no detail from
// OpenNI2".
TEST(CliRecord, TheDriversReasonForRefusingADeviceIsPassedOn) {
  ScratchDir work("work");
  testing::WriteSampleFrameDirectory(work / "frames", testing::SmallCamera(), 2, 36);
  auto r = RunWithDeviceVariable(work.path(), (work / "no_such_dir").string(), "record oni:// out");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("ROMUNECT_VIRTUAL_DEVICE=" + (work / "no_such_dir").string() +
                          ": romunect:" + (work / "no_such_dir").string() + ": no frames.json in"),
            std::string::npos)
      << r.output;
  // OpenNI2 keeps URIs of at most 255 characters.
  std::filesystem::path deep = work / "deep";
  while (deep.string().size() < 300) deep /= "nested_directory";
  std::filesystem::create_directories(deep);
  std::filesystem::copy(work / "frames", deep, std::filesystem::copy_options::recursive);
  r = RunRomunect("record " + StepDevice(deep) + " " + (work / "out").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("longer than OpenNI2's 255 characters"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("no detail"), std::string::npos) << r.output;
}

// A recorder killed mid-run leaves an .oni without its frame count; libOpenNI2 still plays it,
// and so must `record` (and `fuse`, through the same source): every frame until the end.
TEST(CliRecord, ARecordingWhoseRecorderWasKilledPlaysToItsEnd) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  constexpr int kDirectoryFrames = 4;
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kDirectoryFrames, 37);
  VirtualDeviceOptions looped;
  looped.loop = true;
  const std::string oni = (out / "killed.oni").string();
  // Killed once the file holds several 80 x 60 frame sets (depth and IR: 19.2 kB and headers).
  const auto killed = RunShell(testing::RomunectBinary().string() + " record " +
                               Quote(VirtualDeviceUri(dir.path(), looped)) + " " + (out / "live").string() + " --oni " +
                               Quote(oni) + " >/dev/null & pid=$!; " + "for i in $(seq 1 200); do [ $(stat -c %s " +
                               Quote(oni) +
                               " 2>/dev/null || echo 0) -gt 150000 ] && break; sleep 0.05; done; kill -9 $pid");
  ASSERT_GT(std::filesystem::file_size(oni), 150000u) << killed.output;
  ASSERT_FALSE(std::filesystem::exists(out / "live" / "frames.json"));
  const auto r = RunRomunect("record " + Quote(oni) + " " + (out / "back").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  FrameDirectorySource back(out / "back"), truth(dir.path());
  const size_t played = back.manifest().frames.size();
  // Every complete frame set in the file plays: at most ~0.5 kB of headers each, the last one cut.
  const size_t complete_sets = std::filesystem::file_size(oni) / (2 * 80 * 60 * 2 + 512) - 1;
  EXPECT_GE(played, complete_sets) << r.output;
  // The looped device repeats the directory: frame i is the directory's frame i mod 4.
  for (size_t i = 0; i < played; ++i) {
    const Frame a = LoadFrame(out / "back", back.manifest(), i);
    const Frame b = LoadFrame(dir.path(), truth.manifest(), i % kDirectoryFrames);
    EXPECT_EQ(a.index, static_cast<int>(i));
    EXPECT_TRUE(ImagesBitEqual(a.ir, b.ir)) << i;
  }
}

// A frame directory opens as one device at a time, as a USB sensor: a second process is refused
// while the first holds it, and gets it once the first has ended.
TEST(CliRecord, ASecondProcessCannotOpenADeviceInUse) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 38);
  VirtualDeviceOptions looped;
  looped.loop = true;
  const std::string first = out / "first";
  // The first records an endless device; the second tries once the first has written a frame.
  const std::string binary = testing::RomunectBinary().string();
  const auto r = RunShell(binary + " record " + Quote(VirtualDeviceUri(dir.path(), looped)) + " " + first +
                          " >/dev/null 2>&1 & pid=$!; for i in $(seq 1 200); do ls " + Quote(first + "/depth") +
                          " 2>/dev/null | grep -q . && break; sleep 0.05; done; " + binary + " record " +
                          StepDevice(dir.path()) + " " + (out / "second").string() + "; echo exit=$?; kill -9 $pid");
  EXPECT_NE(r.output.find("is open in another process: a device opens once, as a USB sensor"), std::string::npos)
      << r.output;
  EXPECT_NE(r.output.find("exit=2"), std::string::npos) << r.output;
  const auto after = RunRomunect("record " + StepDevice(dir.path()) + " " + (out / "third").string());
  EXPECT_EQ(after.exit_code, 0) << after.output;
}

TEST(CliRecord, ADeviceThatStopsKeepsTheFramesSoFarAndFails) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 5, 32);
  const auto r = RunRomunect("record " + StepDevice(dir.path(), 2) + " " + (out / "cut").string() + " --timeout 0.5");
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("no frame for 0.5 s (device unplugged or stalled)"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("kept 2 frames"), std::string::npos) << r.output;
  ExpectSameFrames(out / "cut", dir.path(), 2);
  const auto doc = nlohmann::json::parse(testing::ReadText(out / "cut" / "frames.json"));
  EXPECT_NE(doc["recording"]["incomplete"].get<std::string>().find("no frame for 0.5 s"), std::string::npos);
}

TEST(CliRecord, PoseLogAndCalibrationGiveFusableFrames) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 33);  // at 0, 1/30, 2/30 s
  testing::WriteText(out / "poses.csv", "time_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0.5,0,0.4,0,1,0,0\n0.1,0.5,0,0.3,0,1,0,0\n");
  const CameraModel camera = testing::SmallCamera();
  const Pose T_H_C = MakePose(Eigen::Matrix3d::Identity(), Eigen::Vector3d(0.01, 0.02, 0.1));
  {
    cv::FileStorage fs((out / "calib.yml").string(), cv::FileStorage::WRITE);
    fs << "format"
       << "romunect-calibration"
       << "version" << 1;
    camera.Write(fs);
    cv::Mat m(4, 4, CV_64F);
    for (int i = 0; i < 16; ++i) m.at<double>(i / 4, i % 4) = T_H_C.matrix()(i / 4, i % 4);
    fs << "T_H_C" << m;
  }
  const auto r = RunRomunect("record " + StepDevice(dir.path()) + " " + (out / "rec").string() + " --pose-log " +
                             (out / "poses.csv").string() + " --calibration " + (out / "calib.yml").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  FrameDirectorySource rec(out / "rec");
  EXPECT_EQ(rec.camera(), camera);  // the calibration's camera, distortion included, not the FOV pinhole
  ASSERT_EQ(rec.manifest().frames.size(), 3u);
  for (int i = 0; i < 3; ++i) {
    const FrameRecord& f = rec.manifest().frames[i];
    ASSERT_TRUE(f.T_B_H && f.T_W_C);
    // Straight-line log: z falls 0.1 m per 0.1 s; the frames' clock starts at the first frame.
    constexpr double kTextAndSlerpTolerance = 1e-12;  // JSON round trip and slerp of equal rotations
    EXPECT_NEAR(f.T_B_H->translation().z(), 0.4 - f.time_s, kTextAndSlerpTolerance);
    EXPECT_TRUE(testing::PosesNear(*f.T_W_C, *f.T_B_H * T_H_C, kTextAndSlerpTolerance, kTextAndSlerpTolerance));
  }
}

// An earlier recording or frame directory is never replaced, and a refusal comes before the
// device opens (opening starts the .oni recording, which truncated the file before).
TEST(CliRecord, NeverReplacesAnEarlierRecordingOrFrameDirectory) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 35);
  const std::string device = StepDevice(dir.path());
  ASSERT_EQ(
      RunRomunect("record " + device + " " + (out / "a").string() + " --oni " + (out / "a.oni").string()).exit_code, 0);
  const std::string recording = testing::ReadText(out / "a.oni");
  auto r = RunRomunect("record " + device + " " + (out / "b").string() + " --oni " + (out / "a.oni").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("a.oni: already exists; refusing to overwrite an earlier recording"), std::string::npos)
      << r.output;
  EXPECT_FALSE(std::filesystem::exists(out / "b"));
  r = RunRomunect("record " + device + " " + (out / "a").string() + " --oni " + (out / "new.oni").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("refusing to overwrite an earlier frame directory"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out / "new.oni"));
  EXPECT_TRUE(testing::ReadText(out / "a.oni") == recording);
}

// Where the capture goes is checked before the device opens: OpenNI2's recorder crashed (exit
// 139) on an .oni file it cannot create, an .oni named like OUT_DIR was left behind when the
// folder then failed, and an unfinished capture's files mixed with the new one's.
TEST(CliRecord, RefusesCaptureTargetsItCannotUseBeforeOpeningTheDevice) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 36);
  const std::string device = StepDevice(dir.path());
  auto r = RunRomunect("record " + device + " " + (out / "a").string() + " --oni " +
                       (out / "no_such" / "a.oni").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("a.oni: cannot be created: "), std::string::npos) << r.output;
  r = RunRomunect("record " + device + " " + (out / "same").string() + " --oni " + (out / "same").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("is OUT_DIR"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out / "same"));
  std::filesystem::create_directories(out / "unfinished" / "depth");
  r = RunRomunect("record " + device + " " + (out / "unfinished").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("is not empty; give a new or empty folder"), std::string::npos) << r.output;
  EXPECT_TRUE(std::filesystem::is_empty(out / "unfinished" / "depth"));
  EXPECT_FALSE(std::filesystem::exists(out / "a"));
}

// A capture that keeps no frame (here: all of them before the pose log) is an error that leaves
// no frame directory, as `fuse` refuses to fuse nothing.
TEST(CliRecord, RecordingNoFrameIsAnErrorThatLeavesNoDirectory) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 38);  // at 0 .. 2/30 s
  testing::WriteText(out / "late.csv", "time_s,x_m,y_m,z_m,qw,qx,qy,qz\n5,0.5,0,0.4,0,1,0,0\n6,0.5,0,0.3,0,1,0,0\n");
  const auto r = RunRomunect("record " + StepDevice(dir.path()) + " " + (out / "rec").string() +
                             " --no-ir --pose-log " + (out / "late.csv").string() + " --oni " +
                             (out / "rec.oni").string());
  EXPECT_EQ(r.exit_code, 2) << r.output;
  EXPECT_NE(r.output.find("recorded no frames (3 skipped"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("the streams are in"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out / "rec"));
  EXPECT_TRUE(std::filesystem::exists(out / "rec.oni"));  // the device's streams are kept
}

// A frame directory is copied as it is: device stream options are refused rather than ignored,
// and a given camera (--camera, --calibration) becomes the copy's, as for a device.
TEST(CliRecord, AFrameDirectoryCopyRefusesDeviceOptionsAndTakesTheGivenCamera) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 37);
  for (const char* option : {"--no-ir", "--raw", "--depth-unit 1mm", "--width 80", "--fps 30"}) {
    const auto r = RunRomunect("record " + dir.path().string() + " " + (out / "x").string() + " " + option);
    EXPECT_EQ(r.exit_code, 2) << option;
    EXPECT_NE(r.output.find("only an OpenNI2 source (device or .oni file) takes it"), std::string::npos) << r.output;
  }
  CameraModel calibrated = testing::SmallCamera();
  calibrated.fx *= 1.01;
  {
    cv::FileStorage fs((out / "calib.yml").string(), cv::FileStorage::WRITE);
    fs << "format"
       << "romunect-calibration"
       << "version" << 1;
    calibrated.Write(fs);
    fs << "T_H_C" << cv::Mat::eye(4, 4, CV_64F);
  }
  const auto r = RunRomunect("record " + dir.path().string() + " " + (out / "copy").string() + " --calibration " +
                             (out / "calib.yml").string());
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_EQ(FrameDirectorySource(out / "copy").camera(), calibrated);
}

TEST(CliRecord, BadInputGivesClearMessages) {
  ScratchDir out("out");
  auto r = RunRomunect("record /no/such/dir " + (out / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("/no/such/dir: not a directory"), std::string::npos) << r.output;
  r = RunRomunect("record " + Quote("romunect:/no/such/dir?pace=step") + " " + (out / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("no OpenNI2 device opens with this URI"), std::string::npos) << r.output;
  r = RunRomunect("record " + (out / "missing.oni").string() + " " + (out / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("no such .oni file"), std::string::npos) << r.output;
  r = RunRomunect("record " + (out / "x").string());
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("OUT_DIR: missing"), std::string::npos) << r.output;
  EXPECT_NE(RunRomunect("record oni:// x --depth-unit 2mm").exit_code, 0);
  // an offset onto no pose log's clock would be silently ignored
  r = RunRomunect("record " + Quote("romunect:/no/such/dir?pace=step") + " " + (out / "x").string() +
                  " --pose-offset 0.5");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.output.find("--pose-offset: applies with --pose-log"), std::string::npos) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out / "x"));
}

}  // namespace
}  // namespace romunect::openni2

namespace romunect::openni2 {
namespace {

// `record` into a disk that fills up: exit 2 with the system's reason, and no frame directory
// (before, a frames.json listed the frames written before the disk filled and `info` called it
// valid). The disk is a 200 kB tmpfs in a user namespace of its own: room for about 3 of the
// 4 frames (each ~50 kB: depth and ground truth EXR, IR and raw PNG).
TEST(CliRecord, AFullDiskLeavesNoFrameDirectoryAndSaysWhy) {
  if (RunShell("unshare -rm true").exit_code != 0) GTEST_SKIP() << "no unprivileged mount namespaces here";
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 4, 31);
  const std::string disk = (out / "disk").string();
  std::filesystem::create_directories(disk);
  const auto r = RunShell("unshare -rm sh -c " +
                          Quote("mount -t tmpfs -o size=200k none " + disk + " && " +
                                testing::RomunectBinary().string() + " record " + dir.path().string() + " " + disk +
                                "/rec; echo exit=$?; ls -A " + disk));
  EXPECT_NE(r.output.find("exit=2"), std::string::npos) << r.output;
  EXPECT_NE(r.output.find("cannot write file: No space left on device; no frame directory was written (the "),
            std::string::npos)
      << r.output;
  // Nothing is left on the disk (`ls -A` lists nothing): the partial frames went with rec.incomplete.
  EXPECT_EQ(r.output.substr(r.output.find("exit=2") + 6), "\n") << r.output;
}

// The frames go to OUT_DIR.incomplete and are renamed to OUT_DIR when the directory is
// finished: a run killed mid-capture leaves no OUT_DIR, and the next run into it replaces what
// the killed one left.
TEST(CliRecord, AKilledCaptureLeavesNoOutDirAndTheNextRunReplacesItsWork) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 4, 37);
  VirtualDeviceOptions looped;
  looped.loop = true;
  const std::string live = (out / "live").string();
  RunShell(testing::RomunectBinary().string() + " record " + Quote(VirtualDeviceUri(dir.path(), looped)) + " " +
           live + " >/dev/null & pid=$!; for i in $(seq 1 200); do [ -e " + live +
           ".incomplete/depth/000003.exr ] && break; sleep 0.05; done; kill -9 $pid; wait $pid");
  EXPECT_FALSE(std::filesystem::exists(live));
  EXPECT_TRUE(std::filesystem::exists(live + ".incomplete/.romunect-run"));
  const auto r = RunRomunect("record " + dir.path().string() + " " + live);
  ASSERT_EQ(r.exit_code, 0) << r.output;
  EXPECT_FALSE(std::filesystem::exists(live + ".incomplete"));
  EXPECT_FALSE(std::filesystem::exists(live + "/.romunect-run"));
  EXPECT_EQ(FrameDirectorySource(live).manifest().frames.size(), 4u);
}

// Every file under `dir` (hidden ones too) by its path relative to `dir`, with its bytes.
std::map<std::string, std::string> FilesUnder(const std::filesystem::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& e : std::filesystem::recursive_directory_iterator(dir)) {
    if (!e.is_regular_file()) continue;
    std::ifstream in(e.path(), std::ios::binary);
    std::ostringstream bytes;
    bytes << in.rdbuf();
    files[std::filesystem::relative(e.path(), dir).string()] = bytes.str();
  }
  return files;
}

// A capture killed mid-run (kill -9) and resumed gives the same bytes as one run without a stop,
// keeping the frames the killed run had written; a resume with other arguments is refused.
TEST(CliRecord, AKilledCaptureResumedGivesTheBytesOfAWholeRun) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  constexpr int kFrames = 120;  // enough that the copy is still running when the kill lands
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 41);
  const std::string whole = (out / "whole").string(), cut = (out / "cut").string();
  const std::string args = " --compress-frames --frames 100";
  ASSERT_EQ(RunRomunect("record " + dir.path().string() + " " + whole + args).exit_code, 0);

  RunShell(testing::RomunectBinary().string() + " record " + dir.path().string() + " " + cut + args +
           " >/dev/null & pid=$!; for i in $(seq 1 2000); do [ -e " + cut +
           ".incomplete/depth/000005.exr ] && break; sleep 0.005; done; kill -9 $pid; wait $pid");
  ASSERT_FALSE(std::filesystem::exists(cut)) << "the kill came after the capture finished";
  ASSERT_TRUE(std::filesystem::exists(cut + ".incomplete/depth/000005.exr"));

  const auto other = RunRomunect("record " + dir.path().string() + " " + cut +
                                 " --frames 99 --compress-frames --resume");
  EXPECT_EQ(other.exit_code, 2) << other.output;
  EXPECT_NE(other.output.find("--frames"), std::string::npos) << other.output;
  EXPECT_TRUE(std::filesystem::exists(cut + ".incomplete/.romunect-run")) << "a refused resume keeps the work";

  const auto r = RunRomunect("record " + dir.path().string() + " " + cut + args + " --resume");
  ASSERT_EQ(r.exit_code, 0) << r.output;
  const size_t at = r.output.find(" reused from the interrupted run");
  ASSERT_NE(at, std::string::npos) << r.output;
  const int reused = std::stoi(r.output.substr(r.output.rfind('(', at) + 1));
  EXPECT_GE(reused, 5) << r.output;  // frames 0-5 were on disk before the kill
  EXPECT_LT(reused, 100) << r.output;
  EXPECT_FALSE(std::filesystem::exists(cut + ".incomplete"));
  const auto a = FilesUnder(whole), b = FilesUnder(cut);
  ASSERT_EQ(a.size(), b.size());
  for (const auto& [name, bytes] : a) {
    ASSERT_TRUE(b.count(name)) << name;
    EXPECT_TRUE(b.at(name) == bytes) << name;
  }
}

// --resume needs an interrupted run to continue and a source that can be replayed.
TEST(CliRecord, ResumeWithoutAnInterruptedRunOrFromADeviceIsRefused) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 43);
  const auto none = RunRomunect("record " + dir.path().string() + " " + (out / "new").string() + " --resume");
  EXPECT_EQ(none.exit_code, 2) << none.output;
  EXPECT_NE(none.output.find("no interrupted record"), std::string::npos) << none.output;
  EXPECT_FALSE(std::filesystem::exists(out / "new.incomplete"));
  const auto device = RunRomunect("record " + StepDevice(dir.path()) + " " + (out / "dev").string() + " --resume");
  EXPECT_EQ(device.exit_code, 2) << device.output;
  EXPECT_NE(device.output.find("a device cannot send again"), std::string::npos) << device.output;
}

}  // namespace
}  // namespace romunect::openni2
