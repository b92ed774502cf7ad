#include "romunect/sensor/frame_io.h"

#include <limits>

#include <sys/stat.h>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>
#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/color_camera.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using nlohmann::json;
using testing::ScratchDir;

// Expects `fn` to throw InputError whose message contains every fragment.
template <typename Fn>
void ExpectInputError(Fn fn, std::initializer_list<std::string> fragments) {
  try {
    fn();
    ADD_FAILURE() << "expected InputError";
  } catch (const InputError& e) {
    for (const std::string& f : fragments) {
      EXPECT_NE(std::string(e.what()).find(f), std::string::npos) << "'" << f << "' not in: " << e.what();
    }
  }
}

TEST(FrameDirectory, WrittenAndReadBackBitForBit) {
  ScratchDir dir("frames");
  const CameraModel camera = testing::SmallCamera();
  const std::vector<Frame> frames = testing::SampleFrames(camera, 4, 11);
  testing::WriteSampleFrameDirectory(dir.path(), camera, 4, 11);

  FrameDirectorySource source(dir.path());
  EXPECT_EQ(source.camera(), camera);
  Frame frame;
  std::string error;
  for (const Frame& expected : frames) {
    ASSERT_EQ(source.Next(&frame, &error), FrameStatus::kOk) << error;
    EXPECT_EQ(frame.index, expected.index);
    EXPECT_EQ(frame.time_s, expected.time_s);
    EXPECT_TRUE(testing::ImagesBitEqual(frame.depth_m, expected.depth_m));
    EXPECT_TRUE(testing::ImagesBitEqual(frame.gt_depth_m, expected.gt_depth_m));
    EXPECT_TRUE(testing::ImagesBitEqual(frame.ir, expected.ir));
    EXPECT_TRUE(testing::ImagesBitEqual(frame.raw, expected.raw));
    ASSERT_TRUE(frame.T_W_C.has_value());
    EXPECT_EQ(frame.T_W_C->matrix(), expected.T_W_C->matrix());
    EXPECT_EQ(frame.T_B_H.has_value(), expected.T_B_H.has_value());
    if (frame.T_B_H) {
      EXPECT_EQ(frame.T_B_H->matrix(), expected.T_B_H->matrix());
    }
  }
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kEndOfStream);
}

TEST(FrameDirectory, SameSeedSameBytes) {
  ScratchDir a("a"), b("b");
  testing::WriteSampleFrameDirectory(a.path(), testing::SmallCamera(), 2, 5);
  testing::WriteSampleFrameDirectory(b.path(), testing::SmallCamera(), 2, 5);
  for (const char* f : {"frames.json", "depth/000001.exr", "ir/000001.png", "raw/000000.png"}) {
    EXPECT_EQ(testing::ReadText(a / f), testing::ReadText(b / f)) << f;
  }
}

TEST(FrameDirectory, UnknownKeysAreKeptAndIgnored) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 2, 3);
  json doc = json::parse(testing::ReadText(dir / "frames.json"));
  doc["producer"] = "some other tool";
  doc["frames"][1]["exposure_s"] = 0.01;
  testing::WriteText(dir / "frames.json", doc.dump());
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir.path());
  ASSERT_EQ(manifest.frames.size(), 2u);
  // Rewriting keeps them.
  ScratchDir copy("copy");
  WriteFrameDirectoryManifest(copy.path(), manifest);
  const json back = json::parse(testing::ReadText(copy / "frames.json"));
  EXPECT_EQ(back["producer"], "some other tool");
  EXPECT_EQ(back["frames"][1]["exposure_s"], 0.01);
}

