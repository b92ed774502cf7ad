#include "romunect/fusion/outputs.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <limits>

#include <nlohmann/json.hpp>
#include <opencv2/imgproc.hpp>

#include "romunect/sensor/check.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/image_io.h"

namespace romunect::fusion {
namespace {

std::string Format(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

void Text(cv::Mat& image, const std::string& text, cv::Point at, double scale = 0.45) {
  cv::putText(image, text, at, cv::FONT_HERSHEY_SIMPLEX, scale, cv::Scalar(0, 0, 0), 1, cv::LINE_AA);
}

}  // namespace

namespace {

bool HasValue(float v, bool zero_is_empty) { return std::isfinite(v) && !(zero_is_empty && v == 0.0f); }

}  // namespace

cv::Mat ColourMapped(const cv::Mat& values, double lo, double hi, bool flip_rows, bool zero_is_empty,
                     const cv::Vec3b& empty_bgr) {
  ROMUNECT_CHECK(values.type() == CV_32FC1 && hi > lo);
  cv::Mat levels(values.size(), CV_8UC1), empty(values.size(), CV_8UC1);
  for (int r = 0; r < values.rows; ++r) {
    const int src = flip_rows ? values.rows - 1 - r : r;
    for (int c = 0; c < values.cols; ++c) {
      const float v = values.at<float>(src, c);
      const bool valued = HasValue(v, zero_is_empty);
      empty.at<uint8_t>(r, c) = valued ? 0 : 255;
      levels.at<uint8_t>(r, c) = valued ? cv::saturate_cast<uint8_t>(255.0 * (v - lo) / (hi - lo)) : 0;
    }
  }
  cv::Mat coloured;
  cv::applyColorMap(levels, coloured, cv::COLORMAP_TURBO);
  coloured.setTo(cv::Scalar(empty_bgr[0], empty_bgr[1], empty_bgr[2]), empty);
  return coloured;
}

void ValueRange(const cv::Mat& values, bool zero_is_empty, double* lo, double* hi) {
  ROMUNECT_CHECK(values.type() == CV_32FC1 && lo != nullptr && hi != nullptr);
  *lo = std::numeric_limits<double>::infinity();
  *hi = -*lo;
  for (int r = 0; r < values.rows; ++r) {
    for (int c = 0; c < values.cols; ++c) {
      const float v = values.at<float>(r, c);
      if (!HasValue(v, zero_is_empty)) continue;
      *lo = std::min<double>(*lo, v);
      *hi = std::max<double>(*hi, v);
    }
  }
  if (!(*lo <= *hi)) *lo = *hi = 0.0;
  if (*hi - *lo < 1e-6) *hi = *lo + 1e-6;
}

void WriteHeightMapPicture(const std::filesystem::path& path, const cv::Mat& height_m,
                           const HeightMapGeometry& geometry) {
  WritePicture(path, HeightMapPicture(height_m, geometry));
}

cv::Mat HeightMapPicture(const cv::Mat& height_m, const HeightMapGeometry& geometry) {
  ROMUNECT_CHECK(height_m.type() == CV_32FC1 && !height_m.empty());
  double lo, hi;
  ValueRange(height_m, /*zero_is_empty=*/false, &lo, &hi);
  const bool any = cv::countNonZero(height_m == height_m) > 0;  // NaN != NaN

  // Colour-mapped cells, +y up in the picture (row 0 of the map at the bottom); empty cells
  // marked (255, 0, 255, no turbo colour) and drawn as a checkerboard.
  const cv::Vec3b kEmpty(255, 0, 255);
  const int scale = std::clamp(1200 / std::max(1, height_m.cols), 1, 8);
  cv::Mat big;
  cv::resize(ColourMapped(height_m, lo, hi, /*flip_rows=*/true, /*zero_is_empty=*/false, kEmpty), big, cv::Size(),
             scale, scale, cv::INTER_NEAREST);
  for (int r = 0; r < big.rows; ++r) {
    for (int c = 0; c < big.cols; ++c) {
      if (big.at<cv::Vec3b>(r, c) != kEmpty) continue;
      const uint8_t g = ((r / 6 + c / 6) % 2) ? 235 : 175;  // checkerboard: "no value"
      big.at<cv::Vec3b>(r, c) = cv::Vec3b(g, g, g);
    }
  }

  const int top = 34, left = 10, right = 110, bottom = 40;
  cv::Mat canvas(big.rows + top + bottom, big.cols + left + right, CV_8UC3, cv::Scalar(255, 255, 255));
  big.copyTo(canvas(cv::Rect(left, top, big.cols, big.rows)));
  Text(canvas,
       "fused height map, " + Format("%.3g", geometry.voxel_m * 1e3) + " mm cells, x right, y up, " +
           Format("%.1f", 100.0 * Completeness(height_m)) + " % complete",
       cv::Point(left, 22));
  // Scale bar: world z in mm.
  const int bar_x = left + big.cols + 15, bar_w = 20, bar_h = std::max(60, big.rows - 40);
  for (int i = 0; i < bar_h; ++i) {
    cv::Mat level(1, 1, CV_8UC1, cv::Scalar(255 - 255 * i / std::max(1, bar_h - 1))), colour;
    cv::applyColorMap(level, colour, cv::COLORMAP_TURBO);
    cv::line(canvas, cv::Point(bar_x, top + i), cv::Point(bar_x + bar_w, top + i),
             cv::Scalar(colour.at<cv::Vec3b>(0, 0)));
  }
  cv::rectangle(canvas, cv::Rect(bar_x, top, bar_w + 1, bar_h), cv::Scalar(0, 0, 0));
  for (int i = 0; i <= 4; ++i) {
    const double z_mm = (hi - (hi - lo) * i / 4.0) * 1e3;
    const int y = top + (bar_h - 1) * i / 4;
    cv::line(canvas, cv::Point(bar_x + bar_w, y), cv::Point(bar_x + bar_w + 4, y), cv::Scalar(0, 0, 0));
    Text(canvas, Format("%.1f", z_mm), cv::Point(bar_x + bar_w + 7, y + 5), 0.4);
  }
  Text(canvas, "z [mm]", cv::Point(bar_x - 4, top + bar_h + 16), 0.4);
  // Legend for empty cells and a 10 mm length bar.
  const int legend_y = top + big.rows + 10;
  for (int r = 0; r < 16; ++r) {
    for (int c = 0; c < 24; ++c) {
      const uint8_t g = ((r / 6 + c / 6) % 2) ? 235 : 175;
      canvas.at<cv::Vec3b>(legend_y + r, left + c) = cv::Vec3b(g, g, g);
    }
  }
  Text(canvas, any ? "no value" : "no value (map is empty)", cv::Point(left + 30, legend_y + 13), 0.4);
  const int ten_mm_px = static_cast<int>(std::lround(0.010 / geometry.voxel_m * scale));
  if (ten_mm_px > 0 && left + 200 + ten_mm_px < canvas.cols) {
    cv::line(canvas, cv::Point(left + 200, legend_y + 8), cv::Point(left + 200 + ten_mm_px, legend_y + 8),
             cv::Scalar(0, 0, 0), 3);
    Text(canvas, "10 mm", cv::Point(left + 208 + ten_mm_px, legend_y + 13), 0.4);
  }
  return canvas;
}

void WriteHeightMapPly(const std::filesystem::path& path, const cv::Mat& height_m, const HeightMapGeometry& geometry) {
  ROMUNECT_CHECK(height_m.type() == CV_32FC1);
  std::vector<float> xyz;
  for (int r = 0; r < height_m.rows; ++r) {
    for (int c = 0; c < height_m.cols; ++c) {
      const float z = height_m.at<float>(r, c);
      if (!std::isfinite(z)) continue;
      xyz.push_back(static_cast<float>(geometry.min_x_m + (c + 0.5) * geometry.voxel_m));
      xyz.push_back(static_cast<float>(geometry.min_y_m + (r + 0.5) * geometry.voxel_m));
      xyz.push_back(z);
    }
  }
  static_assert(std::endian::native == std::endian::little, "PLY is written little-endian");
  WriteAtomically(path, [&](const std::filesystem::path& tmp) {
    std::ofstream out(tmp, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\ncomment romunect fused height map, world frame, metres\n"
        << "element vertex " << xyz.size() / 3 << "\nproperty float x\nproperty float y\nproperty float z\n"
        << "end_header\n";
    out.write(reinterpret_cast<const char*>(xyz.data()), static_cast<std::streamsize>(xyz.size() * sizeof(float)));
    if (!out) throw InputError(path.string(), "", "could not write the point cloud");
  });
}

void WriteCompletenessPlot(const std::filesystem::path& path, const std::vector<double>& completeness) {
  const int w = 640, h = 400, left = 60, right = 20, top = 40, bottom = 50;
  cv::Mat canvas(h, w, CV_8UC3, cv::Scalar(255, 255, 255));
  const int pw = w - left - right, ph = h - top - bottom;
  const size_t n = completeness.size();
  auto to_px = [&](size_t i, double c) {
    const double x = n > 1 ? static_cast<double>(i) / (n - 1) : 0.5;
    return cv::Point(left + static_cast<int>(std::lround(x * pw)),
                     top + ph - static_cast<int>(std::lround(std::clamp(c, 0.0, 1.0) * ph)));
  };
  for (int i = 0; i <= 10; ++i) {  // grid lines every 10 %
    const int y = top + ph - ph * i / 10;
    cv::line(canvas, cv::Point(left, y), cv::Point(left + pw, y), cv::Scalar(225, 225, 225));
    if (i % 2 == 0) Text(canvas, std::to_string(10 * i), cv::Point(left - 30, y + 5), 0.4);
  }
  cv::rectangle(canvas, cv::Rect(left, top, pw, ph), cv::Scalar(0, 0, 0));
  for (size_t i = 0; i + 1 < n; ++i) {
    cv::line(canvas, to_px(i, completeness[i]), to_px(i + 1, completeness[i + 1]), cv::Scalar(180, 90, 20), 2,
             cv::LINE_AA);
  }
  for (size_t i = 0; i < n; ++i) cv::circle(canvas, to_px(i, completeness[i]), 2, cv::Scalar(180, 90, 20), -1);
  Text(canvas, "completeness of the fused map [%] after each frame", cv::Point(left, 25), 0.5);
  Text(canvas, "1", cv::Point(left - 3, top + ph + 18), 0.4);
  if (n > 1) Text(canvas, std::to_string(n), cv::Point(left + pw - 10, top + ph + 18), 0.4);
  Text(canvas, "frames", cv::Point(left + pw / 2 - 20, top + ph + 38), 0.45);
  if (n > 0) {
    Text(canvas, Format("final %.1f %%", 100.0 * completeness.back()), cv::Point(left + pw - 130, top + ph - 10), 0.45);
  }
  WritePicture(path, canvas);
}

std::string FusionReportJson(const FusionReport& r) {
  nlohmann::ordered_json j;
  j["input"] = r.input;
  j["frames"] = r.frames;
  j["bad_frames"] = r.bad_frames;
  j["bad_frame_messages"] = r.bad_frame_messages;
  j["threads"] = r.threads;
  j["voxel_m"] = r.geometry.voxel_m;
  j["grid"] = {{"nx", r.geometry.nx}, {"ny", r.geometry.ny}, {"nz", r.geometry.nz}};
  j["box_m"] = {r.geometry.min_x_m, r.geometry.min_y_m, r.geometry.min_z_m, r.max_x_m, r.max_y_m, r.max_z_m};
  double max_ms = 0.0;
  for (double t : r.insert_ms) max_ms = std::max(max_ms, t);
  j["insert_ms"] = {{"median", Quantile(r.insert_ms, 0.5)}, {"p90", Quantile(r.insert_ms, 0.9)}, {"max", max_ms}};
  j["extract_ms"] = r.extract_ms;
  j["peak_rss_mb"] = r.peak_rss_mb;
  j["grid_mb"] = r.grid_mb;
  j["completeness"] = r.completeness;
  j["completeness_per_frame"] = r.completeness_per_frame;
  j["skipped_pixels"] = r.skipped_pixels;
  j["pixels"] = {{"total", r.stats.pixels},
                 {"no_measurement", r.stats.no_measurement},
                 {"invalid_depth", r.stats.invalid_depth},
                 {"rays", r.stats.rays},
                 {"rays_missing_box", r.stats.rays_missing_box},
                 {"points_outside_box", r.stats.points_outside_box},
                 {"hits", r.stats.hits},
                 {"misses", r.stats.misses}};
  if (r.metrics) {
    j["rmse_mm"] = r.metrics->rmse_mm;
    j["mae_mm"] = r.metrics->mae_mm;
    j["within_1mm"] = r.metrics->within_1mm;
    j["compared_cells"] = r.metrics->compared_cells;
  }
  return j.dump(2);
}

void WriteFusionReport(const std::filesystem::path& path, const FusionReport& report) {
  WriteTextAtomically(path, FusionReportJson(report) + "\n");
}

}  // namespace romunect::fusion
