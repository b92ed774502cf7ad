#include "romunect/fusion/frame_inserter.h"

#include <cmath>
#include <limits>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <gmock/gmock.h>
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
          // A stream, not string concatenation: GCC 12 reports a false -Wrestrict on the latter.
          std::ostringstream s;
          s << "(" << ix << ", " << iy << ", " << iz << "): fast " << grid.vote(ix, iy, iz) << ", reference "
            << ref.at(ix, iy, iz);
          first = s.str();
        }
      }
    }
  }
  if (differences == 0) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << differences << " votes differ, first at " << first;
}

// Every kernel this CPU runs (AVX-512, AVX2, SSE2, scalar), each with 1, 2 and 3 threads: they must all
// give the reference's votes.
struct Config {
  int threads;
  Isa isa;
};
std::vector<Config> AllConfigs(std::vector<int> thread_counts = {1, 2, 3}) {
  std::vector<Config> configs;
  for (const Isa isa : {Isa::kAvx512, Isa::kAvx2, Isa::kSse2, Isa::kScalar}) {
    const InserterOptions options{1, isa};
    if (!options.Problem().empty()) continue;
    for (const int threads : thread_counts) configs.push_back({threads, isa});
  }
  return configs;
}
std::string Describe(const Config& c) {
  return std::string("isa ") + ToString(c.isa) + ", threads " + std::to_string(c.threads);
}

// One fast grid per configuration, fed the same frames.
struct FastGrids {
  FastGrids(const GridOptions& options, const std::vector<Config>& all) : configs(all) {
    for (const Config& c : configs) {
      grids.push_back(std::make_unique<VotingGrid>(options));
      inserters.push_back(std::make_unique<FrameInserter>(grids.back().get(), InserterOptions{c.threads, c.isa}));
      stats.emplace_back();
    }
  }
  void Insert(const CameraModel& camera, const cv::Mat& depth, const Pose& T_W_C) {
    for (size_t i = 0; i < configs.size(); ++i) inserters[i]->Insert(camera, depth, T_W_C, &stats[i]);
  }
  std::vector<Config> configs;
  std::vector<std::unique_ptr<VotingGrid>> grids;
  std::vector<std::unique_ptr<FrameInserter>> inserters;
  std::vector<InsertStats> stats;
};

