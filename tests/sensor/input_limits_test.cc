// Hostile inputs, generated here, against the bounds of input_limits.h: each is refused with an
// InputError naming the file before a parser recurses or allocates what the file claims.
#include "romunect/sensor/input_limits.h"

#include <cstring>
#include <string>

#include <sys/stat.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/camera_model.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using testing::ExpectContains;
using testing::InputErrorOf;
using testing::ScratchDir;

TEST(JsonNesting, DepthAtTheLimitPassesOneDeeperIsRefused) {
  const std::string at_limit = std::string(kMaxJsonDepth, '[') + std::string(kMaxJsonDepth, ']');
  EXPECT_NO_THROW(CheckJsonNesting(at_limit, "a.json"));
  const std::string deeper = "{\"a\": " + std::string(kMaxJsonDepth, '[') + std::string(kMaxJsonDepth, ']') + "}";
  ExpectContains(InputErrorOf([&] { CheckJsonNesting(deeper, "a.json"); }), {"a.json", "deeper than 64", "byte 69"});
}

TEST(JsonNesting, BracketsInStringsDoNotCount) {
  const std::string text = "{\"note\": \"" + std::string(1000, '[') + "\\\"" + std::string(1000, '{') + "\"}";
  EXPECT_NO_THROW(CheckJsonNesting(text, "a.json"));
}

// A camera file with one key of 50,000 nested sequences overflowed the stack inside cv::FileStorage.
TEST(YamlNesting, FiftyThousandNestedSequencesAreRefusedBeforeOpenCvParses) {
  ScratchDir dir("yaml_nesting");
  const std::string flow = "%YAML:1.0\nk: " + std::string(50000, '[') + std::string(50000, ']') + "\n";
  testing::WriteText(dir / "flow.yaml", flow);
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "flow.yaml"); }),
                 {"flow.yaml", "line 2", "flow collections nest deeper than 64"});
  std::string block = "%YAML:1.0\nk:\n";
  for (int i = 0; i < 50000; ++i) block += "- ";
  testing::WriteText(dir / "block.yaml", block + "1\n");
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "block.yaml"); }),
                 {"block.yaml", "line 3", "block sequences nest deeper than 64"});
  std::string indented = "%YAML:1.0\nk:\n";
  for (int i = 0; i < 300; ++i) indented += std::string(i, ' ') + "k" + std::to_string(i) + ":\n";
  testing::WriteText(dir / "indented.yaml", indented);
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "indented.yaml"); }), {"indented.yaml", "indented"});
}

TEST(YamlNesting, QuotedBracketsAndCommentsDoNotCount) {
  const std::string text = "%YAML:1.0\na: \"" + std::string(200, '[') + "\"\nb: '" + std::string(200, '{') +
                           "''x'\n# " + std::string(200, '[') + "\nc: [ [ 1, 2 ], { d: 3 } ]\n";
  EXPECT_NO_THROW(CheckYamlNesting(text, "a.yaml"));
}

// A line left of the document's first key is not YAML; OpenCV 4.6's parser looped forever on
// this 20-byte file (a fuzzer's find), so the pre-scan refuses it.
TEST(YamlNesting, ALineLeftOfTheFirstKeyIsRefusedBeforeOpenCvParses) {
  ScratchDir dir("yaml_dedent");
  testing::WriteText(dir / "dedent.yaml", "%YAML:1.\n s:1\n2, -\n1");
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "dedent.yaml"); }),
                 {"dedent.yaml", "line 3", "indented less than the document's first key (column 2)"});
  EXPECT_NO_THROW(CheckYamlNesting("%YAML:1.0\n---\n  a: 1\n  b:\n    - 2\n# note\n  c: 3\n", "a.yaml"));
}

// Content on a document marker's line starts the document right of the lines below it; OpenCV
// 4.6's parser looped forever on both files (fuzzer finds of 18 and 16 bytes).
TEST(YamlNesting, ContentOnADocumentMarkerLineIsRefusedBeforeOpenCvParses) {
  ScratchDir dir("yaml_marker");
  testing::WriteText(dir / "dashes.yaml", "%YAML:1.0\n----Y\nY\n\n");
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "dashes.yaml"); }),
                 {"dashes.yaml", "line 2", "document marker '---' alone on its line"});
  testing::WriteText(dir / "inline.yaml", "%YAML:1.0\n--- -Y\nY\n\n");
  ExpectContains(InputErrorOf([&] { CameraModel::Load(dir / "inline.yaml"); }), {"inline.yaml", "line 2"});
  EXPECT_NO_THROW(CheckYamlNesting("%YAML:1.0\n--- # first\na: 1\n...\n", "a.yaml"));
}

