#include "romunect/fusion/frame_inserter.h"

#include <cmath>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "reference_fusion.h"
#include "romunect/fusion/metrics.h"
#include "romunect/fusion/voting_grid.h"
#include "romunect/testing/analytic_bin.h"
#include "romunect/testing/test_support.h"

namespace romunect::fusion {
namespace {

using reference::ReferenceCounts;
using reference::ReferenceGrid;
using testing::AnalyticBin;
using testing::AnalyticBinOptions;
using testing::ImagesBitEqual;

ReferenceGrid MakeReference(const VotingGrid& grid) {
  return ReferenceGrid(grid.options().min_W, grid.voxel_m(), grid.nx(), grid.ny(), grid.nz());
}

// Every vote of the fast grid equals the reference's; reports the first difference.
::testing::AssertionResult VotesEqual(const VotingGrid& grid, const ReferenceGrid& ref) {
  size_t differences = 0;
  std::string first;
  for (int iy = 0; iy < grid.ny(); ++iy) {
    for (int ix = 0; ix < grid.nx(); ++ix) {
      for (int iz = 0; iz < grid.nz(); ++iz) {
        if (grid.vote(ix, iy, iz) == ref.at(ix, iy, iz)) continue;
        if (differences++ == 0) {
          first = "(" + std::to_string(ix) + ", " + std::to_string(iy) + ", " + std::to_string(iz) +
                  "): fast " + std::to_string(grid.vote(ix, iy, iz)) + ", reference " +
                  std::to_string(ref.at(ix, iy, iz));
        }
      }
    }
  }
  if (differences == 0) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << differences << " votes differ, first at " << first;
}

// A 1-pixel camera looking straight down at depth d: the column under it gets misses from the
// box top down to the voxel holding the point, which gets the hit; nothing below changes.
TEST(FrameInserterTest, SingleRayMissesAboveAndHitsTheMeasuredVoxel) {
  GridOptions options;
  options.min_W = Eigen::Vector3d(0.0, 0.0, 0.0);
  options.max_W = Eigen::Vector3d(0.004, 0.004, 0.010);
  options.voxel_m = 0.001;
  VotingGrid grid(options);
  CameraModel camera;
  camera.width = camera.height = 1;
  camera.cx = camera.cy = 0.0;
  const Pose T_W_C = MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                              Eigen::Vector3d(0.0025, 0.0015, 0.200));
  cv::Mat depth(1, 1, CV_32F, cv::Scalar(0.200f - 0.0043f));  // point at z = 4.3 mm: voxel 4
  FrameInserter inserter(&grid, InserterOptions{});
  InsertStats stats;
  inserter.Insert(camera, depth, T_W_C, &stats);
  for (int iz = 0; iz < grid.nz(); ++iz) {
    const int expected = iz == 4 ? 1 : (iz > 4 ? -1 : 0);
    EXPECT_EQ(grid.vote(2, 1, iz), expected) << "iz " << iz;
  }
  EXPECT_EQ(stats.hits, 1u);
  EXPECT_EQ(stats.misses, 5u);  // voxels 5..9
  const cv::Mat height = ExtractHeightMap(grid);
  EXPECT_FLOAT_EQ(height.at<float>(1, 2), 0.0045f);
  EXPECT_EQ(Completeness(height), 1.0 / 16.0);
}

// The fast path against the reference on the analytic bin: identical votes, identical maps,
// identical counters, for 1, 2 and 3 threads, with and without lens distortion.
TEST(FrameInserterTest, MatchesReferenceVoteForVoteOnAnalyticBin) {
  for (const bool distorted : {false, true}) {
    AnalyticBinOptions bin_options;
    bin_options.width = 96;
    bin_options.height = 72;
    bin_options.frames = 6;
    bin_options.seed = 7;
    if (distorted) bin_options.distortion = {-0.12, 0.05, 0.001, -0.0015, 0.0};
    const AnalyticBin bin(bin_options);
    GridOptions options;
    options.min_W = AnalyticBin::RegionMin();
    options.max_W = AnalyticBin::RegionMax();
    options.voxel_m = 0.0015;  // coarse, so the reference stays fast
    for (const int threads : {1, 2, 3}) {
      VotingGrid grid(options);
      ReferenceGrid ref = MakeReference(grid);
      FrameInserter inserter(&grid, InserterOptions{threads});
      InsertStats stats;
      ReferenceCounts counts;
      for (int i = 0; i < bin.frames(); ++i) {
        const Frame frame = bin.RenderFrame(i);
        inserter.Insert(bin.camera(), frame.depth_m, *frame.T_W_C, &stats);
        reference::ReferenceInsert(bin.camera(), frame.depth_m, *frame.T_W_C, &ref, &counts);
        // Extraction at any time gives the reference's map.
        ASSERT_TRUE(ImagesBitEqual(ExtractHeightMap(grid), reference::ReferenceExtract(ref)))
            << "frame " << i << ", threads " << threads << ", distorted " << distorted;
      }
      EXPECT_TRUE(VotesEqual(grid, ref)) << "threads " << threads << ", distorted " << distorted;
      EXPECT_EQ(stats.rays, counts.rays);
      EXPECT_EQ(stats.hits, counts.hits);
      EXPECT_EQ(stats.misses, counts.misses);
      EXPECT_EQ(stats.rays_missing_box, counts.rays_missing_box);
      EXPECT_EQ(stats.points_outside_box, counts.points_outside_box);
      EXPECT_GT(stats.hits, 1000u);  // the workload really votes
    }
  }
}

// Random cameras inside, outside and around a small box, looking every way, with depths that end
// inside, beyond and before the box: every clipping and tie case the reference knows.
TEST(FrameInserterTest, MatchesReferenceOnRandomRaysThroughTheBoxFaces) {
  GridOptions options;
  options.min_W = Eigen::Vector3d(-0.01, -0.008, -0.006);
  options.max_W = Eigen::Vector3d(0.01, 0.008, 0.006);
  options.voxel_m = 0.0005;
  CameraModel camera = testing::SmallCamera();
  camera.width = 24;
  camera.height = 18;
  camera.cx = 11.5;
  camera.cy = 8.5;
  camera.fx = camera.fy = 20.0;  // wide: rays leave through every face
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> position(-0.02, 0.02), angle(-M_PI, M_PI), depth(0.0, 0.05);
  for (const int threads : {1, 2}) {
    VotingGrid grid(options);
    ReferenceGrid ref = MakeReference(grid);
    FrameInserter inserter(&grid, InserterOptions{threads});
    InsertStats stats;
    ReferenceCounts counts;
    for (int frame = 0; frame < 40; ++frame) {
      const Eigen::Matrix3d R = (Eigen::AngleAxisd(angle(rng), Eigen::Vector3d::UnitZ()) *
                                 Eigen::AngleAxisd(angle(rng), Eigen::Vector3d::UnitY()) *
                                 Eigen::AngleAxisd(angle(rng), Eigen::Vector3d::UnitX()))
                                    .toRotationMatrix();
      // Every 4th camera sits exactly on voxel corners, to exercise ties between axes.
      Eigen::Vector3d t(position(rng), position(rng), position(rng));
      if (frame % 4 == 0) t = (t / 0.0005).array().round().matrix() * 0.0005;
      const Pose T_W_C = MakePose(R, t);
      cv::Mat d(camera.height, camera.width, CV_32F);
      for (auto it = d.begin<float>(); it != d.end<float>(); ++it) *it = static_cast<float>(depth(rng));
      inserter.Insert(camera, d, T_W_C, &stats);
      reference::ReferenceInsert(camera, d, T_W_C, &ref, &counts);
    }
    EXPECT_TRUE(VotesEqual(grid, ref)) << "threads " << threads;
    EXPECT_TRUE(ImagesBitEqual(ExtractHeightMap(grid), reference::ReferenceExtract(ref)));
    EXPECT_EQ(stats.hits, counts.hits);
    EXPECT_EQ(stats.misses, counts.misses);
    EXPECT_GT(stats.rays_missing_box, 0u);
    EXPECT_GT(stats.points_outside_box, stats.rays_missing_box);  // some rays cross and leave
    EXPECT_GT(stats.hits, 100u);
  }
}

// Against the analytic bin's exact height map: fusion fills the region and stays accurate.
TEST(FrameInserterTest, FusedMapOfAnalyticBinMatchesGroundTruth) {
  AnalyticBinOptions bin_options;
  bin_options.width = 160;
  bin_options.height = 120;
  bin_options.frames = 12;
  const AnalyticBin bin(bin_options);
  GridOptions options;
  options.min_W = AnalyticBin::RegionMin();
  options.max_W = AnalyticBin::RegionMax();
  options.voxel_m = 0.0005;
  VotingGrid grid(options);
  FrameInserter inserter(&grid, InserterOptions{2});
  std::vector<double> completeness;
  for (int i = 0; i < bin.frames(); ++i) {
    const Frame frame = bin.RenderFrame(i);
    inserter.Insert(bin.camera(), frame.depth_m, *frame.T_W_C, nullptr);
    completeness.push_back(Completeness(ExtractHeightMap(grid)));
  }
  const cv::Mat gt = bin.GroundTruthHeightMap(options.min_W, options.voxel_m, grid.nx(), grid.ny());
  const HeightMapMetrics m = CompareHeightMaps(ExtractHeightMap(grid), gt);
  constexpr double kMinFinalCompleteness = 0.5;  // measured 0.63: the camera never sees the corners
  constexpr double kMinGrowth = 5.0;             // fusion's point: measured 11x the first frame
  constexpr double kMinWithin1mm = 0.95;         // measured 0.982; the rest straddle walls and edges
  constexpr double kMaxMaeMm = 1.0;              // measured 0.51: an eighth of a voxel plus edge cells
  EXPECT_GT(m.completeness, kMinFinalCompleteness);
  EXPECT_GT(m.completeness, kMinGrowth * completeness.front());
  EXPECT_GT(m.within_1mm, kMinWithin1mm);
  EXPECT_LT(m.mae_mm, kMaxMaeMm);
}

// NaN, inf and negative pixels are skipped and counted, never thrown; 0 is "no measurement".
TEST(FrameInserterTest, CountsInvalidPixelsAndSkipsThem) {
  GridOptions options;
  options.voxel_m = 0.002;
  VotingGrid grid(options);
  FrameInserter inserter(&grid, InserterOptions{2});
  const CameraModel camera = testing::SmallCamera();
  cv::Mat depth(camera.height, camera.width, CV_32F, cv::Scalar(0.2f));
  depth.at<float>(0, 0) = std::numeric_limits<float>::quiet_NaN();
  depth.at<float>(1, 0) = std::numeric_limits<float>::infinity();
  depth.at<float>(2, 0) = -std::numeric_limits<float>::infinity();
  depth.at<float>(3, 0) = -0.1f;
  depth.at<float>(4, 0) = 0.0f;
  depth.at<float>(5, 0) = 1e30f;  // absurd but finite: the ray crosses the box, no hit
  const Pose T_W_C = MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                              Eigen::Vector3d(0, 0, 0.22));
  InsertStats stats;
  inserter.Insert(camera, depth, T_W_C, &stats);
  EXPECT_EQ(stats.pixels, 80u * 60u);
  EXPECT_EQ(stats.invalid_depth, 4u);
  EXPECT_EQ(stats.no_measurement, 1u);
  EXPECT_EQ(stats.rays, 80u * 60u - 5u);
  EXPECT_EQ(stats.points_outside_box, 1u);  // the absurd one; every other point is in the box
  EXPECT_EQ(stats.hits, stats.rays - 1);
}

