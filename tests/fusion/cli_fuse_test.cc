// `romunect fuse` run as a user would: a good run against ground truth, and every kind of bad
// input docs/fuse.md lists (clear message, non-zero exit; per-pixel junk counted).
#include <cmath>
#include <limits>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/sensor/image_io.h"
#include "romunect/testing/analytic_bin.h"
#include "romunect/testing/test_support.h"

namespace romunect::fusion {
namespace {

using testing::AnalyticBin;
using testing::AnalyticBinOptions;
using ::testing::HasSubstr;
using testing::ReadText;
using testing::RunRomunect;
using testing::ScratchDir;
using testing::WriteText;

constexpr double kVoxelM = 0.001;  // coarse: the CLI test is about wiring, not resolution
constexpr const char* kVoxelArg = "--voxel 0.001";

// A small analytic-bin capture as a frame directory, with its ground-truth height map.
AnalyticBin WriteBinDirectory(const std::filesystem::path& dir, int frames) {
  AnalyticBinOptions options;
  options.width = 96;
  options.height = 72;
  options.frames = frames;
  options.seed = 3;
  AnalyticBin bin(options);
  FrameDirectoryWriter writer(dir, bin.camera());
  for (int i = 0; i < frames; ++i) writer.Add(bin.RenderFrame(i));
  writer.Finish();
  return bin;
}

nlohmann::json ReadManifestJson(const std::filesystem::path& dir) {
  return nlohmann::json::parse(ReadText(dir / "frames.json"));
}

TEST(FuseCliTest, FusesAnAnalyticBinAndReportsAgainstGroundTruth) {
  ScratchDir scratch("fuse_cli_good");
  const AnalyticBin bin = WriteBinDirectory(scratch / "capture", 8);
  GridOptions grid;
  grid.voxel_m = kVoxelM;
  const Eigen::Vector3i n = grid.Dims();
  // As romunect writes height maps: with their geometry, which fuse checks against its grid's.
  WriteHeightMapExr(scratch / "gt.exr", bin.GroundTruthHeightMap(grid.min_W, kVoxelM, n.x(), n.y()),
                    VotingGrid(grid).geometry());

  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --threads 2 --gt " +
                                  (scratch / "gt.exr").string());
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_THAT(result.output, HasSubstr("frame 8/8"));           // the progress line
  const std::filesystem::path out = scratch / "capture_fused";  // default: beside the input
  for (const char* file :
       {"fused_depth.exr", "fused_depth.png", "fused_points.ply", "completeness.png", "report.json"}) {
    EXPECT_TRUE(std::filesystem::exists(out / file)) << file;
  }
  const nlohmann::json report = nlohmann::json::parse(ReadText(out / "report.json"));
  EXPECT_EQ(report["frames"], 8);
  EXPECT_EQ(report["grid"]["nx"], 150);
  EXPECT_EQ(report["grid"]["ny"], 80);
  EXPECT_EQ(report["grid"]["nz"], 64);
  EXPECT_EQ(report["completeness_per_frame"].size(), 8u);
  // Fusion is the point: completeness grows from the first frame (grazing rays' misses cancel
  // single hits, so one coarse frame fills little) to most of the region.
  constexpr double kMinCompleteness = 0.5;  // measured 0.62 with 8 frames of 96 x 72 at 1 mm
  EXPECT_GT(report["completeness"].get<double>(), kMinCompleteness);
  EXPECT_GT(report["completeness"].get<double>(), 3 * report["completeness_per_frame"][0].get<double>());
  // Heights are voxel centres (error up to half a voxel) plus 0.1 mm noise; cells straddling a
  // wall or an object's edge can be off by centimetres, so bound the bulk, not the maximum.
  constexpr double kMinWithin1mm = 0.9;  // measured 0.954: most cells are within half a voxel
  constexpr double kMaxMaeMm = 2.0;      // measured 1.32: half a voxel plus the edge cells' share
  EXPECT_GT(report["within_1mm"].get<double>(), kMinWithin1mm);
  EXPECT_LT(report["mae_mm"].get<double>(), kMaxMaeMm);
  EXPECT_GT(report["rmse_mm"].get<double>(), 0.0);
  const cv::Mat fused = ReadDepthExr(out / "fused_depth.exr");
  EXPECT_EQ(fused.size(), cv::Size(150, 80));
  EXPECT_GT(report["insert_ms"]["median"].get<double>(), 0.0);
}

TEST(FuseCliTest, RejectsEmptyInvertedOrMalformedBoxesAndBadVoxels) {
  ScratchDir scratch("fuse_cli_box");
  WriteBinDirectory(scratch / "capture", 1);
  const std::string dir = (scratch / "capture").string();
  struct Case {
    std::string args, expected;
  };
  for (const Case& c : std::vector<Case>{
           {"--box 0,0,0,0,0.05,0.05", "--box: box x range [0, 0] is empty or inverted"},
           {"--box 0,0.05,0,0.05,0,0.05", "--box: box y range [0.05, 0] is empty or inverted"},
           {"--box 0,0,0,1,1", "expected 6 comma-separated numbers"},
           {"--box 0,0,0,a,1,1", "'a' is not a number"},
           {"--box ''", "--box: '': expected 6 comma-separated numbers"},
           {"--box 0,0,0,1,1,1,", "--box: '0,0,0,1,1,1,': expected 6 comma-separated numbers"},
           {"--voxel 0", "--voxel"},
           {"--voxel -0.001", "must be a positive size"},
           // Metres: 0.25 is a 25 cm voxel (a millimetre figure typed as metres), 1e-300 none at all.
           {"--voxel 0.25", "--voxel: 0.25 m: the box's x extent 0.15 m holds fewer than 2 voxels"},
           {"--voxel 1e-300", "--voxel: box x extent 0.15 m at voxel_m = 1e-300"},
           {"--max-memory-mb inf", "--max-memory-mb: inf: expected 0 < MB <= 1000000"},
           {"--out " + (scratch / "capture" / "frames.json" / "out").string(), "frames.json is not a folder"},
           {"--threads 0", "--threads: threads = 0"},
       }) {
    const auto result = RunRomunect("fuse " + dir + " " + c.args);
    EXPECT_NE(result.exit_code, 0) << c.args;
    EXPECT_THAT(result.output, HasSubstr(c.expected)) << c.args;
    EXPECT_FALSE(std::filesystem::exists(scratch / "capture_fused" / "report.json")) << c.args;
  }
}

// The default output lies beside the frame directory however it is named ("capture/" too).
TEST(FuseCliTest, DefaultOutputIsBesideTheSourceEvenWithATrailingSlash) {
  ScratchDir scratch("fuse_cli_slash");
  WriteBinDirectory(scratch / "capture", 1);
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + "/ " + kVoxelArg);
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_TRUE(std::filesystem::exists(scratch / "capture_fused" / "report.json"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "capture" / "_fused"));
}