TEST(FrameInserterTest, KernelsAreOfferedAsTheCpuAllows) {
  const InserterOptions scalar{1, Isa::kScalar}, automatic{1, Isa::kAuto};
  const InserterOptions avx2{1, Isa::kAvx2}, avx512{1, Isa::kAvx512};
  EXPECT_EQ(scalar.Problem(), "");
  EXPECT_EQ(automatic.Problem(), "");
  GridOptions options;
  options.voxel_m = 0.004;
  VotingGrid grid(options);
  EXPECT_NE(FrameInserter(&grid, InserterOptions{}).isa(), Isa::kAuto);  // resolved
  EXPECT_EQ(FrameInserter(&grid, scalar).isa(), Isa::kScalar);
  const bool has_avx512 = __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
                          __builtin_cpu_supports("avx512dq");
  if (!has_avx512) {
    EXPECT_THAT(avx512.Problem(), ::testing::HasSubstr("isa = avx512"));
  }
  if (!__builtin_cpu_supports("avx2")) {
    EXPECT_THAT(avx2.Problem(), ::testing::HasSubstr("isa = avx2"));
  }
  const Isa best = has_avx512 ? Isa::kAvx512 : __builtin_cpu_supports("avx2") ? Isa::kAvx2 : Isa::kSse2;
  EXPECT_EQ(FrameInserter(&grid, InserterOptions{}).isa(), best);
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
// identical counters, for every kernel with 1, 2 and 3 threads, with and without lens distortion.
// nz = 43: runs of one block, of several blocks and at the column top (AVX2 end-aligned block).
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
    FastGrids fast(options, AllConfigs());
    ReferenceGrid ref = MakeReference(*fast.grids[0]);
    ReferenceCounts counts;
    for (int i = 0; i < bin.frames(); ++i) {
      const Frame frame = bin.RenderFrame(i);
      fast.Insert(bin.camera(), frame.depth_m, *frame.T_W_C);
      reference::ReferenceInsert(bin.camera(), frame.depth_m, *frame.T_W_C, &ref, &counts);
      // Extraction at any time gives the reference's map.
      const cv::Mat expected = reference::ReferenceExtract(ref);
      for (size_t c = 0; c < fast.configs.size(); ++c) {
        ASSERT_TRUE(ImagesBitEqual(ExtractHeightMap(*fast.grids[c]), expected))
            << "frame " << i << ", " << Describe(fast.configs[c]) << ", distorted " << distorted;
      }
    }
    for (size_t c = 0; c < fast.configs.size(); ++c) {
      const InsertStats& stats = fast.stats[c];
      SCOPED_TRACE(Describe(fast.configs[c]) + ", distorted " + std::to_string(distorted));
      EXPECT_TRUE(VotesEqual(*fast.grids[c], ref));
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
// inside, beyond and before the box: every clipping and tie case the reference knows. Two box
// heights: nz = 24 (shorter than two AVX2 blocks: the general run kernel) and nz = 40.
TEST(FrameInserterTest, MatchesReferenceOnRandomRaysThroughTheBoxFaces) {
  for (const int nz : {24, 40}) {
    GridOptions options;
    options.min_W = Eigen::Vector3d(-0.01, -0.008, -0.00025 * nz);
    options.max_W = Eigen::Vector3d(0.01, 0.008, 0.00025 * nz);
    options.voxel_m = 0.0005;
    CameraModel camera = testing::SmallCamera();
    camera.width = 24;
    camera.height = 18;
    camera.cx = 11.5;
    camera.cy = 8.5;
    camera.fx = camera.fy = 20.0;  // wide: rays leave through every face
    std::mt19937 rng(11);
    std::uniform_real_distribution<double> position(-0.02, 0.02), angle(-M_PI, M_PI), depth(0.0, 0.05);
    FastGrids fast(options, AllConfigs({1, 2}));
    ASSERT_EQ(fast.grids[0]->nz(), nz);
    ReferenceGrid ref = MakeReference(*fast.grids[0]);
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
      fast.Insert(camera, d, T_W_C);
      reference::ReferenceInsert(camera, d, T_W_C, &ref, &counts);
    }
    for (size_t c = 0; c < fast.configs.size(); ++c) {
      const InsertStats& stats = fast.stats[c];
      SCOPED_TRACE(Describe(fast.configs[c]) + ", nz " + std::to_string(nz));
      EXPECT_TRUE(VotesEqual(*fast.grids[c], ref));
      EXPECT_TRUE(ImagesBitEqual(ExtractHeightMap(*fast.grids[c]), reference::ReferenceExtract(ref)));
      EXPECT_EQ(stats.hits, counts.hits);
      EXPECT_EQ(stats.misses, counts.misses);
      EXPECT_GT(stats.rays_missing_box, 0u);
      EXPECT_GT(stats.points_outside_box, stats.rays_missing_box);  // some rays cross and leave
      EXPECT_GT(stats.hits, 100u);
    }
  }
}

// Rays whose crossings fall exactly on voxel planes: a camera looking straight down from voxel
// corners and centres, dyadic voxel (2^-11 m), ray slopes k/16 and dyadic depths, so crossing
// times tie between axes, the z at a column's exit lands on z planes (the walks' exact
// near-plane path), and rays run along x or y planes or straight down. nz = 40: the AVX2 kernel
// walks four rays at once in lanes at 1 thread; 33 x 17 pixels leave groups of fewer than four
// rays at tile ends; wide slopes leave through the box's sides; depths end above, inside and
// below the box.
TEST(FrameInserterTest, MatchesReferenceOnRaysAlongVoxelPlanes) {
  const double voxel = std::ldexp(1.0, -11);
  GridOptions options;
  options.min_W = Eigen::Vector3d(-24 * voxel, -20 * voxel, 0.0);
  options.max_W = Eigen::Vector3d(24 * voxel, 20 * voxel, 40 * voxel);
  options.voxel_m = voxel;
  CameraModel camera = testing::SmallCamera();
  camera.width = 33;
  camera.height = 17;
  camera.cx = 16.0;
  camera.cy = 8.0;
  camera.fx = camera.fy = 16.0;  // slopes k / 16, up to 1
  camera.distortion = {0.0, 0.0, 0.0, 0.0, 0.0};
  const Eigen::Matrix3d down = Eigen::Vector3d(1.0, -1.0, -1.0).asDiagonal();  // camera z = world -z
  std::mt19937 rng(5);
  std::uniform_int_distribution<int> corner(-8, 8), height(44, 90), depth_voxels(-6, 48);
  FastGrids fast(options, AllConfigs({1, 2}));
  ASSERT_EQ(fast.grids[0]->nz(), 40);
  ReferenceGrid ref = MakeReference(*fast.grids[0]);
  ReferenceCounts counts;
  for (int frame = 0; frame < 24; ++frame) {
    // Voxel corners, or centres every 3rd frame.
    const double shift = frame % 3 == 0 ? 0.5 : 0.0;
    const int h = height(rng);
    const Eigen::Vector3d t((corner(rng) + shift) * voxel, (corner(rng) + shift) * voxel, h * voxel);
    cv::Mat d(camera.height, camera.width, CV_32F);
    for (auto it = d.begin<float>(); it != d.end<float>(); ++it) {
      // From above the box top (h - 40 voxels) to below its floor; some pixels without one.
      const int k = depth_voxels(rng);
      *it = k < -4 ? 0.0f : static_cast<float>((h - 42 + k) * voxel);
    }
    fast.Insert(camera, d, MakePose(down, t));
    reference::ReferenceInsert(camera, d, MakePose(down, t), &ref, &counts);
  }
  for (size_t c = 0; c < fast.configs.size(); ++c) {
    const InsertStats& stats = fast.stats[c];
    SCOPED_TRACE(Describe(fast.configs[c]));
    EXPECT_TRUE(VotesEqual(*fast.grids[c], ref));
    EXPECT_EQ(stats.hits, counts.hits);
    EXPECT_EQ(stats.misses, counts.misses);
    EXPECT_GT(stats.hits, 1000u);
    EXPECT_GT(stats.points_outside_box, stats.rays_missing_box);  // some rays leave through a side
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

// changed_columns() bounds what a frame changes: no vote outside it moves, so a completeness
// tracker that looks again only there follows the full extraction's completeness frame after
// frame, for every kernel and thread count; a camera seeing part of the box leaves the rest out
// (rays tilted and distorted, the approach of the analytic bin at 1 mm: 400 mm down to 200 mm).
TEST(FrameInserterTest, ChangedColumnsBoundWhatAFrameChanges) {
  AnalyticBinOptions bin_options;
  bin_options.width = 96;
  bin_options.height = 72;
  bin_options.frames = 8;
  bin_options.distortion = {-0.12, 0.05, 0.001, -0.0015, 0.0};
  const AnalyticBin bin(bin_options);
  GridOptions options;
  options.min_W = AnalyticBin::RegionMin();
  options.max_W = AnalyticBin::RegionMax();
  options.voxel_m = 0.001;
  for (const Config& config : AllConfigs()) {
    SCOPED_TRACE(Describe(config));
    VotingGrid grid(options);
    FrameInserter inserter(&grid, InserterOptions{config.threads, config.isa});
    EXPECT_TRUE(inserter.changed_columns().empty());
    CompletenessTracker completeness(grid);
    bool some_frame_sees_part = false;
    for (int i = 0; i < bin.frames(); ++i) {
      std::vector<Vote> before(grid.column(0, 0),
                               grid.column(0, 0) + static_cast<size_t>(grid.nx()) * grid.ny() * grid.nz());
      const Frame frame = bin.RenderFrame(i);
      inserter.Insert(bin.camera(), frame.depth_m, *frame.T_W_C, nullptr);
      const cv::Rect changed = inserter.changed_columns();
      ASSERT_FALSE(changed.empty()) << "frame " << i;
      some_frame_sees_part = some_frame_sees_part || changed.area() < grid.nx() * grid.ny();
      size_t moved_outside = 0;
      for (int iy = 0; iy < grid.ny(); ++iy) {
        for (int ix = 0; ix < grid.nx(); ++ix) {
          if (changed.contains(cv::Point(ix, iy))) continue;
          for (int iz = 0; iz < grid.nz(); ++iz) {
            moved_outside += grid.vote(ix, iy, iz) != before[grid.ColumnIndex(ix, iy) * grid.nz() + iz];
          }
        }
      }
      EXPECT_EQ(moved_outside, 0u) << "frame " << i;
      EXPECT_EQ(completeness.Update(changed), Completeness(ExtractHeightMap(grid))) << "frame " << i;
    }
    EXPECT_TRUE(some_frame_sees_part);
    // Depth in one small patch only (most tiles and threads' chunks cast no ray): the bound
    // stays around the patch's rays; a frame without depth changes nothing.
    const Frame frame = bin.RenderFrame(bin.frames() - 1);
    std::vector<cv::Point> measured;
    cv::findNonZero(frame.depth_m > 0.0f, measured);
    ASSERT_FALSE(measured.empty());
    const cv::Rect around = cv::Rect(measured[measured.size() / 2] - cv::Point(3, 3), cv::Size(6, 6)) &
                            cv::Rect(cv::Point(0, 0), frame.depth_m.size());
    cv::Mat patch(frame.depth_m.size(), CV_32F, cv::Scalar(0.0f));
    frame.depth_m(around).copyTo(patch(around));
    inserter.Insert(bin.camera(), patch, *frame.T_W_C, nullptr);
    EXPECT_FALSE(inserter.changed_columns().empty());
    EXPECT_LT(inserter.changed_columns().area(), grid.nx() * grid.ny() / 4);
    inserter.Insert(bin.camera(), cv::Mat(frame.depth_m.size(), CV_32F, cv::Scalar(0.0f)), *frame.T_W_C, nullptr);
    EXPECT_TRUE(inserter.changed_columns().empty());
  }
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

// Votes saturate at +-32767 (voting_grid.h): a 40 x 30 camera looking down into a 2 x 2 x nz box
// of coarse voxels sends ~300 rays per column per frame, so within 200 frames the top voxels
// reach -32767 and the surface voxels +32767 and keep receiving votes. Saturation is where the
// order of votes would matter; every kernel must still equal the reference vote for vote, with
// runs of every length (nz = 8 and 11: runs crossing 8-lane blocks and column ends; nz = 40:
// 16-lane blocks, several per run, and end-aligned blocks at the column top).
TEST(FrameInserterTest, SaturatedVotesMatchReference) {
  for (const int nz : {8, 11, 40}) {
    GridOptions options;
    options.min_W = Eigen::Vector3d(0.0, 0.0, 0.0);
    options.max_W = Eigen::Vector3d(0.002, 0.002, 0.001 * nz);
    options.voxel_m = 0.001;
    CameraModel camera = testing::SmallCamera();
    camera.width = 40;
    camera.height = 30;
    camera.cx = 19.5;
    camera.cy = 14.5;
    // The camera 20 mm above the floor, above the box top for nz = 40; 40 px span 2 mm at 20 mm.
    const double height_m = nz <= 11 ? 0.020 : 0.010 + 0.001 * nz;
    camera.fx = camera.fy = 400.0 * height_m / 0.020;
    const Pose T_W_C = MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                                Eigen::Vector3d(0.001, 0.001, height_m));
    FastGrids fast(options, AllConfigs({1, 2}));
    ReferenceGrid ref = MakeReference(*fast.grids[0]);
    ReferenceCounts counts;
    std::mt19937 rng(5);
    // Depths put the points at z in [0.5, nz - 1.5] mm: hits at every level but the top one,
    // which only misses reach (a voxel hit in a frame ends it above -32767: hits come last).
    std::uniform_real_distribution<double> depth(height_m - 0.001 * (nz - 1.5), height_m - 0.0005);
    for (int frame = 0; frame < 200; ++frame) {
      cv::Mat d(camera.height, camera.width, CV_32F);
      // Most pixels on one plane (the surface saturates positive), the rest scattered.
      for (auto it = d.begin<float>(); it != d.end<float>(); ++it) {
        *it = static_cast<float>(rng() % 4 != 0 ? height_m - 0.0042 : depth(rng));
      }
      fast.Insert(camera, d, T_W_C);
      reference::ReferenceInsert(camera, d, T_W_C, &ref, &counts);
    }
    for (size_t c = 0; c < fast.configs.size(); ++c) {
      SCOPED_TRACE(Describe(fast.configs[c]) + ", nz " + std::to_string(nz));
      EXPECT_TRUE(VotesEqual(*fast.grids[c], ref));
      EXPECT_TRUE(ImagesBitEqual(ExtractHeightMap(*fast.grids[c]), reference::ReferenceExtract(ref)));
      EXPECT_EQ(fast.stats[c].hits, counts.hits);
      EXPECT_EQ(fast.stats[c].misses, counts.misses);
    }
    int saturated_low = 0, saturated_high = 0;
    for (const int16_t v : ref.votes) {
      saturated_low += v == -32767;
      saturated_high += v == 32767;
    }
    EXPECT_GT(saturated_low, 0) << "the workload must saturate misses";
    EXPECT_GT(saturated_high, 0) << "the workload must saturate hits";
  }
}

// A frame's misses come before its hits (voting_grid.h), whatever the order of its pixels, and
// it shows once a voxel saturates: a 3 x 64 camera looks down one column. After the voxel at z
// index 3 is saturated at +32767, a frame casts a hit into it from one pixel and misses through
// it from the other two of row 0: 32767 - 2 + 1 = 32766 with the hit at the first pixel (cast ray after
// ray, the hit would be lost to saturation: 32765) and with it at the last.
TEST(FrameInserterTest, AppliesAFramesMissesBeforeItsHits) {
  GridOptions options;
  options.min_W = Eigen::Vector3d(0.0, 0.0, 0.0);
  options.max_W = Eigen::Vector3d(0.001, 0.001, 0.008);
  options.voxel_m = 0.001;
  CameraModel camera = testing::SmallCamera();
  camera.width = 3;
  camera.height = 64;  // 192 hits per frame saturate the voxel quickly; the test frame uses row 0
  camera.cx = 1.0;
  camera.cy = 31.5;
  camera.fx = camera.fy = 20000.0;  // every ray stays inside the one column
  const Pose T_W_C = MakePose(Eigen::AngleAxisd(M_PI, Eigen::Vector3d::UnitX()).toRotationMatrix(),
                              Eigen::Vector3d(0.0005, 0.0005, 0.020));
  const float hit_depth = 0.020f - 0.0035f, miss_depth = 0.020f - 0.0015f;  // z 3.5 mm, 1.5 mm
  for (const int hit_pixel : {0, 2}) {
    for (const Config& config : AllConfigs({1, 2})) {
      SCOPED_TRACE(Describe(config) + ", hit at pixel " + std::to_string(hit_pixel));
      VotingGrid grid(options);
      ReferenceGrid ref = MakeReference(grid);
      ReferenceCounts counts;
      FrameInserter inserter(&grid, InserterOptions{config.threads, config.isa});
      const cv::Mat saturate(camera.height, camera.width, CV_32F, cv::Scalar(hit_depth));
      for (int frame = 0; frame * camera.width * camera.height < 32767; ++frame) {
        inserter.Insert(camera, saturate, T_W_C, nullptr);
        reference::ReferenceInsert(camera, saturate, T_W_C, &ref, &counts);
      }
      ASSERT_EQ(grid.vote(0, 0, 3), 32767);
      cv::Mat d(camera.height, camera.width, CV_32F, cv::Scalar(0.0f));
      for (int u = 0; u < camera.width; ++u) d.at<float>(0, u) = u == hit_pixel ? hit_depth : miss_depth;
      InsertStats stats;
      inserter.Insert(camera, d, T_W_C, &stats);
      reference::ReferenceInsert(camera, d, T_W_C, &ref, &counts);
      EXPECT_EQ(stats.hits, 3u);  // the misses through z index 3 end in hits at index 1
      EXPECT_EQ(grid.vote(0, 0, 3), 32766);
      EXPECT_EQ(ref.at(0, 0, 3), 32766);
      EXPECT_TRUE(VotesEqual(grid, ref));
    }
  }
}

}  // namespace
}  // namespace romunect::fusion