TEST(InputFile, OnlyRegularFilesAreRead) {
  ScratchDir dir("input_file");
  ASSERT_EQ(mkfifo((dir / "fifo").c_str(), 0600), 0);
  ExpectContains(InputErrorOf([&] { ReadInputFile(dir / "fifo", 100, "JSON file"); }), {"fifo", "not a regular file"});
  ExpectContains(InputErrorOf([&] { ReadInputFile(dir.path(), 100, "JSON file"); }), {"is a folder"});
  ExpectContains(InputErrorOf([&] { ReadInputFile(dir / "missing", 100, "JSON file"); }), {"file not found"});
  testing::WriteText(dir / "big", std::string(101, 'x'));
  ExpectContains(InputErrorOf([&] { ReadInputFile(dir / "big", 100, "JSON file"); }),
                 {"is 101 bytes", "at most 100 bytes"});
  EXPECT_EQ(ReadInputFile(dir / "big", 101, "JSON file"), std::string(101, 'x'));
}

TEST(ImageDimensions, BoundsHoldForAnyHeaderValue) {
  EXPECT_NO_THROW(CheckImageDimensions(1, 1, "x"));
  EXPECT_NO_THROW(CheckImageDimensions(kMaxImageSidePx, kMaxImagePixels / kMaxImageSidePx, "x"));
  for (const auto& [w, h] : {std::pair<int64_t, int64_t>{0, 10},
                             {10, -1},
                             {kMaxImageSidePx + 1, 1},
                             {kMaxImageSidePx, kMaxImageSidePx},
                             {4294967295LL, 4294967295LL}}) {
    ExpectContains(InputErrorOf([&] { CheckImageDimensions(w, h, "x.png"); }), {"x.png: image size"});
  }
}

void PutBe32(std::string* s, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) (*s)[at + i] = static_cast<char>(v >> (8 * (3 - i)));
}

// A PNG whose header claims 32768 x 32768 (2 GB of pixels) was decoded before its size was
// checked; it is refused from IHDR. The same file at a size other than the camera's, too.
TEST(ImageBomb, PngHeaderSizeIsCheckedBeforeDecoding) {
  ScratchDir dir("png_bomb");
  WritePng16(dir / "small.png", cv::Mat(60, 80, CV_16U, cv::Scalar(7)), ImageCompression::kFast);
  std::string bytes = testing::ReadText(dir / "small.png");
  EXPECT_EQ(DecodePng16(bytes, "small.png", cv::Size(80, 60)).at<uint16_t>(59, 79), 7);
  ExpectContains(InputErrorOf([&] { DecodePng16(bytes, "small.png", cv::Size(640, 480)); }),
                 {"small.png: image size", "expected 640 x 480, found 80 x 60"});
  PutBe32(&bytes, 16, 32768);
  PutBe32(&bytes, 20, 32768);
  testing::WriteText(dir / "bomb.png", bytes);
  ExpectContains(InputErrorOf([&] { ReadPng16(dir / "bomb.png"); }),
                 {"bomb.png: image size", "the header says 32768 x 32768"});
}

TEST(ImageBomb, ExrDataWindowIsCheckedBeforeDecoding) {
  ScratchDir dir("exr_bomb");
  for (const ImageCompression compression : {ImageCompression::kFast, ImageCompression::kCompact}) {
    WriteDepthExr(dir / "small.exr", cv::Mat(60, 80, CV_32F, cv::Scalar(0.25)), compression);
    std::string bytes = testing::ReadText(dir / "small.exr");
    EXPECT_EQ(DecodeDepthExr(bytes, "small.exr", cv::Size(80, 60)).at<float>(59, 79), 0.25f);
    ExpectContains(InputErrorOf([&] { DecodeDepthExr(bytes, "small.exr", cv::Size(640, 480)); }),
                   {"small.exr: image size", "expected 640 x 480, found 80 x 60"});
    // dataWindow: name, type "box2i", size 16, then xmin ymin xmax ymax (little-endian int32).
    const size_t window = bytes.find("dataWindow");
    ASSERT_NE(window, std::string::npos);
    const size_t value = window + std::strlen("dataWindow") + 1 + std::strlen("box2i") + 1 + 4;
    const uint32_t max = 16383;
    std::memcpy(&bytes[value + 8], &max, 4);
    std::memcpy(&bytes[value + 12], &max, 4);
    testing::WriteText(dir / "bomb.exr", bytes);
    ExpectContains(InputErrorOf([&] { ReadDepthExr(dir / "bomb.exr"); }),
                   {"bomb.exr: image size", "the header says 16384 x 16384"});
    ExpectContains(InputErrorOf([&] { DecodeDepthExr(bytes.substr(0, 20), "cut.exr"); }),
                   {"cut.exr", "not a readable OpenEXR file"});
  }
}

}  // namespace
}  // namespace romunect
