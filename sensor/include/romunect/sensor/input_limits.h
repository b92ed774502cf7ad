// Bounds on outside input, checked before a parser recurses or allocates what a file asks for
// (docs/design.md, "Errors and validation"). A hostile file (a JSON document nested 80,000 levels
// deep, a YAML key of 50,000 nested sequences, a 2 MB PNG that claims 32768 x 32768 pixels, a FIFO
// named as an image) is refused with InputError naming the file, never a crash, a hang or gigabytes.
#pragma once

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <string>
#include <string_view>

#include <opencv2/core/persistence.hpp>

namespace romunect {

// Nesting depth of the JSON documents romunect reads (rigs, frames.json, saved scenes); its own
// files nest at most 5 levels, and nlohmann::json copies and prints by recursion.
constexpr int kMaxJsonDepth = 64;
// Nesting depth of a cv::FileStorage YAML file (calibration, camera): flow brackets plus block
// indentation. OpenCV's parser recurses once per level and has no limit of its own.
constexpr int kMaxYamlDepth = 64;
// The widest indentation of a YAML line, in columns: block nesting needs one column per level.
constexpr int kMaxYamlIndent = 256;
// Size of a text input file (JSON, YAML, CSV). A calibration file with its two depth maps inline
// at 1280 x 1024 is ~40 MB.
constexpr size_t kMaxTextFileBytes = size_t{256} << 20;
// Size of an image file: the largest image read (2^24 float pixels) is 64 MB uncompressed.
constexpr size_t kMaxImageFileBytes = size_t{256} << 20;
// Image dimensions, read from the file's header before anything is decoded.
constexpr int kMaxImageSidePx = 16384;
constexpr int64_t kMaxImagePixels = int64_t{1} << 24;  // 64 MB of float32

// Reads a whole file of at most max_bytes. Only a regular file is opened (a FIFO, a device or a
// folder is refused without blocking); `what` names the kind of file in messages ("JSON file").
std::string ReadInputFile(const std::filesystem::path& path, size_t max_bytes, const std::string& what);

// Throws InputError(source) when JSON text nests arrays and objects deeper than kMaxJsonDepth;
// the message names the byte offset. Strings are skipped, so brackets in them do not count.
void CheckJsonNesting(std::string_view text, const std::string& source);

// Throws InputError(source) when YAML text nests deeper than kMaxYamlDepth flow brackets, indents
// a line more than kMaxYamlIndent columns or puts more than kMaxYamlDepth block sequence
// indicators ("- - -") on one line; the message names the line.
void CheckYamlNesting(std::string_view text, const std::string& source);

// Opens a cv::FileStorage file (YAML, or JSON or XML by extension) after ReadInputFile and the
// nesting check of its format; OpenCV then parses the bytes read, from memory.
cv::FileStorage OpenFileStorage(const std::filesystem::path& path, const std::string& what);

// Throws InputError(source, field) unless `node` is an OpenCV matrix (a map with integer rows and
// cols) of at most max_rows x max_cols: OpenCV allocates rows x cols before it reads the data.
void CheckMatrixNode(const cv::FileNode& node, int max_rows, int max_cols, const std::string& source,
                     const std::string& field);

// Throws InputError(source, "image size") unless 1 <= width, height <= kMaxImageSidePx and
// width * height <= kMaxImagePixels. Takes 64-bit sizes so that any header's values fit.
void CheckImageDimensions(int64_t width, int64_t height, const std::string& source);

}  // namespace romunect
