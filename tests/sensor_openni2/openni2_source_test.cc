// OpenNI2Source against the virtual device and OpenNI2's file driver: every frame of a small
// frame directory must come back through libOpenNI2 bit for bit (depth after the wire's
// quantization, IR and microsecond timestamps exactly).
#include "romunect/sensor/openni2/openni2_source.h"

#include <chrono>
#include <cmath>
#include <fstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/clock.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/openni2/depth_units.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::ImagesBitEqual;
using testing::ScratchDir;

// The device reports fields of view as float radians: fx comes back to float precision.
constexpr double kFovFocalRelTolerance = 1e-6;
// A stalled stream must be reported within its timeout plus scheduling slack on a loaded CI box.
constexpr double kStallReportSlackS = 3.0;
constexpr int kFrames = 5;

// The slow, obvious reference for the wire's depth rule: per pixel, in double.
cv::Mat ExpectedDepth(const cv::Mat& depth_m, DepthUnit unit) {
  cv::Mat out(depth_m.size(), CV_32F);
  const double unit_m = unit == DepthUnit::k100um ? 1e-4 : 1e-3;
  for (int v = 0; v < depth_m.rows; ++v) {
    for (int u = 0; u < depth_m.cols; ++u) {
      const double d = depth_m.at<float>(v, u);
      double counts = d > 0.0 ? std::round(d / unit_m) : 0.0;
      if (counts > 65535.0) counts = 0.0;
      out.at<float>(v, u) = static_cast<float>(counts * unit_m);
    }
  }
  return out;
}

double ExpectedTime(double t_s, double t0_s) {
  return static_cast<double>(std::llround(t_s * 1e6) - std::llround(t0_s * 1e6)) * 1e-6;
}

std::vector<Frame> ReadAll(FrameSource& source) {
  std::vector<Frame> frames;
  Frame f;
  std::string error;
  for (FrameStatus s; (s = source.Next(&f, &error)) != FrameStatus::kEndOfStream;) {
    EXPECT_EQ(s, FrameStatus::kOk) << error;
    frames.push_back(f);
  }
  return frames;
}

// Checks frames against the directory they came from, frame by frame.
void ExpectMatchesDirectory(const std::vector<Frame>& frames, const std::filesystem::path& dir, DepthUnit unit,
                            size_t expected_count, bool allow_missing_ir = false) {
  FrameDirectorySource truth(dir);
  const auto& records = truth.manifest().frames;
  ASSERT_EQ(frames.size(), expected_count);
  for (const Frame& f : frames) {
    ASSERT_GE(f.index, 0);
    ASSERT_LT(static_cast<size_t>(f.index), records.size());
    const Frame expected = LoadFrame(dir, truth.manifest(), f.index);
    SCOPED_TRACE("frame " + std::to_string(f.index));
    EXPECT_TRUE(ImagesBitEqual(f.depth_m, ExpectedDepth(expected.depth_m, unit)));
    if (!(allow_missing_ir && f.ir.empty())) {
      EXPECT_TRUE(ImagesBitEqual(f.ir, expected.ir));
    }
    EXPECT_EQ(f.time_s, ExpectedTime(records[f.index].time_s, records[0].time_s));
    EXPECT_FALSE(f.T_B_H.has_value());
  }
}

VirtualDeviceOptions Step() {
  VirtualDeviceOptions o;
  o.pace = VirtualDeviceOptions::Pace::kStep;
  return o;
}

TEST(DepthUnits, QuantizationFollowsTheDocumentedRule) {
  EXPECT_EQ(QuantizeDepth(0.2f, DepthUnit::k100um), 2000);
  EXPECT_EQ(QuantizeDepth(0.2f, DepthUnit::k1mm), 200);
  EXPECT_EQ(QuantizeDepth(0.0f, DepthUnit::k100um), 0);
  EXPECT_EQ(QuantizeDepth(-0.1f, DepthUnit::k100um), 0);
  EXPECT_EQ(QuantizeDepth(std::nanf(""), DepthUnit::k100um), 0);
  EXPECT_EQ(QuantizeDepth(6.5535f, DepthUnit::k100um), 65535);
  EXPECT_EQ(QuantizeDepth(6.6f, DepthUnit::k100um), 0);  // beyond the wire's range: no measurement
  EXPECT_EQ(DequantizeDepth(2000, DepthUnit::k100um), static_cast<float>(0.2));
  // Over the working range the round trip errs by at most half a unit (plus float rounding).
  for (float d = 0.15f; d < 0.25f; d += 0.0000137f) {
    EXPECT_LE(std::abs(DequantizeDepth(QuantizeDepth(d, DepthUnit::k100um), DepthUnit::k100um) - d), 0.5e-4 + 1e-7);
  }
}