// Votes saturate at +-32767 (voting_grid.h): a 40 x 30 camera looking down into a 2 x 2 x 8 box
// of coarse voxels sends ~300 rays per column per frame, so within 200 frames the top voxels
// reach -32767 and the surface voxels +32767 and keep receiving votes. Saturation is where the
// order of votes could matter; the fast path must still equal the reference vote for vote, with
// SIMD runs of every length (nz = 8 and nz = 11: runs crossing 8-lane blocks and column ends).
TEST(FrameInserterTest, SaturatedVotesMatchReference) {
  for (const int nz : {8, 11}) {
    GridOptions options;
    options.min_W = Eigen::Vector3d(0.0, 0.0, 0.0);
    options.max_W = Eigen::Vector3d(0.002, 0.002, 0.001 * nz);
    options.voxel_m = 0.001;
    CameraModel camera = testing::SmallCamera();
    camera.width = 40;
    camera.height = 30;
    camera.cx = 19.5;
    camera.cy = 14.5;
    camera.fx = camera.fy = 400.0;  // 40 px span 2 mm at 20 mm
    const Pose T_W_C = MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                                Eigen::Vector3d(0.001, 0.001, 0.020));
    for (const int threads : {1, 2}) {
      VotingGrid grid(options);
      ReferenceGrid ref = MakeReference(grid);
      FrameInserter inserter(&grid, InserterOptions{threads});
      InsertStats stats;
      ReferenceCounts counts;
      std::mt19937 rng(5);
      // Depths put the points at z in [0.5, nz - 0.5] mm: some columns hit at every level.
      std::uniform_real_distribution<double> depth(0.020 - 0.001 * (nz - 0.5), 0.0195);
      for (int frame = 0; frame < 200; ++frame) {
        cv::Mat d(camera.height, camera.width, CV_32F);
        // Most pixels on one plane (the surface saturates positive), the rest scattered.
        for (auto it = d.begin<float>(); it != d.end<float>(); ++it) {
          *it = static_cast<float>(rng() % 4 != 0 ? 0.020 - 0.0042 : depth(rng));
        }
        inserter.Insert(camera, d, T_W_C, &stats);
        reference::ReferenceInsert(camera, d, T_W_C, &ref, &counts);
      }
      EXPECT_TRUE(VotesEqual(grid, ref)) << "nz " << nz << ", threads " << threads;
      EXPECT_TRUE(ImagesBitEqual(ExtractHeightMap(grid), reference::ReferenceExtract(ref)));
      EXPECT_EQ(stats.hits, counts.hits);
      EXPECT_EQ(stats.misses, counts.misses);
      int saturated_low = 0, saturated_high = 0;
      for (const int16_t v : ref.votes) {
        saturated_low += v == -32767;
        saturated_high += v == 32767;
      }
      EXPECT_GT(saturated_low, 0) << "the workload must saturate misses";
      EXPECT_GT(saturated_high, 0) << "the workload must saturate hits";
    }
  }
}

}  // namespace
}  // namespace romunect::fusion
