// Board pictures from outside: sizes read from the header before anything is decoded.
#include "romunect/calib/picture.h"

#include <cstdint>
#include <cstring>
#include <string>

#include <sys/stat.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect {
namespace {
namespace fs = std::filesystem;
using testing::ExpectContains;
using testing::InputErrorOf;
using testing::ScratchDir;

void PutBe32(std::string* s, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) (*s)[at + i] = static_cast<char>(v >> (8 * (3 - i)));
}

// Board pictures (calibrate intrinsics --images) of any format: PNG, JPEG and BMP sizes are read from
// the header before decoding; they were decoded whole.
TEST(ImageBomb, PictureHeadersAreCheckedBeforeDecoding) {
  ScratchDir dir("picture_bomb");
  const cv::Mat small(6, 8, CV_8UC3, cv::Scalar(10, 20, 30));
  for (const char* name : {"small.png", "small.jpg", "small.bmp"}) {
    ASSERT_TRUE(cv::imwrite((dir / name).string(), small)) << name;
    EXPECT_EQ(ReadPicture(dir / name).size(), small.size()) << name;
  }
  std::string png = testing::ReadText(dir / "small.png");
  PutBe32(&png, 16, 60000);
  PutBe32(&png, 20, 60000);
  testing::WriteText(dir / "bomb.png", png);
  // JPEG: start of image, then a baseline frame header (SOF0) claiming 60000 x 60000.
  const std::string jpeg("\xff\xd8\xff\xc0\x00\x11\x08\xea\x60\xea\x60\x03\x01\x22\x00\x02\x11\x01\x03\x11\x01", 21);
  testing::WriteText(dir / "bomb.jpg", jpeg);
  std::string bmp = testing::ReadText(dir / "small.bmp");
  const int32_t wide = 100000;
  std::memcpy(&bmp[18], &wide, 4);
  testing::WriteText(dir / "bomb.bmp", bmp);
  for (const char* name : {"bomb.png", "bomb.jpg", "bomb.bmp"}) {
    ExpectContains(InputErrorOf([&] { ReadPicture(dir / name); }), {name, "image size", "the header says"});
  }
  ASSERT_EQ(mkfifo((dir / "fifo.png").c_str(), 0600), 0);
  ExpectContains(InputErrorOf([&] { ReadPicture(dir / "fifo.png"); }), {"fifo.png", "not a regular file"});
  testing::WriteText(dir / "garbage.png", "not a picture");
  EXPECT_TRUE(ReadPicture(dir / "garbage.png").empty());
}

}  // namespace
}  // namespace romunect