TEST(VirtualDevice, PlaysAFrameDirectoryThroughOpenNI2BitForBit) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 11);
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  OpenNI2Source source(options);
  EXPECT_EQ(source.depth_unit(), DepthUnit::k100um);
  EXPECT_FALSE(source.is_recording_playback());
  EXPECT_NE(source.Describe().find("80x60 @30 Hz, depth in 100 um, IR, 5 frames; chip: zero plane 120 mm"),
            std::string::npos)
      << source.Describe();
  EXPECT_NE(source.Describe().find("emitter-camera 75 mm"), std::string::npos) << source.Describe();
  const CameraModel truth = testing::SmallCamera();
  EXPECT_EQ(source.camera().width, truth.width);
  EXPECT_NEAR(source.camera().fx, truth.fx, kFovFocalRelTolerance * truth.fx);
  EXPECT_NEAR(source.camera().fy, truth.fy, kFovFocalRelTolerance * truth.fy);
  // The stock chip's geometry, as the twin's kinect-v1 preset has it.
  ASSERT_TRUE(source.chip().zero_plane_distance_m.has_value());
  EXPECT_DOUBLE_EQ(*source.chip().zero_plane_distance_m, 0.120);
  ASSERT_TRUE(source.chip().emitter_camera_distance_m.has_value());
  EXPECT_NEAR(*source.chip().emitter_camera_distance_m, 0.075, 1e-12);
  EXPECT_TRUE(source.chip().zero_plane_pixel_size_m.has_value());

  const std::vector<Frame> frames = ReadAll(source);
  ExpectMatchesDirectory(frames, dir.path(), DepthUnit::k100um, kFrames);
  for (int i = 0; i < kFrames; ++i) EXPECT_EQ(frames[i].index, i);
  EXPECT_EQ(source.stats().frames, kFrames);
  EXPECT_EQ(source.stats().dropped_frames, 0);
  EXPECT_EQ(source.stats().unpaired_ir, 0);
}

TEST(VirtualDevice, OneMillimetreUnitAndDepthOnly) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 12);
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  options.depth_unit = DepthUnit::k1mm;
  options.ir = false;
  OpenNI2Source source(options);
  EXPECT_EQ(source.depth_unit(), DepthUnit::k1mm);
  const std::vector<Frame> frames = ReadAll(source);
  ASSERT_EQ(frames.size(), 3u);
  FrameDirectorySource truth(dir.path());
  for (const Frame& f : frames) {
    EXPECT_TRUE(ImagesBitEqual(f.depth_m, ExpectedDepth(LoadFrame(dir.path(), truth.manifest(), f.index).depth_m,
                                                        DepthUnit::k1mm)));
    EXPECT_TRUE(f.ir.empty());
  }
}

// The chip's raw shifts (PS1080 SHIFT_9_2) pass through OpenNI2 as sent, live and from a
// recording, so the calibration's exact depth model can run on captures.
TEST(VirtualDevice, RawShiftsComeThroughOpenNI2AndRecordingsBitForBit) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 3, 18);
  const std::filesystem::path oni = out / "raw.oni";
  FrameDirectorySource truth(dir.path());
  auto expect_raw = [&](const std::vector<Frame>& frames) {
    ASSERT_EQ(frames.size(), 3u);
    for (const Frame& f : frames) {
      const Frame expected = LoadFrame(dir.path(), truth.manifest(), f.index);
      EXPECT_TRUE(ImagesBitEqual(f.raw, expected.raw)) << f.index;
      EXPECT_TRUE(ImagesBitEqual(f.ir, expected.ir)) << f.index;
      EXPECT_TRUE(f.depth_m.empty());
    }
  };
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  options.raw = true;
  options.record_oni = oni;
  {
    OpenNI2Source live(options);
    EXPECT_NE(live.Describe().find("raw shifts"), std::string::npos) << live.Describe();
    expect_raw(ReadAll(live));
    live.FinishRecording();
  }
  options.uri = oni.string();
  options.record_oni.clear();
  OpenNI2Source playback(options);
  expect_raw(ReadAll(playback));
  // Metric depth from a recording of raw shifts is a clear error, not garbage.
  options.raw = false;
  try {
    OpenNI2Source wrong(options);
    ADD_FAILURE() << "opened";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("holds the chip's raw shifts (shift9.2)"), std::string::npos) << e.what();
  }
}

