// PNG files of the dataset, encoded here for speed: one fixed row filter and one zlib strategy
// per kind of image instead of libpng's per-row filter search, which took a third of an image's
// CPU. Standard 8- and 16-bit grayscale PNGs that every reader opens.
#pragma once

#include <filesystem>

#include <opencv2/core.hpp>

namespace romunect::jobs::dataset {

enum class PngKind {
  kMask,   // CV_8U, 0 or 255: runs of equal bytes (zlib's run-length strategy)
  kDepth,  // CV_16U, smooth (depth, raw codes): the Sub filter leaves runs of small differences
  kNoisy,  // CV_16U, sensor noise (IR): the Sub filter, then Huffman coding only (no matches)
};

// Writes `image` to `path` through a temporary name and a rename.
void WritePng(const std::filesystem::path& path, const cv::Mat& image, PngKind kind);

}  // namespace romunect::jobs::dataset