TEST(FrameDirectory, RegionIsWrittenAndReadBackAndOptional) {
  ScratchDir with("with"), without("without");
  testing::WriteSampleFrameDirectory(without.path(), testing::SmallCamera(), 1, 3);
  EXPECT_FALSE(ReadFrameDirectoryManifest(without.path()).region_W.has_value());
  {
    FrameDirectoryWriter writer(with.path(), testing::SmallCamera());
    writer.Add(testing::SampleFrames(testing::SmallCamera(), 1, 3)[0]);
    writer.SetRegion({{0.375, -0.04, -0.004}, {0.525, 0.04, 0.065}});
    writer.Finish();
  }
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(with.path());
  ASSERT_TRUE(manifest.region_W.has_value());
  EXPECT_EQ(manifest.region_W->min_W, Eigen::Vector3d(0.375, -0.04, -0.004));
  EXPECT_EQ(manifest.region_W->max_W, Eigen::Vector3d(0.525, 0.04, 0.065));
  // A known key: not carried twice through the unknown ones.
  EXPECT_EQ(json::parse(manifest.extra_json).count("region_W"), 0u);
  ScratchDir copy("copy");
  WriteFrameDirectoryManifest(copy.path(), manifest);
  EXPECT_EQ(json::parse(testing::ReadText(copy / "frames.json"))["region_W"],
            json::array({0.375, -0.04, -0.004, 0.525, 0.04, 0.065}));
}

// A colour image per frame (R, G, B bytes) and the colour camera it comes from: written, read back
// bit for bit, and refused where it does not fit.
TEST(FrameDirectory, ColourImagesAndTheirCameraRoundTripAndAreValidated) {
  ScratchDir dir("frames");
  const CameraModel camera = testing::SmallCamera();
  ColorCamera color = StockColorCamera();
  color.camera = ScaledCamera(color.camera, 32, 24);
  Frame frame = testing::SampleFrames(camera, 1, 7)[0];
  frame.color = cv::Mat(24, 32, CV_8UC3);
  cv::randu(frame.color, 0, 256);
  {
    FrameDirectoryWriter writer(dir.path(), camera);
    writer.SetColorCamera(color);
    writer.Add(frame);
    writer.Finish();
  }
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir.path());
  ASSERT_TRUE(manifest.color_camera.has_value());
  EXPECT_EQ(*manifest.color_camera, color);
  EXPECT_EQ(manifest.frames[0].color, "color/000000.png");
  const Frame back = LoadFrame(dir.path(), manifest, 0);
  EXPECT_TRUE(testing::ImagesBitEqual(back.color, frame.color));

  const json good = json::parse(testing::ReadText(dir / "frames.json"));
  auto expect_refused = [&](const json& doc, std::initializer_list<std::string> fragments) {
    testing::WriteText(dir / "frames.json", doc.dump());
    ExpectInputError([&] { LoadFrame(dir.path(), ReadFrameDirectoryManifest(dir.path()), 0); }, fragments);
  };
  json no_camera = good;
  no_camera.erase("color_camera");
  expect_refused(no_camera, {"frames[0].color", "color_camera"});
  json no_pose = good;
  no_pose["color_camera"].erase("T_C_RGB");
  expect_refused(no_pose, {"color_camera.T_C_RGB", "missing"});
  json not_rigid = good;
  not_rigid["color_camera"]["T_C_RGB"][0] = 2.0;
  expect_refused(not_rigid, {"color_camera.T_C_RGB", "rigid"});
  json other_size = good;
  other_size["color_camera"]["width"] = 64;
  expect_refused(other_size, {"color/000000.png", "expected 64 x 24"});
  json grey = good;
  grey["frames"][0]["color"] = "ir/000000.png";
  grey["color_camera"]["width"] = camera.width;
  grey["color_camera"]["height"] = camera.height;
  expect_refused(grey, {"ir/000000.png", "8-bit RGB"});
}

TEST(FrameDirectory, WriterRefusesToOverwriteAFinishedDirectory) {
  ScratchDir dir("frames");
  testing::WriteSampleFrameDirectory(dir.path(), testing::SmallCamera(), 1, 3);
  const std::string before = testing::ReadText(dir / "frames.json");
  ExpectInputError([&] { FrameDirectoryWriter(dir.path(), testing::SmallCamera()); },
                   {"frames.json", "refusing to overwrite"});
  EXPECT_EQ(testing::ReadText(dir / "frames.json"), before);
}

TEST(FrameDirectory, UnfinishedDirectoryHasNoManifest) {
  ScratchDir dir("frames");
  {
    FrameDirectoryWriter writer(dir.path(), testing::SmallCamera());
    writer.Add(testing::SampleFrames(testing::SmallCamera(), 1, 1)[0]);
  }
  EXPECT_FALSE(fs::exists(dir / "frames.json"));
  ExpectInputError([&] { ReadFrameDirectoryManifest(dir.path()); }, {"frames.json", "not found"});
}