TEST(VirtualDevice, RealtimePaceDeliversMatchingFramesAndCountsDrops) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 4, 13);
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path());
  OpenNI2Source source(options);
  const std::vector<Frame> frames = ReadAll(source);
  // A loaded machine may drop frames (or an IR frame) at 30 Hz, as on hardware; whatever arrives
  // must be exact, and every loss accounted for.
  ASSERT_FALSE(frames.empty());
  ExpectMatchesDirectory(frames, dir.path(), DepthUnit::k100um, frames.size(), /*allow_missing_ir=*/true);
  EXPECT_EQ(source.stats().frames + source.stats().dropped_frames, 4);
  int without_ir = 0;
  for (const Frame& f : frames) without_ir += f.ir.empty();
  EXPECT_LE(without_ir, source.stats().unpaired_ir);
  EXPECT_EQ(frames.back().index, 3);  // the last frame is never lost: nothing replaces it
}

// A frame whose image cannot be read is a frame the device never sent: its number is skipped,
// so the reader sees a dropped frame, and the stream goes on.
TEST(VirtualDevice, AnUnreadableFrameIsADroppedFrame) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 19);
  {
    FrameDirectorySource truth(dir.path());
    std::filesystem::remove(dir.path() / truth.manifest().frames[2].depth);
  }
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  OpenNI2Source source(options);
  const std::vector<Frame> frames = ReadAll(source);
  ASSERT_EQ(frames.size(), static_cast<size_t>(kFrames - 1));
  EXPECT_EQ(frames[1].index, 1);
  EXPECT_EQ(frames[2].index, 3);
  ExpectMatchesDirectory(frames, dir.path(), DepthUnit::k100um, kFrames - 1);
  EXPECT_EQ(source.stats().dropped_frames, 1);
}

// loop=1: a short directory plays over and over as an endless device. Whatever a loaded machine
// lets through must be exact: each frame is the directory's frame at its position modulo the
// directory's length, and times go on at the directory's rate (a pass follows the last one by
// one frame interval).
TEST(VirtualDevice, LoopedDirectoryRepeatsWithTimesGoingOn) {
  ScratchDir dir("frames");
  constexpr int kShortFrames = 3;
  constexpr int kRead = 3 * kShortFrames + 1;
  constexpr double kPeriodS = 1.0 / 30.0;  // the sample frames' interval
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kShortFrames, 18);
  VirtualDeviceOptions device;
  device.loop = true;
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), device);
  options.max_frames = kRead;
  OpenNI2Source source(options);
  EXPECT_EQ(source.Describe().find(" frames"), std::string::npos) << source.Describe();  // endless
  const std::vector<Frame> frames = ReadAll(source);
  ASSERT_EQ(frames.size(), static_cast<size_t>(kRead));
  FrameDirectorySource truth(dir.path());
  std::vector<cv::Mat> expected_depth;
  for (int i = 0; i < kShortFrames; ++i) {
    expected_depth.push_back(ExpectedDepth(LoadFrame(dir.path(), truth.manifest(), i).depth_m, DepthUnit::k100um));
  }
  // The first frame read may be any of the directory's (a frame lost at the start).
  int first = -1;
  for (int i = 0; i < kShortFrames && first < 0; ++i) {
    if (ImagesBitEqual(frames[0].depth_m, expected_depth[i])) first = i;
  }
  ASSERT_GE(first, 0);
  for (const Frame& f : frames) {
    SCOPED_TRACE("frame " + std::to_string(f.index));
    EXPECT_TRUE(ImagesBitEqual(f.depth_m, expected_depth[(first + f.index) % kShortFrames]));
    // Timestamps are whole microseconds, each rounded on its own.
    EXPECT_NEAR(f.time_s, f.index * kPeriodS, 1.01e-6);
  }
  EXPECT_EQ(frames.back().index, kRead - 1 + source.stats().dropped_frames);
}

// Records the virtual device playing the frame directory `dir` into `oni`; returns the frames
// it delivered meanwhile.
std::vector<Frame> RecordVirtualDevice(const std::filesystem::path& dir, const std::filesystem::path& oni) {
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir, Step());
  options.record_oni = oni;
  OpenNI2Source live(options);
  std::vector<Frame> frames = ReadAll(live);
  live.FinishRecording();
  return frames;
}

