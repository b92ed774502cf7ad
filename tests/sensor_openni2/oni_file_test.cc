// Damaged .oni recordings: the container checks (oni_file.h) and, end to end, recordings that
// crashed libOpenNI2's file driver inside `record --list-modes`, `record` and `fuse`. Each is a
// recording this test makes (the same bytes every time: the virtual device is step-paced) with
// one byte changed, found by mutating it at random.
#include "romunect/sensor/openni2/oni_file.h"

#include <atomic>
#include <chrono>
#include <cstring>
#include <fstream>
#include <thread>

#include <gtest/gtest.h>
#include <opencv2/core/persistence.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/sensor/openni2/openni2_source.h"
#include "romunect/sensor/openni2/virtual_device.h"
#include "romunect/testing/test_support.h"

namespace romunect::openni2 {
namespace {

using testing::RunRomunect;
using testing::ScratchDir;

std::string Quote(const std::string& s) { return "'" + s + "'"; }

std::string ReadBytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

void WriteBytes(const std::filesystem::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// 4 frames of 80 x 60 depth and IR recorded from the step-paced virtual device: 185,190 bytes,
// the same each time (the mutations below are offsets into it).
std::filesystem::path MakeRecording(const ScratchDir& dir) {
  testing::WriteSampleFrameDirectory(dir / "frames", testing::SmallCamera(), 4, 31);
  VirtualDeviceOptions step;
  step.pace = VirtualDeviceOptions::Pace::kStep;
  const auto r = RunRomunect("record " + Quote(VirtualDeviceUri(dir / "frames", step)) + " " + (dir / "rec").string() +
                             " --oni " + (dir / "rec.oni").string());
  EXPECT_EQ(r.exit_code, 0) << r.output;
  return dir / "rec.oni";
}

std::string Problem(const std::string& bytes) {
  return OniStructureProblem(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
}

void Put32(std::string* bytes, size_t at, uint32_t v) { std::memcpy(bytes->data() + at, &v, 4); }

TEST(OniFile, ARecordAndItsCutShortCopiesAreSound) {
  ScratchDir dir("oni");
  const std::string bytes = ReadBytes(MakeRecording(dir));
  ASSERT_EQ(bytes.size(), 185190u);
  EXPECT_EQ(Problem(bytes), "");
  EXPECT_NO_THROW(CheckOniStructure(dir / "rec.oni"));
  // A recorder killed mid-run leaves the records so far, the last one cut (and no seek table
  // position in its node records, which this recording's first cuts have not reached yet).
  for (size_t cut : {24u, 50u, 80u}) EXPECT_EQ(Problem(bytes.substr(0, cut)), "") << cut;
}

TEST(OniFile, ContainerDamageIsNamedWithItsByteAndRecord) {
  ScratchDir dir("oni");
  const std::string good = ReadBytes(MakeRecording(dir));
  ASSERT_EQ(good.size(), 185190u);
  ASSERT_EQ(good.substr(0, 4), "NI10");
  struct Case {
    size_t at;
    uint32_t value;
    const char* expected;
  };
  // Record offsets of this recording: 24 the depth node, 98 its first property, 2487 its
  // first frame, 92311 its seek table (the layout is the recorder's, fixed for these options).
  const Case cases[] = {
      {0, 0x30314e58, "no \"NI10\" magic"},
      {20, 300, "largest node id 300, expected at most 255"},
      {98, 0x0052494F, "byte 98: record 1 (unknown): no record magic"},
      {98 + 4, 99, "record type 99, expected 2..14"},
      {98 + 8, 7, "node id 7 above the file header's largest, 2"},
      {98 + 12, 12, "fields of 12 bytes and payload of 0, expected fields of at least 28"},
      {98 + 28, 4000, "property name length 4000, expected 1..81"},
      {98 + 53, 3, "property size 3, expected 8"},
      {2487 + 16, 5760050, "frame payload larger than the driver's buffer"},
      {2487 + 20, 90000, "undo position 90000 not before the record"},
      {24 + 66, 200000, "cut short: the seek table belongs at byte 200000, past the file's 185190 bytes"},
      {92311 + 28 + 12, 999999, "seek table entry 0 points to byte 999999"},
  };
  for (const Case& c : cases) {
    std::string bad = good;
    Put32(&bad, c.at, c.value);
    EXPECT_NE(Problem(bad).find(c.expected), std::string::npos) << c.at << ": " << Problem(bad);
  }
  std::string bad = good;
  Put32(&bad, 20, 300);
  WriteBytes(dir / "bad.oni", bad);
  try {
    CheckOniStructure(dir / "bad.oni");
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    testing::ExpectContains(e.what(), {"bad.oni: not a readable .oni recording: file header: largest node id 300"});
  }
}

// One byte changed in a property name: the container is sound, and libOpenNI2 crashed with
// SIGSEGV (exit 139) in all three commands before the trial read.
TEST(OniFile, RecordingsThatCrashedTheFileDriverAreRefusedByEveryCommand) {
  ScratchDir dir("oni");
  const std::string good = ReadBytes(MakeRecording(dir));
  ASSERT_EQ(good.size(), 185190u);
  testing::WriteText(dir / "poses.csv", "time_s,x_m,y_m,z_m,qw,qx,qy,qz\n0,0,0,0.25,0,1,0,0\n0.2,0,0,0.25,0,1,0,0\n");
  {
    cv::FileStorage fs((dir / "calib.yml").string(), cv::FileStorage::WRITE);
    fs << "format" << "romunect-calibration" << "version" << 1;
    testing::SmallCamera().Write(fs);
    fs << "T_H_C" << cv::Mat::eye(4, 4, CV_64F);
  }
  struct Mutation {
    size_t at;
    char was, becomes;  // a character of a property name
  };
  const Mutation crashers[] = {
      {149, 'e', static_cast<char>('e' ^ 0x80)},  // oniRequiredFrameSize (depth)
      {318, 'u', static_cast<char>(255)},         // xnSupportedMapOutputModesCount (depth)
      {640, 'x', static_cast<char>('x' ^ 0x80)},  // xnPixelFormat (depth)
      {1449, 'i', static_cast<char>('i' ^ 0x80)},  // PixelSizeFactor (depth)
      {1950, 's', static_cast<char>(227)},        // xnSupportedPixelFormats (IR)
  };
  for (const Mutation& m : crashers) {
    ASSERT_EQ(good[m.at], m.was) << m.at;
    std::string bad = good;
    bad[m.at] = m.becomes;
    const std::filesystem::path oni = dir / ("crash_" + std::to_string(m.at) + ".oni");
    WriteBytes(oni, bad);
    EXPECT_EQ(Problem(bad), "") << m.at;  // the container checks cannot see it
    const std::string expected = oni.string() + ": libOpenNI2's file driver crashed in a trial read of this recording";
    const std::string fuse_options = " --poses " + (dir / "poses.csv").string() + " --calibration " +
                                     (dir / "calib.yml").string() + " --out " + (dir / "fused").string();
    for (const std::string& command :
         {"record --list-modes " + oni.string(), "record " + oni.string() + " " + (dir / "out").string(),
          "fuse " + oni.string() + fuse_options}) {
      const auto r = RunRomunect(command);
      EXPECT_EQ(r.exit_code, 2) << command << "\n" << r.output;
      EXPECT_NE(r.output.find(expected), std::string::npos) << command << "\n" << r.output;
    }
    for (const char* left : {"out", "out.incomplete", "fused", "fused.incomplete"}) {
      EXPECT_FALSE(std::filesystem::exists(dir / left)) << left;
    }
  }
  // The intact recording still reads in all three.
  const std::string oni = (dir / "rec.oni").string();
  EXPECT_EQ(RunRomunect("record --list-modes " + oni).exit_code, 0);
  EXPECT_EQ(RunRomunect("record " + oni + " " + (dir / "out").string()).exit_code, 0);
  const auto fused = RunRomunect("fuse " + oni + " --poses " + (dir / "poses.csv").string() + " --calibration " +
                                 (dir / "calib.yml").string() + " --out " + (dir / "fused").string());
  EXPECT_EQ(fused.exit_code, 0) << fused.output;
}

// The trial read is a program of its own, never a fork: a fork of a process whose libOpenNI2
// has threads inherits the locks they hold, and waited on them for ever. Another thread keeps
// libOpenNI2 busy here while the same recording opens again and again.
TEST(OniFile, RecordingsOpenWhileOtherThreadsUseOpenNI2) {
  ScratchDir dir("oni");
  const std::filesystem::path oni = MakeRecording(dir);
  struct Busy {
    std::atomic<bool> stop{false};
    std::thread thread{[this] {
      while (!stop) ListDevices();
    }};
    ~Busy() {
      stop = true;
      thread.join();
    }
  } busy;
  OpenNI2SourceOptions options;
  options.uri = oni.string();
  const auto start = std::chrono::steady_clock::now();
  for (int i = 0; i < 20; ++i) {
    OpenNI2Source source(options);
    Frame frame;
    std::string error;
    ASSERT_EQ(source.Next(&frame, &error), FrameStatus::kOk) << i << ": " << error;
  }
  // 20 opens take about 2 s; a trial read that hangs waits out its 60 s limit.
  EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count(), 50.0);
}

// The program is found, and one that is not the one built with this library says so.
TEST(OniFile, TheTrialReadProgramRefusesArgumentsItDoesNotKnow) {
  ScratchDir dir("oni");
  const std::filesystem::path oni = MakeRecording(dir);
  EXPECT_EQ(OniTrialReadProgram().filename(), kOniTrialReadProgramName);
  EXPECT_TRUE(std::filesystem::is_regular_file(OniTrialReadProgram()));
  EXPECT_NO_THROW(TrialReadOni(oni, {"modes", oni.string()}, 60.0));
  const std::string o = oni.string();
  const std::vector<std::vector<std::string>> wrongs = {
      {},
      {"read", o},
      {"read", o, "2", "1", "1", "0", "0", "0", "auto", "0", "2"},   // a flag of 2
      {"read", o, "0", "1", "1", "0", "0", "0", "10um", "0", "2"},   // no such unit
      {"read", o, "0", "1", "1", "0", "0", "x", "auto", "0", "2"}};  // a rate that is no number
  for (const std::vector<std::string>& wrong : wrongs) {
    try {
      TrialReadOni(oni, wrong, 60.0);
      ADD_FAILURE() << wrong.size();
    } catch (const InputError& e) {
      testing::ExpectContains(e.what(), {oni.string() + ": its trial read, the program", "refused its arguments"});
    }
  }
}

}  // namespace
}  // namespace romunect::openni2
