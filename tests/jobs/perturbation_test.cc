// Injected calibration errors (--perturb): the text, the pose and camera they change, and their
// effect on a fused map against ground truth: the map's error grows with each injected error.
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/testing/analytic_bin.h"
#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/calibration_sensitivity.h"
#include "romunect/tools/jobs/fuse.h"
#include "romunect/tools/jobs/perturbation.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using ::testing::HasSubstr;
using testing::InputErrorOf;
using testing::ScratchDir;

constexpr double kDeg = M_PI / 180.0;

TEST(Perturbation, ParsesNamesAxesAndDefaults) {
  const CalibrationPerturbation p = ParsePerturbation(
      "hand_eye_deg=0.5,hand_eye_mm=2,hand_eye_mm_x=-1,focal_pct=0.1,principal_px_y=3,"
      "depth_scale_pct=1,depth_offset_mm=0.5");
  EXPECT_DOUBLE_EQ(p.hand_eye_rotation_C.x(), 0.5 * kDeg);  // about x unless an axis is given
  EXPECT_DOUBLE_EQ(p.hand_eye_translation_C.z(), 2e-3);     // along z unless an axis is given
  EXPECT_DOUBLE_EQ(p.hand_eye_translation_C.x(), -1e-3);
  EXPECT_DOUBLE_EQ(p.focal_fraction, 1e-3);
  EXPECT_DOUBLE_EQ(p.principal_px.y(), 3.0);
  EXPECT_EQ(ParsePerturbation("").Text(), "none");
  EXPECT_THAT(p.Text(), HasSubstr("hand_eye_deg_x=0.5"));
  // T_C_C' turns about the camera's x axis by the angle given
  const Pose T = p.T_C_Cp();
  EXPECT_NEAR(Eigen::AngleAxisd(T.linear()).angle(), 0.5 * kDeg, 1e-12);
  EXPECT_NEAR(std::abs(Eigen::AngleAxisd(T.linear()).axis().x()), 1.0, 1e-12);
  CameraModel camera;
  camera.fx = camera.fy = 500.0;
  EXPECT_DOUBLE_EQ(p.Apply(camera).fx, 500.5);
  cv::Mat depth(1, 2, CV_32F);
  depth.at<float>(0) = 0.2f, depth.at<float>(1) = 0.0f;
  p.ApplyToDepth(&depth);
  EXPECT_FLOAT_EQ(depth.at<float>(0), 0.2f * 1.01f + 0.0005f);
  EXPECT_EQ(depth.at<float>(1), 0.0f);  // no measurement stays none
}

TEST(Perturbation, RefusesUnknownNamesAndBadValues) {
  EXPECT_THAT(InputErrorOf([] { ParsePerturbation("hand_eye=1"); }), HasSubstr("unknown"));
  EXPECT_THAT(InputErrorOf([] { ParsePerturbation("hand_eye_deg_w=1"); }), HasSubstr("unknown"));
  EXPECT_THAT(InputErrorOf([] { ParsePerturbation("focal_pct=abc"); }), HasSubstr("NAME=VALUE"));
  EXPECT_THAT(InputErrorOf([] { ParsePerturbation("focal_pct"); }), HasSubstr("NAME=VALUE"));
}

// Re-fusing the same frames with growing injected errors: the map's MAE grows with each. The
// unperturbed map has a bias of its own (mixed pixels at the walls: 0.49 mm MAE at 160 x 120),
// which a depth offset of a few tenths of a millimetre along z partly cancels, so the z sweeps
// start at 1 mm.
TEST(Perturbation, MapErrorGrowsWithEachInjectedError) {
  ScratchDir dir("perturb_fuse");
  testing::AnalyticBinOptions bin_options;
  bin_options.width = 160, bin_options.height = 120, bin_options.frames = 12, bin_options.seed = 5;
  bin_options.noise_m = 2e-5;  // small: the injected errors, not the noise, decide the error
  const testing::AnalyticBin bin(bin_options);
  {
    FrameDirectoryWriter writer(dir / "capture", bin.camera());
    for (int i = 0; i < bin.frames(); ++i) writer.Add(bin.RenderFrame(i));
    writer.Finish();
  }
  constexpr double kVoxelM = 0.5e-3;
  fusion::GridOptions grid;
  grid.voxel_m = kVoxelM;
  const Eigen::Vector3i n = grid.Dims();
  WriteHeightMapExr(dir / "gt.exr", bin.GroundTruthHeightMap(grid.min_W, kVoxelM, n.x(), n.y()),
                    fusion::VotingGrid(grid).geometry());
  const auto mae_mm = [&](const std::string& perturb) {
    FuseOptions o;
    o.source = (dir / "capture").string();
    o.out = (dir / ("fused_" + std::to_string(std::hash<std::string>()(perturb)))).string();
    o.gt = (dir / "gt.exr").string();
    o.voxel_m = kVoxelM;
    o.perturb = perturb;
    const FuseJobSummary s = RunFuse(o);
    return s.report.metrics->mae_mm;
  };
  const double base = mae_mm("");
  const std::vector<std::pair<std::string, std::vector<double>>> sweeps = {
      {"hand_eye_deg", {0.2, 0.5, 1.0}}, {"hand_eye_mm", {1.0, 2.0, 4.0}},     {"hand_eye_mm_x", {0.3, 1.0, 3.0}},
      {"focal_pct", {0.5, 1.0, 2.0}},    {"depth_scale_pct", {0.2, 0.5, 1.0}}, {"depth_offset_mm", {1.0, 2.0, 4.0}},
      {"principal_px", {2.0, 5.0, 10.0}}};
  for (const auto& [name, values] : sweeps) {
    double previous = base;
    for (double v : values) {
      const double mae = mae_mm(name + "=" + std::to_string(v));
      EXPECT_GT(mae, previous) << name << "=" << v << " (MAE " << mae << " mm, before " << previous << " mm)";
      previous = mae;
    }
  }
}