// A frame directory without frames has nothing to fuse: an error, and no empty maps.
TEST(FuseCliTest, ADirectoryWithoutFramesIsAnErrorThatWritesNothing) {
  ScratchDir scratch("fuse_cli_none");
  FrameDirectoryWriter writer(scratch / "capture", testing::SmallCamera());
  writer.Finish();
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg);
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("nothing to fuse: frames.json lists no frame"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "capture_fused"));
}

// Frames that give no hit would fuse to empty maps written with exit 0: frames without one
// valid depth pixel, and a box that the rays cross on the way to points beyond it.
TEST(FuseCliTest, FramesThatHitNothingInTheBoxAreAnErrorThatWritesNothing) {
  ScratchDir scratch("fuse_cli_no_hits");
  WriteBinDirectory(scratch / "capture", 2);
  const auto above = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg +
                                 " --box -0.075,-0.04,0.1,0.075,0.04,0.15 --out " + (scratch / "above").string());
  EXPECT_EQ(above.exit_code, 2) << above.output;
  EXPECT_THAT(above.output, HasSubstr("frames ends inside the box (5560 cross it to points beyond, 293 miss it)"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "above"));

  const nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  for (const nlohmann::json& frame : manifest["frames"]) {
    const std::filesystem::path depth_path = scratch / "capture" / frame["depth"].get<std::string>();
    WriteDepthExr(depth_path, cv::Mat::zeros(ReadDepthExr(depth_path).size(), CV_32F));
  }
  const auto dark = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --out " +
                                (scratch / "dark").string());
  EXPECT_EQ(dark.exit_code, 2) << dark.output;
  EXPECT_THAT(dark.output, HasSubstr("nothing to fuse: no frame has a valid depth pixel"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "dark"));
}

TEST(FuseCliTest, RefusesAGridThatDoesNotFitWithTheSizeItNeeds) {
  ScratchDir scratch("fuse_cli_memory");
  WriteBinDirectory(scratch / "capture", 1);
  // 0.01 mm voxels over the default box: 15000 x 8000 x 6400 voxels, 1.5 TB.
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " --voxel 0.00001");
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("15000 x 8000 x 6400 grid needs"));
}