// Each bad input: one message naming the file and the field.
class BadFrameDirectory : public ::testing::Test {
 protected:
  void SetUp() override {
    testing::WriteSampleFrameDirectory(dir_.path(), testing::SmallCamera(), 2, 3);
    doc_ = json::parse(testing::ReadText(dir_ / "frames.json"));
  }
  void Rewrite() { testing::WriteText(dir_ / "frames.json", doc_.dump()); }
  void ExpectManifestError(std::initializer_list<std::string> fragments) {
    ExpectInputError([&] { ReadFrameDirectoryManifest(dir_.path()); }, fragments);
  }
  void ExpectFrameError(size_t i, std::initializer_list<std::string> fragments) {
    const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir_.path());
    ExpectInputError([&] { LoadFrame(dir_.path(), manifest, i); }, fragments);
  }
  ScratchDir dir_{"frames"};
  json doc_;
};

TEST_F(BadFrameDirectory, MissingManifest) {
  fs::remove(dir_ / "frames.json");
  ExpectManifestError({"frames.json", "not found"});
}

TEST_F(BadFrameDirectory, MalformedJson) {
  testing::WriteText(dir_ / "frames.json", "{\"format\": \"romunect-frames\", \"version\": 1,, }");
  ExpectManifestError({"frames.json", "malformed JSON"});
}

TEST_F(BadFrameDirectory, TruncatedJson) {
  const std::string text = testing::ReadText(dir_ / "frames.json");
  testing::WriteText(dir_ / "frames.json", text.substr(0, text.size() / 2));
  ExpectManifestError({"frames.json", "malformed JSON"});
}

// A number beyond a double (1e999) is bad input naming the file, not an internal error.
TEST_F(BadFrameDirectory, NumberOutOfRange) {
  std::string text = testing::ReadText(dir_ / "frames.json");
  const size_t fx = text.find("\"fx\"");
  ASSERT_NE(fx, std::string::npos);
  const size_t value = text.find_first_of("-0123456789", fx);
  text.replace(value, text.find_first_of(",}\n", value) - value, "1e999");
  testing::WriteText(dir_ / "frames.json", text);
  ExpectManifestError({"frames.json", "malformed JSON", "number overflow"});
}

TEST_F(BadFrameDirectory, ManifestThatIsAFolder) {
  fs::remove(dir_ / "frames.json");
  fs::create_directory(dir_ / "frames.json");
  ExpectManifestError({"frames.json", "is a folder, not a JSON file"});
}

TEST_F(BadFrameDirectory, UnknownFormatVersion) {
  doc_["version"] = 2;
  Rewrite();
  ExpectManifestError({"frames.json", "version", "unknown format version 2"});
}

TEST_F(BadFrameDirectory, WrongFormatName) {
  doc_["format"] = "something-else";
  Rewrite();
  ExpectManifestError({"frames.json", "format", "romunect-frames"});
}

TEST_F(BadFrameDirectory, MissingCameraField) {
  doc_["camera"].erase("fx");
  Rewrite();
  ExpectManifestError({"frames.json", "camera.fx", "missing"});
}

TEST_F(BadFrameDirectory, NegativeFocalLength) {
  doc_["camera"]["fx"] = -300.0;
  Rewrite();
  ExpectManifestError({"frames.json", "camera", "focal"});
}

TEST_F(BadFrameDirectory, NonRigidPose) {
  doc_["frames"][1]["T_W_C"][0] = 3.0;  // scales the rotation
  Rewrite();
  ExpectManifestError({"frames.json", "frames[1].T_W_C", "not a rigid transform"});
}

TEST_F(BadFrameDirectory, RegionOfWrongLengthNonNumericOrInverted) {
  doc_["region_W"] = json::array({0, 0, 0, 1, 1});
  Rewrite();
  ExpectManifestError({"frames.json", "region_W", "6 numbers"});
  doc_["region_W"] = json::array({0, 0, 0, 1, "a", 1});
  Rewrite();
  ExpectManifestError({"frames.json", "region_W"});
  doc_["region_W"] = json::array({0, 0.05, 0, 1, 0.01, 1});
  Rewrite();
  ExpectManifestError({"frames.json", "region_W", "y range [0.05, 0.01] is empty or inverted"});
}

