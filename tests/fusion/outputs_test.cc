#include "romunect/fusion/outputs.h"

#include <cmath>
#include <fstream>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/sensor/image_io.h"
#include "romunect/testing/test_support.h"

namespace romunect::fusion {
namespace {

using testing::ImagesBitEqual;
using testing::ScratchDir;

HeightMapGeometry SmallGeometry() {
  HeightMapGeometry g;
  g.min_x_m = -0.01;
  g.min_y_m = 0.02;
  g.min_z_m = 0.0;
  g.voxel_m = 0.001;
  g.nx = 3;
  g.ny = 2;
  g.nz = 10;
  return g;
}

cv::Mat SmallMap() {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  return (cv::Mat_<float>(2, 3) << 0.001f, nan, 0.003f, 0.004f, 0.005f, nan);
}

TEST(OutputsTest, ExrRoundTripsWithNaNForEmptyCellsAndItsGeometry) {
  ScratchDir dir("fusion_outputs_exr");
  WriteHeightMapExr(dir / "fused_depth.exr", SmallMap(), SmallGeometry());
  EXPECT_TRUE(ImagesBitEqual(ReadDepthExr(dir / "fused_depth.exr"), SmallMap()));
  const std::optional<HeightMapGeometry> g = ReadHeightMapGeometry(dir / "fused_depth.exr");
  ASSERT_TRUE(g.has_value());
  EXPECT_EQ(g->min_x_m, SmallGeometry().min_x_m);
  EXPECT_EQ(g->min_y_m, SmallGeometry().min_y_m);
  EXPECT_EQ(g->min_z_m, SmallGeometry().min_z_m);
  EXPECT_EQ(g->voxel_m, SmallGeometry().voxel_m);
  EXPECT_EQ(g->nx, 3);
  EXPECT_EQ(g->ny, 2);
  // A plain depth EXR (another tool's height map) records none.
  WriteDepthExr(dir / "plain.exr", SmallMap());
  EXPECT_FALSE(ReadHeightMapGeometry(dir / "plain.exr").has_value());
}

TEST(OutputsTest, PlyHoldsOneVertexPerValuedCellAtCellCentres) {
  ScratchDir dir("fusion_outputs_ply");
  WriteHeightMapPly(dir / "fused_points.ply", SmallMap(), SmallGeometry());
  std::ifstream in(dir / "fused_points.ply", std::ios::binary);
  std::string line, header;
  while (std::getline(in, line) && line != "end_header") header += line + "\n";
  EXPECT_NE(header.find("format binary_little_endian 1.0"), std::string::npos);
  EXPECT_NE(header.find("element vertex 4\n"), std::string::npos);
  float xyz[12];
  in.read(reinterpret_cast<char*>(xyz), sizeof(xyz));
  ASSERT_TRUE(in.good());
  // Cell (row 0, col 0): (-0.01 + 0.5 mm, 0.02 + 0.5 mm, 1 mm); last: (row 1, col 1).
  EXPECT_FLOAT_EQ(xyz[0], -0.0095f);
  EXPECT_FLOAT_EQ(xyz[1], 0.0205f);
  EXPECT_FLOAT_EQ(xyz[2], 0.001f);
  EXPECT_FLOAT_EQ(xyz[9], -0.0085f);
  EXPECT_FLOAT_EQ(xyz[10], 0.0215f);
  EXPECT_FLOAT_EQ(xyz[11], 0.005f);
  EXPECT_EQ(in.peek(), std::char_traits<char>::eof());
}

TEST(OutputsTest, PicturesAreWrittenWithScaleBarAndPlotSized) {
  ScratchDir dir("fusion_outputs_png");
  WriteHeightMapPicture(dir / "fused_depth.png", SmallMap(), SmallGeometry());
  WriteCompletenessPlot(dir / "completeness.png", {0.1, 0.4, 0.6});
  WriteHeightMapPicture(dir / "empty.png", cv::Mat(2, 3, CV_32F, cv::Scalar(NAN)), SmallGeometry());
  EXPECT_GT(std::filesystem::file_size(dir / "fused_depth.png"), 1000u);
  EXPECT_GT(std::filesystem::file_size(dir / "completeness.png"), 1000u);
  EXPECT_GT(std::filesystem::file_size(dir / "empty.png"), 1000u);
}

TEST(OutputsTest, ReportHoldsTheIssuesFields) {
  FusionReport report;
  report.frames = 3;
  report.geometry = SmallGeometry();
  report.insert_ms = {3.0, 1.0, 2.0};
  report.completeness_per_frame = {0.1, 0.4, 0.6};
  report.completeness = 0.6;
  HeightMapMetrics m;
  m.rmse_mm = 0.2;
  report.metrics = m;
  const nlohmann::json j = nlohmann::json::parse(FusionReportJson(report));
  for (const char* key : {"frames", "voxel_m", "grid", "insert_ms", "extract_ms", "peak_rss_mb", "completeness",
                          "completeness_per_frame", "rmse_mm", "mae_mm", "within_1mm"}) {
    EXPECT_TRUE(j.contains(key)) << key;
  }
  EXPECT_EQ(j["insert_ms"]["median"], 2.0);
  EXPECT_EQ(j["insert_ms"]["max"], 3.0);
  EXPECT_EQ(j["grid"]["nx"], 3);
}

}  // namespace
}  // namespace romunect::fusion
