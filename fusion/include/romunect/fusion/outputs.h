// Output files of a fusion run, shared by `romunect fuse` and `romunect scan`: the height map as
// EXR, a picture of it, a point cloud, a completeness plot and the report. Height maps follow
// voting_grid.h (CV_32F, world z in metres, NaN = empty, row 0 = smallest y). Every file is
// written atomically (image_io.h).
#pragma once

#include <cstddef>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <opencv2/core.hpp>

#include "romunect/fusion/frame_inserter.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/voting_grid.h"

namespace romunect::fusion {

// The one colour map of our pictures: values (CV_32F) over [lo, hi] to turbo (low = blue,
// high = red), CV_8UC3 BGR. Cells without a value (non-finite; also 0 with zero_is_empty, as
// in depth maps) get `empty_bgr`. flip_rows puts row 0 at the bottom (height maps: +y up).
cv::Mat ColourMapped(const cv::Mat& values, double lo, double hi, bool flip_rows, bool zero_is_empty,
                     const cv::Vec3b& empty_bgr);
// The range of a map's values (as ColourMapped counts them), widened to at least 1 um; 0, 0
// (then 0, 1e-6) when none.
void ValueRange(const cv::Mat& values, bool zero_is_empty, double* lo, double* hi);

// A colour-mapped picture (ColourMapped) drawn with +y up, empty cells in a grey
// checkerboard, a scale bar in millimetres of world z and a caption.
cv::Mat HeightMapPicture(const cv::Mat& height_m, const HeightMapGeometry& geometry);
void WriteHeightMapPicture(const std::filesystem::path& path, const cv::Mat& height_m,
                           const HeightMapGeometry& geometry);

// One vertex (x, y, z in W, metres, float32) per valued cell, binary little-endian PLY (MeshLab,
// CloudCompare and Open3D read it).
void WriteHeightMapPly(const std::filesystem::path& path, const cv::Mat& height_m, const HeightMapGeometry& geometry);

// Completeness (%) over frames, as a line plot PNG.
void WriteCompletenessPlot(const std::filesystem::path& path, const std::vector<double>& completeness);

// Everything report.json holds.
struct FusionReport {
  std::string input;      // what was fused (a directory, "simulation")
  size_t frames = 0;      // frames inserted
  size_t bad_frames = 0;  // frames skipped (unreadable or unusable)
  std::vector<std::string> bad_frame_messages;
  int threads = 1;
  HeightMapGeometry geometry;
  double max_x_m = 0.0, max_y_m = 0.0, max_z_m = 0.0;  // the box's maximum as given
  std::vector<double> insert_ms;                       // per frame (CPU wall time of Insert)
  double extract_ms = 0.0;                             // final extraction
  double peak_rss_mb = 0.0;
  double grid_mb = 0.0;
  size_t skipped_pixels = 0;  // NaN/inf/negative pixels set to "none" while loading
  InsertStats stats;
  std::vector<double> completeness_per_frame;
  double completeness = 0.0;
  std::optional<HeightMapMetrics> metrics;  // with ground truth
};

// The report as JSON text (an object; `romunect scan` may embed it).
std::string FusionReportJson(const FusionReport& report);
void WriteFusionReport(const std::filesystem::path& path, const FusionReport& report);

}  // namespace romunect::fusion
