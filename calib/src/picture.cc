#include "romunect/calib/picture.h"

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/input_limits.h"

namespace romunect {
namespace fs = std::filesystem;
namespace {

uint32_t Be32(std::string_view b, size_t at) {
  uint32_t v = 0;
  for (int i = 0; i < 4; ++i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}

uint32_t Le32(std::string_view b, size_t at) {
  uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8) | static_cast<unsigned char>(b[at + i]);
  return v;
}

uint32_t Be16(std::string_view b, size_t at) {
  return static_cast<uint32_t>(static_cast<unsigned char>(b[at])) << 8 | static_cast<unsigned char>(b[at + 1]);
}

// The size a PNG, JPEG (its first SOFn frame header) or BMP header gives, or nullopt for other
// formats and headers not found.
std::optional<cv::Size2l> PictureHeaderSize(std::string_view b) {
  if (b.size() >= 24 && b.compare(0, 8, "\x89PNG\r\n\x1a\n") == 0) {
    return cv::Size2l(static_cast<int64_t>(Be32(b, 16)), static_cast<int64_t>(Be32(b, 20)));
  }
  if (b.size() >= 26 && b.compare(0, 2, "BM") == 0) {
    const int64_t width = static_cast<int32_t>(Le32(b, 18));
    const int64_t height = static_cast<int32_t>(Le32(b, 22));  // negative: rows stored top-down
    return cv::Size2l(width, height < 0 ? -height : height);
  }
  if (b.size() >= 4 && b.compare(0, 2, "\xff\xd8") == 0) {
    for (size_t at = 2; at + 9 <= b.size();) {
      if (static_cast<unsigned char>(b[at]) != 0xff) return std::nullopt;
      const unsigned marker = static_cast<unsigned char>(b[at + 1]);
      if (marker == 0xff) {  // a fill byte
        ++at;
        continue;
      }
      if (marker >= 0xc0 && marker <= 0xcf && marker != 0xc4 && marker != 0xc8 && marker != 0xcc) {
        return cv::Size2l(Be16(b, at + 7), Be16(b, at + 5));  // SOFn: length, precision, height, width
      }
      at += 2 + Be16(b, at + 2);
    }
  }
  return std::nullopt;
}

}  // namespace

cv::Mat ReadPicture(const fs::path& path) {
  const std::string bytes = ReadInputFile(path, kMaxImageFileBytes, "picture");
  if (const std::optional<cv::Size2l> size = PictureHeaderSize(bytes)) {
    CheckImageDimensions(size->width, size->height, path.string());
  }
  if (bytes.empty()) return cv::Mat();
  try {
    const cv::Mat buffer(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data()));
    return cv::imdecode(buffer, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception&) {
    return cv::Mat();
  }
}

}  // namespace romunect
