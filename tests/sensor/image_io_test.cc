#include "romunect/sensor/image_io.h"

#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <limits>
#include <random>
#include <string>

#include <signal.h>
#include <sys/resource.h>
#include <unistd.h>

#include <gtest/gtest.h>
#include <opencv2/imgcodecs.hpp>

#include "romunect/testing/test_support.h"

namespace romunect {
namespace {

using testing::ImagesBitEqual;
using testing::ScratchDir;

std::string FileBytes(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

cv::Mat RandomU16(int rows, int cols, uint32_t seed) {
  cv::Mat image(rows, cols, CV_16U);
  std::mt19937 rng(seed);
  for (auto it = image.begin<uint16_t>(); it != image.end<uint16_t>(); ++it) *it = static_cast<uint16_t>(rng());
  image.at<uint16_t>(0, 0) = 0;
  image.at<uint16_t>(rows - 1, cols - 1) = 65535;
  return image;
}

// Depth with every value the format must carry bit for bit: 0 (no measurement), NaN, +-inf,
// negative, subnormal, and ordinary metres.
cv::Mat SpecialDepth(int rows, int cols, uint32_t seed) {
  cv::Mat depth(rows, cols, CV_32F);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> metres(0.15f, 0.45f);
  for (auto it = depth.begin<float>(); it != depth.end<float>(); ++it) *it = metres(rng);
  const float specials[] = {0.0f,
                            -0.0f,
                            std::numeric_limits<float>::quiet_NaN(),
                            std::numeric_limits<float>::infinity(),
                            -std::numeric_limits<float>::infinity(),
                            -0.2f,
                            std::numeric_limits<float>::denorm_min(),
                            std::numeric_limits<float>::max()};
  for (size_t i = 0; i < std::size(specials); ++i)
    depth.at<float>(static_cast<int>(i % rows), static_cast<int>(i)) = specials[i];
  return depth;
}

// The fast (uncompressed) PNG writer: OpenCV and our reader decode it to the same pixels as the
// compressed one, at a size that needs several stored deflate blocks (640 x 480: 615 kB) and at
// odd sizes (a single short block).
TEST(ImageIoTest, FastPngDecodesToTheSamePixels) {
  ScratchDir dir("image_io_png");
  for (const cv::Size size : {cv::Size(640, 480), cv::Size(37, 23), cv::Size(1, 1)}) {
    SCOPED_TRACE(std::to_string(size.width) + " x " + std::to_string(size.height));
    const cv::Mat image = RandomU16(size.height, size.width, 3);
    WritePng16(dir / "fast.png", image, ImageCompression::kFast);
    WritePng16(dir / "compact.png", image, ImageCompression::kCompact);
    EXPECT_TRUE(ImagesBitEqual(ReadPng16(dir / "fast.png"), image));
    EXPECT_TRUE(ImagesBitEqual(cv::imread((dir / "fast.png").string(), cv::IMREAD_UNCHANGED), image));
    EXPECT_TRUE(ImagesBitEqual(ReadPng16(dir / "compact.png"), image));
    // Uncompressed: 2 bytes per pixel plus a filter byte per row, plus fixed overhead.
    const size_t payload = static_cast<size_t>(size.height) * (1 + 2 * size.width);
    EXPECT_GE(std::filesystem::file_size(dir / "fast.png"), payload);
    EXPECT_LE(std::filesystem::file_size(dir / "fast.png"), payload + 5 * (payload / 65535 + 1) + 64);
  }
}

// The fast (uncompressed) EXR writer: OpenEXR reads back every float bit for bit, NaN and
// infinities included, as it does the compressed file.
TEST(ImageIoTest, FastExrReadsBackBitForBit) {
  ScratchDir dir("image_io_exr");
  for (const cv::Size size : {cv::Size(640, 480), cv::Size(13, 7)}) {
    SCOPED_TRACE(std::to_string(size.width) + " x " + std::to_string(size.height));
    const cv::Mat depth = SpecialDepth(size.height, size.width, 5);
    WriteDepthExr(dir / "fast.exr", depth, ImageCompression::kFast);
    WriteDepthExr(dir / "compact.exr", depth, ImageCompression::kCompact);
    EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(dir / "fast.exr"), depth));
    EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(dir / "compact.exr"), depth));
    EXPECT_GE(std::filesystem::file_size(dir / "fast.exr"), 4u * size.area());
  }
}