TEST(OniRecording, RecordsTheVirtualDeviceAndPlaysBackThroughTheFileDriver) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 14);
  const std::filesystem::path oni = out / "scan.oni";
  ExpectMatchesDirectory(RecordVirtualDevice(dir.path(), oni), dir.path(), DepthUnit::k100um, kFrames);
  ASSERT_TRUE(std::filesystem::is_regular_file(oni));

  OpenNI2SourceOptions options;
  options.uri = oni.string();
  OpenNI2Source playback(options);
  EXPECT_TRUE(playback.is_recording_playback());
  EXPECT_EQ(playback.depth_unit(), DepthUnit::k100um);
  EXPECT_NEAR(playback.camera().fx, testing::SmallCamera().fx, kFovFocalRelTolerance * testing::SmallCamera().fx);
  // The chip's geometry travels in the recording.
  ASSERT_TRUE(playback.chip().zero_plane_distance_m.has_value());
  EXPECT_DOUBLE_EQ(*playback.chip().zero_plane_distance_m, 0.120);
  ASSERT_TRUE(playback.chip().emitter_camera_distance_m.has_value());
  EXPECT_NEAR(*playback.chip().emitter_camera_distance_m, 0.075, 1e-12);
  const std::vector<Frame> frames = ReadAll(playback);
  ExpectMatchesDirectory(frames, dir.path(), DepthUnit::k100um, kFrames);
  for (int i = 0; i < kFrames; ++i) EXPECT_EQ(frames[i].index, i);
  EXPECT_EQ(playback.stats().dropped_frames, 0);
}

// Once a recording has been played to its end, OpenNI2's player thread (PlayerDevice::MainLoop)
// reads on at the end of the file without pausing while a stream runs, which kept a core busy
// for as long as the source lived (through a fusion's extraction or a calibration's solve). The
// source stops its streams at the end of the stream, and the thread then sleeps 10 ms a turn.
TEST(OniRecording, AFinishedPlaybackLeavesNoThreadSpinning) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  constexpr int kShortFrames = 3;
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kShortFrames, 17);
  const std::filesystem::path oni = out / "done.oni";
  ASSERT_EQ(RecordVirtualDevice(dir.path(), oni).size(), static_cast<size_t>(kShortFrames));
  OpenNI2SourceOptions options;
  options.uri = oni.string();
  OpenNI2Source playback(options);
  ASSERT_EQ(ReadAll(playback).size(), static_cast<size_t>(kShortFrames));
  Frame f;
  std::string error;
  ASSERT_EQ(playback.Next(&f, &error), FrameStatus::kEndOfStream);  // asking again changes nothing
  // CPU time of the whole process: every thread, libOpenNI2's included.
  const double cpu0 = ProcessCpuSeconds();
  const Stopwatch wall;
  std::this_thread::sleep_for(std::chrono::milliseconds(400));
  const double wall_s = wall.seconds();
  // A spinning thread takes about a core (1 s of CPU per s); a sleeping one almost nothing. On a
  // loaded machine the spinner gets less than a core, so the bound is generous.
  EXPECT_LT(ProcessCpuSeconds() - cpu0, 0.25 * wall_s);
}

std::string OpenError(const OpenNI2SourceOptions& options) {
  try {
    OpenNI2Source source(options);
  } catch (const InputError& e) {
    return e.what();
  }
  return "(no error)";
}

// OpenNI2's file driver plays each opened recording on a thread of its own that walks the
// device's streams without a lock (every 10 ms while none runs), so taking a playback down must
// never free a stream under it: that race crashed about 1 in 50 runs. Many short playbacks, ended
// each way a source ends (after one frame, at the end, before any frame, and by an error of the
// constructor once the streams exist), with and without IR, give that thread many chances.
TEST(OniRecording, ManyShortPlaybacksOpenAndCloseCleanly) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  constexpr int kShortFrames = 2;
  constexpr int kCycles = 200;
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kShortFrames, 16);
  const std::filesystem::path oni = out / "short.oni";
  ASSERT_EQ(RecordVirtualDevice(dir.path(), oni).size(), static_cast<size_t>(kShortFrames));
  for (int i = 0; i < kCycles; ++i) {
    SCOPED_TRACE("playback " + std::to_string(i));
    OpenNI2SourceOptions options;
    options.uri = oni.string();
    options.ir = (i / 4) % 2 == 0;
    Frame f;
    std::string error;
    switch (i % 4) {
      case 0: {
        OpenNI2Source playback(options);
        ASSERT_EQ(playback.Next(&f, &error), FrameStatus::kOk) << error;
        EXPECT_EQ(f.index, 0);
        break;
      }
      case 1: {
        OpenNI2Source playback(options);
        ASSERT_EQ(ReadAll(playback).size(), static_cast<size_t>(kShortFrames));
        break;
      }
      case 2: {
        OpenNI2Source playback(options);
        break;
      }
      default: {
        options.width = options.height = 8;  // not the recorded size: thrown after the streams exist
        EXPECT_NE(OpenError(options).find("not the requested 8x8"), std::string::npos);
        break;
      }
    }
  }
}