TEST_F(BadFrameDirectory, PoseOfWrongLength) {
  doc_["frames"][0]["T_B_H"] = json::array({1, 0, 0});
  Rewrite();
  ExpectManifestError({"frames.json", "frames[0].T_B_H", "16 numbers"});
}

TEST_F(BadFrameDirectory, DepthPathEscapingTheDirectory) {
  doc_["frames"][0]["depth"] = "../elsewhere.exr";
  Rewrite();
  ExpectManifestError({"frames.json", "frames[0].depth", "inside the frame directory"});
}

TEST_F(BadFrameDirectory, DecreasingTime) {
  doc_["frames"][1]["time_s"] = -1.0;
  Rewrite();
  ExpectManifestError({"frames.json", "frames[1].time_s"});
}

TEST_F(BadFrameDirectory, MissingDepthFile) {
  fs::remove(dir_ / "depth/000001.exr");
  ExpectFrameError(1, {"depth/000001.exr", "not found"});
}

TEST_F(BadFrameDirectory, DepthOfWrongSize) {
  WriteDepthExr(dir_ / "depth/000000.exr", cv::Mat(10, 12, CV_32F, cv::Scalar(0.2)));
  ExpectFrameError(0, {"depth/000000.exr", "image size", "expected 80 x 60", "found 12 x 10"});
}

TEST_F(BadFrameDirectory, DepthOfWrongType) {
  // A PNG where an EXR is expected.
  cv::imwrite((dir_ / "depth/not_exr.png").string(), cv::Mat(60, 80, CV_16U, cv::Scalar(200)));
  doc_["frames"][0]["depth"] = "depth/not_exr.png";
  Rewrite();
  ExpectFrameError(0, {"depth/not_exr.png", "OpenEXR"});
}

// An unknown key nested 80,000 levels deep overflowed the stack in the copy of unknown keys.
TEST_F(BadFrameDirectory, UnknownKeyNestedTooDeep) {
  std::string text = testing::ReadText(dir_ / "frames.json");
  const std::string deep = std::string(80000, '[') + std::string(80000, ']');
  text.insert(text.find('{') + 1, "\"deep\": " + deep + ",");
  testing::WriteText(dir_ / "frames.json", text);
  ExpectManifestError({"frames.json", "nests arrays and objects deeper than 64"});
}

// A FIFO named as an image is refused at once; opening it to read used to wait for a writer.
TEST_F(BadFrameDirectory, ImageThatIsAFifo) {
  fs::remove(dir_ / "ir/000000.png");
  ASSERT_EQ(mkfifo((dir_ / "ir/000000.png").c_str(), 0600), 0);
  ExpectFrameError(0, {"ir/000000.png", "not a regular file"});
}

// Paths may not leave the directory: a symbolic link out of it was followed.
TEST_F(BadFrameDirectory, SymlinkOutOfTheDirectory) {
  ScratchDir elsewhere("frames_elsewhere");
  fs::rename(dir_ / "depth/000000.exr", elsewhere / "000000.exr");
  fs::create_symlink(elsewhere / "000000.exr", dir_ / "depth/000000.exr");
  ExpectFrameError(0, {"depth/000000.exr", "leads out of the frame directory through a symbolic link"});
  // A link that stays inside is followed.
  fs::remove(dir_ / "depth/000000.exr");
  fs::create_symlink("000001.exr", dir_ / "depth/000000.exr");
  const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir_.path());
  EXPECT_NO_THROW(LoadFrame(dir_.path(), manifest, 0));
}

// "\u0000" in a path was cut at the NUL; 2^64 - 1 as an index read as "index -1".
TEST_F(BadFrameDirectory, NulInAPathAndAnIndexBeyondInt) {
  std::string text = testing::ReadText(dir_ / "frames.json");
  const std::string depth = "\"depth/000000.exr\"";
  ASSERT_NE(text.find(depth), std::string::npos);
  testing::WriteText(dir_ / "frames.json",
                     std::string(text).replace(text.find(depth), depth.size(), "\"depth/000000.exr\\u0000.txt\""));
  ExpectManifestError({"frames.json", "frames[0].depth", "NUL character"});
  doc_["frames"][0]["index"] = 18446744073709551615ULL;
  Rewrite();
  ExpectManifestError({"frames.json", "frames[0].index", "integer out of range: 18446744073709551615"});
}

