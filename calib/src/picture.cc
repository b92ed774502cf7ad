#include "romunect/calib/picture.h"

#include <string>

#include <opencv2/imgcodecs.hpp>

#include "romunect/sensor/image_io.h"
#include "romunect/sensor/input_limits.h"

namespace romunect {
namespace fs = std::filesystem;

cv::Mat ReadPicture(const fs::path& path) {
  const std::string bytes = ReadInputFile(path, kMaxImageFileBytes, "picture");
  CheckPictureHeader(bytes, path.string());
  if (bytes.empty()) return cv::Mat();
  try {
    const cv::Mat buffer(1, static_cast<int>(bytes.size()), CV_8U, const_cast<char*>(bytes.data()));
    return cv::imdecode(buffer, cv::IMREAD_UNCHANGED);
  } catch (const cv::Exception&) {
    return cv::Mat();
  }
}

}  // namespace romunect