TEST(VirtualDevice, StalledDeviceGivesAClearErrorWithinTheTimeoutAndKeepsEarlierFrames) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 15);
  VirtualDeviceOptions device = Step();
  device.stop_after = 2;
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), device);
  options.timeout_s = 0.5;
  OpenNI2Source source(options);
  std::vector<Frame> kept;
  Frame f;
  std::string error;
  ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk) << error;
  kept.push_back(f);
  ASSERT_EQ(source.Next(&f, &error), FrameStatus::kOk) << error;
  kept.push_back(f);
  const Stopwatch stall;
  try {
    source.Next(&f, &error);
    FAIL() << "a stalled device must throw";
  } catch (const InputError& e) {
    const std::string message = e.what();
    EXPECT_NE(message.find(options.uri), std::string::npos) << message;
    EXPECT_NE(
        message.find(
            "no frame for 0.5 s (device unplugged or stalled); 2 frames were delivered before, the last at index 1"),
        std::string::npos)
        << message;
  }
  const double elapsed_s = stall.seconds();
  EXPECT_GE(elapsed_s, 0.5);
  EXPECT_LT(elapsed_s, 0.5 + kStallReportSlackS);
  // What came before the stall is intact.
  ExpectMatchesDirectory(kept, dir.path(), DepthUnit::k100um, 2);
}

TEST(OpenNI2SourceErrors, UnknownUriNamesTheUriAndTheDevicesFound) {
  OpenNI2SourceOptions options;
  options.uri = "romunect:/no/such/frame/directory";
  std::string m = OpenError(options);
  EXPECT_NE(m.find("romunect:/no/such/frame/directory: no OpenNI2 device opens with this URI: "
                   "/no/such/frame/directory is not a frame directory (no frames.json)"),
            std::string::npos)
      << m;
  options.uri = "romunect:/tmp?pace=fast";
  m = OpenError(options);
  EXPECT_NE(m.find(
                "romunect:/tmp?pace=fast: not a valid virtual-device URI: unknown or malformed parameter 'pace=fast'"),
            std::string::npos)
      << m;
  options.uri = "usb://bogus/1";
  m = OpenError(options);
  EXPECT_NE(m.find("usb://bogus/1: no OpenNI2 device opens with this URI"), std::string::npos) << m;
  EXPECT_NE(m.find("devices found:"), std::string::npos) << m;
}

// A directory without frames used to open as a device without sensors: "the device has no depth
// sensor".
TEST(OpenNI2SourceErrors, AFrameDirectoryWithoutFramesIsRefusedAsSuch) {
  ScratchDir dir("no_frames");
  FrameDirectoryWriter(dir.path(), testing::SmallCamera()).Finish();
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  const std::string m = OpenError(options);
  EXPECT_NE(m.find("frames.json: frames: is empty: a virtual device needs at least one frame"), std::string::npos) << m;
}