TEST_F(BadFrameDirectory, IrOfWrongType) {
  cv::imwrite((dir_ / "ir/000000.png").string(), cv::Mat(60, 80, CV_8U, cv::Scalar(20)));
  ExpectFrameError(0, {"ir/000000.png", "16-bit"});
}

TEST_F(BadFrameDirectory, EachNonFiniteOrNegativeDepth) {
  for (float bad : {std::numeric_limits<float>::quiet_NaN(), std::numeric_limits<float>::infinity(), -0.2f}) {
    cv::Mat depth(60, 80, CV_32F, cv::Scalar(0.2));
    depth.at<float>(7, 5) = bad;
    WriteDepthExr(dir_ / "depth/000000.exr", depth);
    ExpectFrameError(0, {"depth/000000.exr", "depth", "u=5, v=7"});
    // The skipping policy turns the pixel into "no measurement" and counts it.
    const FrameDirectoryManifest manifest = ReadFrameDirectoryManifest(dir_.path());
    size_t skipped = 0;
    const Frame f = LoadFrame(dir_.path(), manifest, 0, InvalidDepthPolicy::kSkip, &skipped);
    EXPECT_EQ(skipped, 1u);
    EXPECT_EQ(f.depth_m.at<float>(7, 5), 0.0f);
  }
}

TEST_F(BadFrameDirectory, SourceReportsBadFrameAndGoesOn) {
  fs::remove(dir_ / "depth/000000.exr");
  FrameDirectorySource source(dir_.path());
  Frame frame;
  std::string error;
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kBadFrame);
  EXPECT_NE(error.find("depth/000000.exr"), std::string::npos) << error;
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kOk);
  EXPECT_EQ(source.Next(&frame, &error), FrameStatus::kEndOfStream);
}

TEST(ImageIo, ExrFromOpenCvWithItsOneYChannelIsReadAndOthersWithoutZAreRejected) {
  ScratchDir dir("exr");
  cv::Mat m(4, 5, CV_32F, cv::Scalar(0.0));
  m.at<float>(1, 2) = 1.25f;
  m.at<float>(3, 4) = 0.5f;
  ASSERT_TRUE(cv::imwrite((dir / "y.exr").string(), m));  // OpenCV names its channel Y
  EXPECT_TRUE(testing::ImagesBitEqual(ReadDepthExr(dir / "y.exr", cv::Size(5, 4)), m));
  // Several channels and none of them Y or Z: which one is depth is unknown.
  cv::Mat colour(4, 4, CV_32FC3, cv::Scalar(1.0, 2.0, 3.0));
  ASSERT_TRUE(cv::imwrite((dir / "bgr.exr").string(), colour));
  ExpectInputError([&] { ReadDepthExr(dir / "bgr.exr"); }, {"bgr.exr", "channel Y", "missing", "channel Z"});
  // Half floats lose depth resolution (11 bits of mantissa): refused, naming the channel.
  ASSERT_TRUE(cv::imwrite((dir / "half.exr").string(), m, {cv::IMWRITE_EXR_TYPE, cv::IMWRITE_EXR_TYPE_HALF}));
  ExpectInputError([&] { ReadDepthExr(dir / "half.exr"); }, {"half.exr", "channel Y", "float32"});
}

TEST(ImageIo, AtomicWriteLeavesNothingBehindOnFailure) {
  ScratchDir dir("atomic");
  testing::WriteText(dir / "keep.txt", "old");
  EXPECT_THROW(WriteAtomically(dir / "keep.txt",
                               [](const fs::path& tmp) {
                                 testing::WriteText(tmp, "half");
                                 throw InputError("x", "", "fail");
                               }),
               InputError);
  EXPECT_EQ(testing::ReadText(dir / "keep.txt"), "old");
  EXPECT_EQ(std::distance(fs::directory_iterator(dir.path()), fs::directory_iterator()), 1);
}

}  // namespace
}  // namespace romunect
