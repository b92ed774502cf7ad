// Board pictures from outside (calibrate intrinsics --images): any format OpenCV reads, with
// their size checked from the header before anything is decoded (docs/design.md, "Errors and
// validation").
#pragma once

#include <filesystem>

#include <opencv2/core.hpp>

namespace romunect {

// Reads a picture of any format OpenCV reads (PNG, JPEG, BMP, TIFF: calibration board views) as
// stored (IMREAD_UNCHANGED), or an empty Mat when OpenCV cannot decode it. A regular file only; for
// PNG, JPEG and BMP the size is read from the header and checked against input_limits.h's bounds
// before decoding (InputError "image size").
cv::Mat ReadPicture(const std::filesystem::path& path);

}  // namespace romunect