TEST(FuseCliTest, RejectsANonRigidPose) {
  ScratchDir scratch("fuse_cli_pose");
  WriteBinDirectory(scratch / "capture", 2);
  nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  manifest["frames"][1]["T_W_C"][0] = 2.0;  // scales x: not a rotation
  WriteText(scratch / "capture" / "frames.json", manifest.dump());
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg);
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("frames[1].T_W_C"));
}

TEST(FuseCliTest, RejectsAFrameWithoutPose) {
  ScratchDir scratch("fuse_cli_nopose");
  WriteBinDirectory(scratch / "capture", 2);
  nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  manifest["frames"][1].erase("T_W_C");
  WriteText(scratch / "capture" / "frames.json", manifest.dump());
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg);
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("frames[1].T_W_C: missing"));
}

TEST(FuseCliTest, RejectsFramesOfADifferentSize) {
  ScratchDir scratch("fuse_cli_size");
  WriteBinDirectory(scratch / "capture", 2);
  const nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  const std::string depth = manifest["frames"][1]["depth"];
  WriteDepthExr(scratch / "capture" / depth, cv::Mat(36, 48, CV_32F, cv::Scalar(0.2f)));
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg);
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("frames[1]"));
  EXPECT_THAT(result.output, HasSubstr("48"));
}

TEST(FuseCliTest, CountsNaNInfAndNegativePixelsAsSkipped) {
  ScratchDir scratch("fuse_cli_nan");
  WriteBinDirectory(scratch / "capture", 2);
  const nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  const std::filesystem::path depth_path = scratch / "capture" / manifest["frames"][0]["depth"].get<std::string>();
  cv::Mat depth = ReadDepthExr(depth_path);
  depth.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  depth.at<float>(1, 1) = std::numeric_limits<float>::infinity();
  depth.at<float>(2, 2) = -0.2f;
  WriteDepthExr(depth_path, depth);
  // Ground truth fuse does not read: its junk is skipped and counted too, never fatal.
  ASSERT_TRUE(manifest["frames"][1].contains("gt_depth"));
  const std::filesystem::path gt_path = scratch / "capture" / manifest["frames"][1]["gt_depth"].get<std::string>();
  cv::Mat gt = ReadDepthExr(gt_path);
  gt.at<float>(3, 3) = std::numeric_limits<float>::quiet_NaN();
  WriteDepthExr(gt_path, gt);
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --out " +
                                  (scratch / "out").string());
  ASSERT_EQ(result.exit_code, 0) << result.output;
  const nlohmann::json report = nlohmann::json::parse(ReadText(scratch / "out" / "report.json"));
  EXPECT_EQ(report["skipped_pixels"], 4);
  EXPECT_EQ(report["frames"], 2);
}

TEST(FuseCliTest, RejectsGroundTruthOfAnotherGrid) {
  ScratchDir scratch("fuse_cli_gt");
  WriteBinDirectory(scratch / "capture", 1);
  WriteDepthExr(scratch / "gt.exr", cv::Mat(10, 10, CV_32F, cv::Scalar(0.0f)));
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --gt " +
                                  (scratch / "gt.exr").string());
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("expected the grid's 150 x 80"));
}

// A capture of a scene away from the world origin (as `romunect scan`'s, around its bin) is fused
// over the region its frames.json records; the default box, which no ray enters, is refused.
TEST(FuseCliTest, FusesOverTheRegionItsFrameDirectoryRecords) {
  ScratchDir scratch("fuse_cli_region");
  WriteBinDirectory(scratch / "capture", 8);
  constexpr double kShiftX = 0.3;  // the scene and its cameras, 30 cm along world x
  nlohmann::json manifest = ReadManifestJson(scratch / "capture");
  for (auto& frame : manifest["frames"]) frame["T_W_C"][3] = frame["T_W_C"][3].get<double>() + kShiftX;
  const GridOptions box;  // the default box, around the origin
  manifest["region_W"] = {box.min_W.x() + kShiftX, box.min_W.y(), box.min_W.z(),
                          box.max_W.x() + kShiftX, box.max_W.y(), box.max_W.z()};
  WriteText(scratch / "capture" / "frames.json", manifest.dump());

  const auto fused = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg);
  ASSERT_EQ(fused.exit_code, 0) << fused.output;
  EXPECT_THAT(fused.output, HasSubstr("(frames.json's region_W)"));
  const nlohmann::json report = nlohmann::json::parse(ReadText(scratch / "capture_fused" / "report.json"));
  EXPECT_EQ(report["box_from"], "frames.json's region_W");
  EXPECT_DOUBLE_EQ(report["box_m"][0].get<double>(), box.min_W.x() + kShiftX);
  EXPECT_EQ(report["grid"]["nx"], 150);
  // The same scene as FusesAnAnalyticBinAndReportsAgainstGroundTruth's, shifted: as complete.
  constexpr double kMinCompleteness = 0.5;  // measured 0.62 unshifted
  EXPECT_GT(report["completeness"].get<double>(), kMinCompleteness);

  // --box wins over the region; a box that no ray enters is an error, not an empty map.
  const std::string default_box = "--box -0.075,-0.04,-0.004,0.075,0.04,0.06";
  const auto missed = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " " + default_box +
                                  " --out " + (scratch / "missed").string());
  EXPECT_EQ(missed.exit_code, 2) << missed.output;
  EXPECT_THAT(missed.output, HasSubstr("--box: none of the"));
  EXPECT_THAT(missed.output, HasSubstr("rays of the 8 frames enters the box [-0.075, 0.075] x [-0.04, 0.04]"));
  EXPECT_THAT(missed.output, HasSubstr("the cameras were at x 0.265..0.335"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "missed" / "report.json"));
}