// The experiment on a given scan folder (here an analytic bin's frames, its ground truth and voxel):
// the table, the CSV, a plot per sweep and the tolerances.
TEST(CalibrationSensitivity, ReFusesAGivenScanPerInjectedError) {
  ScratchDir dir("sensitivity");
  testing::AnalyticBinOptions bin_options;
  bin_options.width = 96, bin_options.height = 72, bin_options.frames = 6, bin_options.seed = 2;
  const testing::AnalyticBin bin(bin_options);
  const fs::path scan = dir / "scan";
  {
    FrameDirectoryWriter writer(scan / "frames", bin.camera());
    for (int i = 0; i < bin.frames(); ++i) writer.Add(bin.RenderFrame(i));
    writer.Finish();
  }
  fusion::GridOptions grid;
  grid.voxel_m = 1e-3;
  const Eigen::Vector3i n = grid.Dims();
  WriteHeightMapExr(scan / "gt_height.exr", bin.GroundTruthHeightMap(grid.min_W, grid.voxel_m, n.x(), n.y()),
                    fusion::VotingGrid(grid).geometry());
  WriteTextAtomically(scan / "report.json", R"({"options": {"voxel_m": 0.001}})");
  SensitivityOptions o;
  o.out = (dir / "out").string();
  o.scan = scan.string();
  o.sweeps = {"hand_eye_deg=1:0.5", "depth_offset_mm=2"};
  const SensitivitySummary s = RunCalibrationSensitivity(o);
  ASSERT_EQ(s.points.size(), 3u);
  EXPECT_EQ(s.points[0].value, 0.5);  // sorted
  EXPECT_EQ(s.points[0].pick, -1);    // no settled pile (scene.json) to pick from
  EXPECT_GT(s.points[1].mae_mm, s.points[0].mae_mm);
  ASSERT_EQ(s.tolerances.size(), 2u);
  EXPECT_GT(s.tolerances[0].within_1mm, 0.0);
  for (const char* file : {"sensitivity.md", "sensitivity.csv", "hand_eye_deg.svg", "depth_offset_mm.svg"}) {
    EXPECT_TRUE(fs::exists(dir / "out" / file)) << file;
  }
  EXPECT_THAT(InputErrorOf([&] {
                o.out = (dir / "out2").string();
                o.sweeps = {"hand_eye=1"};
                RunCalibrationSensitivity(o);
              }),
              HasSubstr("unknown"));
  // a scan folder whose report.json does not say its voxel is refused by file and field
  o.sweeps = {"depth_offset_mm=2"};
  for (const char* report : {"not json", R"({"options": 5})", R"({"options": {"voxel_m": "1 mm"}})"}) {
    WriteTextAtomically(scan / "report.json", report);
    o.out = (dir / "out3").string();
    EXPECT_THAT(InputErrorOf([&] { RunCalibrationSensitivity(o); }), HasSubstr("options.voxel_m")) << report;
  }
}

// The tolerance: where the MAE's excess over the unperturbed map crosses 0.1 mm / 1 mm.
TEST(CalibrationSensitivity, ToleranceInterpolatesWhereTheExcessCrossesTheLimit) {
  const std::vector<SensitivityPoint> sweep = {
      {"hand_eye_deg", 0.1, 0.55}, {"hand_eye_deg", 0.2, 0.70}, {"hand_eye_deg", 0.5, 1.90}};
  const SensitivityTolerance t = ToleranceOf("hand_eye_deg", sweep, 0.5);
  EXPECT_NEAR(t.within_0_1mm, 0.1 + 0.1 * (0.1 - 0.05) / (0.2 - 0.05), 1e-12);  // excess 0.05 -> 0.2
  EXPECT_NEAR(t.within_1mm, 0.2 + 0.3 * (1.0 - 0.2) / (1.4 - 0.2), 1e-12);      // excess 0.2 -> 1.4
  EXPECT_EQ(ToleranceOf("x", {{"x", 1.0, 0.52}}, 0.5).within_1mm, 1.0);         // never exceeded: the largest swept
}

}  // namespace
}  // namespace romunect::jobs
