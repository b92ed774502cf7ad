// Image files of romunect: metric depth as single-channel float32 OpenEXR (channel "Y", the
// name OpenCV gives a single-channel image, so cv2.imread reads it; metres), IR and device raw
// depth as 16-bit PNG. Every writer writes a temporary file in the same folder and renames it,
// so no half-written file is ever left under the final name.
// Readers throw InputError naming the file and what was expected.
//
// Writers compress (kCompact: PNG through OpenCV at zlib level 1, EXR ZIP at level 1) or not
// (kFast: our own stored-deflate PNG and uncompressed scanline EXR, standard files that any
// reader opens). Compressing a 640 x 480 frame's four images takes ~50 ms of CPU, more than a
// 30 Hz frame's budget, and no deflate runs at the ~1 GB/s it would need; kFast takes ~2 ms for
// files 2-5 times larger.
#pragma once

#include <filesystem>
#include <functional>
#include <optional>
#include <string>
#include <string_view>

#include <opencv2/core.hpp>

#include "romunect/sensor/height_map.h"

namespace romunect {

enum class ImageCompression { kCompact, kFast };

// Readers open regular files only, read the image size from the header (PNG IHDR, EXR dataWindow)
// and refuse it before decoding when it is outside input_limits.h's bounds or, when `expected` is
// given, not that size ("image size": "expected W x H, found w x h"). The Decode* forms read
// bytes in memory; `source` names them in errors.

// Reads a float EXR's depth into a CV_32F Mat: the channel "Z" (depth renderers' name for it), or
// the one channel "Y" (what romunect and OpenCV's imwrite write for a single-channel float image).
cv::Mat ReadDepthExr(const std::filesystem::path& path, const std::optional<cv::Size>& expected = std::nullopt);
cv::Mat DecodeDepthExr(std::string_view bytes, const std::string& source,
                       const std::optional<cv::Size>& expected = std::nullopt);
// Writes a CV_32F Mat as a float32 EXR with one channel "Y" (NaN and 0 are written as is).
void WriteDepthExr(const std::filesystem::path& path, const cv::Mat& depth,
                   ImageCompression compression = ImageCompression::kCompact);

// Height maps (height_map.h) as EXR: WriteDepthExr's file plus where its cells lie, as header
// attributes "romunect.min_W" (v3d: the box's minimum corner, m) and "romunect.voxel_m" (double),
// so that a reader can tell two maps of the same size over different boxes apart.
void WriteHeightMapExr(const std::filesystem::path& path, const cv::Mat& height_m, const HeightMapGeometry& geometry);
// The geometry a height map's EXR records (nx, ny: its size; nz: 0), or nullopt for
// an EXR without it (written by other tools). Throws InputError for an unreadable file.
std::optional<HeightMapGeometry> ReadHeightMapGeometry(const std::filesystem::path& path);

// Reads a 16-bit single-channel PNG into a CV_16U Mat.
cv::Mat ReadPng16(const std::filesystem::path& path, const std::optional<cv::Size>& expected = std::nullopt);
cv::Mat DecodePng16(std::string_view bytes, const std::string& source,
                    const std::optional<cv::Size>& expected = std::nullopt);
// Reads an 8-bit RGB PNG (an RGBA one loses its alpha) into a CV_8UC3 Mat in R, G, B order (a
// colour image, frame.h), not OpenCV's usual B, G, R.
cv::Mat ReadPngRgb8(const std::filesystem::path& path, const std::optional<cv::Size>& expected = std::nullopt);
cv::Mat DecodePngRgb8(std::string_view bytes, const std::string& source,
                      const std::optional<cv::Size>& expected = std::nullopt);
// For a PNG, JPEG (its first frame header) or BMP file's bytes, the size its header gives checked
// against input_limits.h's bounds (InputError "image size"), before anything decodes it; other
// formats pass unchecked.
void CheckPictureHeader(std::string_view bytes, const std::string& source);

// Writes a CV_16U Mat as a 16-bit PNG.
void WritePng16(const std::filesystem::path& path, const cv::Mat& image,
                ImageCompression compression = ImageCompression::kCompact);
// Writes a colour image (CV_8UC3 in R, G, B order) as an 8-bit RGB PNG.
void WritePngRgb8(const std::filesystem::path& path, const cv::Mat& image);
// Writes an 8-bit picture (CV_8UC1 or CV_8UC3, BGR) as PNG, for people to look at.
void WritePicture(const std::filesystem::path& path, const cv::Mat& image);

// Calls write(tmp) with a temporary path beside `path`, then renames it to `path`. If write
// throws, the temporary is removed and the exception propagates; `path` is untouched.
void WriteAtomically(const std::filesystem::path& path,
                     const std::function<void(const std::filesystem::path& tmp)>& write);
// Writes text to a file atomically.
void WriteTextAtomically(const std::filesystem::path& path, const std::string& text);

}  // namespace romunect