TEST(FuseCliTest, RefusesToOverwriteAFinishedFusion) {
  ScratchDir scratch("fuse_cli_overwrite");
  WriteBinDirectory(scratch / "capture", 1);
  const std::string command = "fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --out " +
                              (scratch / "out").string();
  ASSERT_EQ(RunRomunect(command).exit_code, 0);
  const std::string before = ReadText(scratch / "out" / "report.json");
  const auto again = RunRomunect(command + " --threads 2");
  EXPECT_EQ(again.exit_code, 2) << again.output;
  EXPECT_THAT(again.output, HasSubstr("holds a finished fusion (report.json); choose another --out"));
  EXPECT_EQ(ReadText(scratch / "out" / "report.json"), before);
}

// Ground truth of the grid's size made for another box (it records where its cells lie) would be
// compared with the wrong cells: refused, naming both.
TEST(FuseCliTest, RejectsGroundTruthOverAnotherBoxOfTheSameSize) {
  ScratchDir scratch("fuse_cli_gt_box");
  const AnalyticBin bin = WriteBinDirectory(scratch / "capture", 1);
  GridOptions grid;
  grid.voxel_m = kVoxelM;
  HeightMapGeometry shifted = VotingGrid(grid).geometry();
  shifted.min_x_m += 0.01;  // 1 cm along x: 10 cells, same count
  const Eigen::Vector3i n = grid.Dims();
  WriteHeightMapExr(scratch / "gt.exr",
                    bin.GroundTruthHeightMap({shifted.min_x_m, shifted.min_y_m, grid.min_W.z()}, kVoxelM, n.x(), n.y()),
                    shifted);
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --gt " +
                                  (scratch / "gt.exr").string());
  EXPECT_EQ(result.exit_code, 2) << result.output;
  EXPECT_THAT(result.output, HasSubstr("gt.exr: romunect.min_W: its cells start at (-0.065, -0.04) m with 1 mm voxels; "
                                       "the grid's at (-0.075, -0.04) m"));
  EXPECT_FALSE(std::filesystem::exists(scratch / "capture_fused" / "report.json"));
}

// Ground truth without a value under any fused cell has no error to report: null, not 0 mm.
TEST(FuseCliTest, ReportsNoErrorWhereNothingCanBeCompared) {
  ScratchDir scratch("fuse_cli_gt_empty");
  WriteBinDirectory(scratch / "capture", 2);
  GridOptions grid;
  grid.voxel_m = kVoxelM;
  const Eigen::Vector3i n = grid.Dims();
  WriteDepthExr(scratch / "gt.exr", cv::Mat(n.y(), n.x(), CV_32F, cv::Scalar(std::numeric_limits<float>::quiet_NaN())));
  const auto result = RunRomunect("fuse " + (scratch / "capture").string() + " " + kVoxelArg + " --gt " +
                                  (scratch / "gt.exr").string());
  ASSERT_EQ(result.exit_code, 0) << result.output;
  EXPECT_THAT(result.output, HasSubstr("no fused cell where the ground truth has a value"));
  const nlohmann::json report = nlohmann::json::parse(ReadText(scratch / "capture_fused" / "report.json"));
  EXPECT_EQ(report["compared_cells"], 0);
  EXPECT_TRUE(report["rmse_mm"].is_null());
  EXPECT_TRUE(report["mae_mm"].is_null());
  EXPECT_TRUE(report["within_1mm"].is_null());
}

}  // namespace
}  // namespace romunect::fusion