// frames.json's "ps1080" block is what the device reports to every client, which divides by its
// factors and sizes shift tables by max_shift: a value no PS1080 reports is refused by key (1e30
// as a whole number was undefined behaviour, -1 became 2^64 - 1); sound values are reported.
TEST(OpenNI2SourceErrors, AChipBlockNoPs1080ReportsIsRefusedByKey) {
  ScratchDir dir("chip_block");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 16);
  const std::filesystem::path manifest_file = dir.path() / "frames.json";
  const nlohmann::json manifest = nlohmann::json::parse(testing::ReadText(manifest_file));
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  const std::vector<std::pair<nlohmann::json, std::string>> refused = {
      {{{"max_shift", 1e30}}, "ps1080.max_shift: expected a whole number in [1, 65535], found 1e+30"},
      {{{"max_shift", -1}}, "ps1080.max_shift: expected a whole number in [1, 65535], found -1"},
      {{{"param_coeff", 0}}, "ps1080.param_coeff: expected a whole number in [1, 65535], found 0"},
      {{{"zero_plane_pixel_size_mm", "0.1"}}, "ps1080.zero_plane_pixel_size_mm: expected a number in (0.0, 10.0]"},
      {nlohmann::json(5), "ps1080: expected an object"}};
  for (const auto& [block, message] : refused) {
    nlohmann::json bad = manifest;
    bad["ps1080"] = block;
    testing::WriteText(manifest_file, bad.dump());
    const std::string m = OpenError(options);
    EXPECT_NE(m.find("frames.json: " + message), std::string::npos) << m;
  }
  nlohmann::json sound = manifest;
  sound["ps1080"] = {{"const_shift", 201}, {"max_shift", 2047}};
  testing::WriteText(manifest_file, sound.dump());
  OpenNI2Source source(options);
  ASSERT_TRUE(source.chip().const_shift.has_value());
  EXPECT_EQ(*source.chip().const_shift, 201);
}

TEST(OpenNI2SourceErrors, UnsupportedModeListsTheOfferedModes) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 16);
  OpenNI2SourceOptions options;
  options.uri = VirtualDeviceUri(dir.path(), Step());
  options.width = 1280;
  options.height = 1024;
  options.fps = 30;
  const std::string m = OpenError(options);
  // As a PS1080: 1 mm and 100 um at half size (its QVGA, the default) and full size (VGA).
  EXPECT_NE(m.find("video mode: depth 1280x1024 @30 Hz in 100um or 1mm is not offered; the device offers: "
                   "depth 40x30 @30 Hz 1mm, depth 40x30 @30 Hz 100um, depth 80x60 @30 Hz 1mm, "
                   "depth 80x60 @30 Hz 100um, depth 80x60 @30 Hz shift9.2"),
            std::string::npos)
      << m;
  const auto modes = ListVideoModes(options.uri);
  ASSERT_EQ(modes.size(), 7u);
  EXPECT_EQ(modes[5], "ir 40x30 @30 Hz gray16");
  EXPECT_EQ(modes[6], "ir 80x60 @30 Hz gray16");
}

TEST(OpenNI2SourceErrors, InvalidOptionsNameTheField) {
  OpenNI2SourceOptions options;
  options.timeout_s = -1.0;
  EXPECT_NE(OpenError(options).find("timeout_s = -1"), std::string::npos);
  options = {};
  options.depth = options.ir = false;
  EXPECT_NE(OpenError(options).find("at least one stream"), std::string::npos);
}

TEST(OpenNI2SourceErrors, CorruptOrMissingOniFileIsRejected) {
  ScratchDir dir("oni");
  testing::WriteText(dir / "garbage.oni", std::string(4096, 'x'));
  testing::WriteText(dir / "empty.oni", "");
  OpenNI2SourceOptions options;
  for (const char* name : {"garbage.oni", "empty.oni"}) {
    options.uri = (dir / name).string();
    const std::string m = OpenError(options);
    EXPECT_NE(m.find(options.uri + ": not a readable .oni recording"), std::string::npos) << m;
  }
  options.uri = (dir / "missing.oni").string();
  EXPECT_NE(OpenError(options).find("missing.oni: no such .oni file"), std::string::npos);
}

TEST(OpenNI2SourceErrors, TruncatedRecordingIsRejected) {
  ScratchDir dir("frames");
  ScratchDir out("out");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), kFrames, 17);
  const std::filesystem::path oni = out / "scan.oni";
  RecordVirtualDevice(dir.path(), oni);
  // A recording cut to a quarter (a copy interrupted early) has lost its stream descriptions.
  const std::string bytes = testing::ReadText(oni);
  testing::WriteText(out / "cut.oni", bytes.substr(0, bytes.size() / 4));
  OpenNI2SourceOptions options;
  options.uri = (out / "cut.oni").string();
  const std::string m = OpenError(options);
  EXPECT_NE(m.find("cut.oni: not a readable .oni recording"), std::string::npos) << m;
}

TEST(OpenNI2Runtime, DriversComeFromTheBuildTree) {
  const std::filesystem::path drivers = DriverDirectory();
  EXPECT_EQ(drivers, std::filesystem::path(ROMUNECT_BINARY_DIR) / "lib" / "OpenNI2" / "Drivers");
  EXPECT_TRUE(std::filesystem::exists(drivers / "libRomunectVirtual.so.0"));
}

}  // namespace
}  // namespace romunect::openni2