// OpenCV reads the depth files as romunect writes them, fast or compressed, to the same floats:
// its EXR decoder takes the channels R, G, B, A and Y, and reads a file with a channel "Z" alone
// as zeros, without an error.
TEST(ImageIoTest, OpenCvReadsTheDepthFiles) {
  setenv("OPENCV_IO_ENABLE_OPENEXR", "1", 1);  // OpenCV reads the switch at its first EXR file
  ScratchDir dir("image_io_exr_opencv");
  cv::Mat depth(48, 64, CV_32F);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> metres(0.15f, 0.45f);
  for (auto it = depth.begin<float>(); it != depth.end<float>(); ++it) *it = metres(rng);
  depth.at<float>(0, 0) = 0.0f;  // no measurement
  for (const ImageCompression compression : {ImageCompression::kFast, ImageCompression::kCompact}) {
    WriteDepthExr(dir / "depth.exr", depth, compression);
    const cv::Mat read = cv::imread((dir / "depth.exr").string(), cv::IMREAD_UNCHANGED);
    ASSERT_EQ(read.type(), CV_32FC1);
    EXPECT_TRUE(ImagesBitEqual(read, depth));
  }
}

// The fast files go out with direct I/O where the filesystem takes it and with plain writes
// where it refuses (tmpfs does): both read back the same.
TEST(ImageIoTest, FastFilesOnAFilesystemWithoutDirectIo) {
  const std::filesystem::path shm = "/dev/shm";
  if (!std::filesystem::is_directory(shm) || access(shm.c_str(), W_OK) != 0) GTEST_SKIP() << "no /dev/shm";
  const std::filesystem::path dir = shm / ("romunect_image_io_" + std::to_string(getpid()));
  std::filesystem::create_directories(dir);
  const cv::Mat image = RandomU16(37, 23, 4);
  const cv::Mat depth = SpecialDepth(37, 23, 4);
  WritePng16(dir / "a.png", image, ImageCompression::kFast);
  WriteDepthExr(dir / "a.exr", depth, ImageCompression::kFast);
  EXPECT_TRUE(ImagesBitEqual(ReadPng16(dir / "a.png"), image));
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(dir / "a.exr"), depth));
  std::filesystem::remove_all(dir);
}

// Same image, same bytes, and nothing left beside the file.
TEST(ImageIoTest, FastWritersAreDeterministicAndAtomic) {
  ScratchDir dir("image_io_same");
  const cv::Mat image = RandomU16(48, 64, 9);
  const cv::Mat depth = SpecialDepth(48, 64, 9);
  WritePng16(dir / "a.png", image, ImageCompression::kFast);
  WritePng16(dir / "b.png", image, ImageCompression::kFast);
  WriteDepthExr(dir / "a.exr", depth, ImageCompression::kFast);
  WriteDepthExr(dir / "b.exr", depth, ImageCompression::kFast);
  EXPECT_EQ(FileBytes(dir / "a.png"), FileBytes(dir / "b.png"));
  EXPECT_EQ(FileBytes(dir / "a.exr"), FileBytes(dir / "b.exr"));
  size_t files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    ++files;
    EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos) << entry.path();
  }
  EXPECT_EQ(files, 4u);
}

// A write that fails says why ("cannot write file" alone used to), and leaves no file behind. A
// file-size limit stands in for a full disk.
TEST(ImageIo, WriteErrorsSayWhyAndLeaveNothing) {
  ScratchDir dir("write_errors");
  rlimit saved{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &saved), 0);
  const auto previous = signal(SIGXFSZ, SIG_IGN);  // the write fails with EFBIG instead
  rlimit small = saved;
  small.rlim_cur = 1000;
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  std::string error;
  try {
    WriteTextAtomically(dir / "big.txt", std::string(5000, 'x'));
  } catch (const InputError& e) {
    error = e.what();
  }
  setrlimit(RLIMIT_FSIZE, &saved);
  signal(SIGXFSZ, previous);
  EXPECT_NE(error.find("big.txt: cannot write file: File too large"), std::string::npos) << error;
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

}  // namespace
}  // namespace romunect
