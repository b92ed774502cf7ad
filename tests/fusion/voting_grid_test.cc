#include "romunect/fusion/voting_grid.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <random>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

#include "reference_fusion.h"
#include "romunect/sensor/errors.h"
#include "romunect/testing/test_support.h"

namespace romunect::fusion {
namespace {

using ::testing::HasSubstr;

std::string ProblemOf(const GridOptions& options) {
  try {
    VotingGrid grid(options);
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}

TEST(VotingGridTest, DefaultIsThePapersGrid) {
  const GridOptions options;
  EXPECT_EQ(options.Problem(), "");
  EXPECT_EQ(options.Dims(), Eigen::Vector3i(600, 320, 256));  // 150 x 80 x 64 mm at 0.25 mm
  EXPECT_EQ(options.RequiredBytes(), 600u * 320u * 256u * 2u + 600u * 320u * 4u);
}

TEST(VotingGridTest, RejectsEmptyInvertedOrNonFiniteBoxesAndBadVoxels) {
  GridOptions options;
  options.max_W.x() = options.min_W.x();
  EXPECT_THAT(ProblemOf(options), HasSubstr("box x range"));
  options = GridOptions{};
  options.max_W.y() = options.min_W.y() - 0.01;
  EXPECT_THAT(ProblemOf(options), HasSubstr("inverted"));
  options = GridOptions{};
  options.min_W.z() = NAN;
  EXPECT_THAT(ProblemOf(options), HasSubstr("finite"));
  options = GridOptions{};
  options.voxel_m = 0.0;
  EXPECT_THAT(ProblemOf(options), HasSubstr("voxel_m = 0"));
  options.voxel_m = -1e-3;
  EXPECT_THAT(ProblemOf(options), HasSubstr("positive"));
}

TEST(VotingGridTest, RefusesAGridThatDoesNotFitAndSaysHowMuchItNeeds) {
  GridOptions options;
  options.voxel_m = 0.00005;  // 3000 x 1600 x 1280 voxels: 12.3 GB
  options.max_memory_bytes = size_t{1} << 30;
  const std::string message = ProblemOf(options);
  EXPECT_THAT(message, HasSubstr("3000 x 1600 x 1280"));
  EXPECT_THAT(message, HasSubstr("12307.2 MB"));
  EXPECT_THAT(message, HasSubstr("memory"));
}

TEST(VotingGridTest, ExtractionKeepsHighestPositiveVoteAndBreaksTiesUpward) {
  GridOptions options;
  options.min_W = Eigen::Vector3d(0, 0, -0.002);
  options.max_W = Eigen::Vector3d(0.003, 0.001, 0.008);
  options.voxel_m = 0.001;
  VotingGrid grid(options);
  ASSERT_EQ(grid.nz(), 10);
  auto set = [&](int ix, int iz, Vote v) {
    const size_t c = grid.ColumnIndex(ix, 0);
    grid.mutable_column(c)[iz] = v;
    if (v > 0) {
      grid.mutable_hit_lo()[c] = std::min<uint16_t>(grid.hit_lo(c), iz);
      grid.mutable_hit_hi()[c] = std::max<uint16_t>(grid.hit_hi(c), iz);
    }
  };
  set(0, 2, 3);  // column 0: 3 at z index 2, 5 at 6 -> 6 wins
  set(0, 6, 5);
  set(0, 8, -4);
  set(1, 3, 4);  // column 1: a tie between 3 and 7 -> the higher (7)
  set(1, 7, 4);
  set(2, 5, -2);  // column 2: no positive vote -> empty
  const cv::Mat height = ExtractHeightMap(grid);
  ASSERT_EQ(height.size(), cv::Size(3, 1));
  EXPECT_DOUBLE_EQ(height.at<float>(0, 0), static_cast<float>(-0.002 + 6.5 * 0.001));
  EXPECT_DOUBLE_EQ(height.at<float>(0, 1), static_cast<float>(-0.002 + 7.5 * 0.001));
  EXPECT_TRUE(std::isnan(height.at<float>(0, 2)));
  grid.Clear();
  EXPECT_TRUE(std::isnan(ExtractHeightMap(grid).at<float>(0, 0)));
}

// Extraction has no AVX-512 search: asking for one is bad input, named as such.
TEST(VotingGridTest, ExtractionRefusesAnInstructionSetItLacks) {
  GridOptions options;
  options.voxel_m = 0.004;
  VotingGrid grid(options);
  try {
    ExtractHeightMap(grid, Isa::kAvx512);
    ADD_FAILURE() << "no InputError";
  } catch (const InputError& e) {
    EXPECT_THAT(e.what(), HasSubstr("isa: avx512"));
  }
}

// Extraction (16- and 8-lane maximum or a plain loop, then the highest z holding it) against the
// reference's obvious full-column loop, on random small votes (many ties) in columns of 1 to 70
// voxels whose hit range spans from one voxel to the whole column.
TEST(VotingGridTest, ExtractionMatchesReferenceOnRandomVotes) {
  std::mt19937 rng(3);
  for (const int nz : {1, 7, 8, 9, 16, 17, 23, 40, 70}) {
    GridOptions options;
    options.min_W = Eigen::Vector3d(0, 0, 0);
    options.max_W = Eigen::Vector3d(0.030, 0.020, 0.001 * nz);
    options.voxel_m = 0.001;
    VotingGrid grid(options);
    reference::ReferenceGrid ref(options.min_W, options.voxel_m, grid.nx(), grid.ny(), grid.nz());
    std::uniform_int_distribution<int> vote(-3, 3), index(0, nz - 1);
    for (int iy = 0; iy < grid.ny(); ++iy) {
      for (int ix = 0; ix < grid.nx(); ++ix) {
        const size_t c = grid.ColumnIndex(ix, iy);
        // Positive votes only inside [lo, hi], as insertion guarantees (hits set the range).
        int lo = index(rng), hi = index(rng);
        if (lo > hi) std::swap(lo, hi);
        if (rng() % 8 == 0) continue;  // some columns never hit
        grid.mutable_hit_lo()[c] = static_cast<uint16_t>(lo);
        grid.mutable_hit_hi()[c] = static_cast<uint16_t>(hi);
        for (int iz = 0; iz < nz; ++iz) {
          const int v = (iz >= lo && iz <= hi) ? vote(rng) : -std::abs(vote(rng));
          grid.mutable_column(c)[iz] = static_cast<Vote>(v);
          ref.at(ix, iy, iz) = static_cast<int16_t>(v);
        }
      }
    }
    const cv::Mat expected = reference::ReferenceExtract(ref);
    EXPECT_TRUE(testing::ImagesBitEqual(ExtractHeightMap(grid), expected)) << "nz " << nz;
    for (const Isa isa : {Isa::kScalar, Isa::kSse2, Isa::kAvx2}) {
      if (!CpuSupports(isa)) continue;
      EXPECT_TRUE(testing::ImagesBitEqual(ExtractHeightMap(grid, isa), expected))
          << "nz " << nz << ", " << ToString(isa);
    }
    for (const int threads : {2, 3, 64}) {  // bands of rows; 64 > ny: one row per thread at most
      EXPECT_TRUE(testing::ImagesBitEqual(ExtractHeightMap(grid, Isa::kAuto, threads), expected))
          << "nz " << nz << ", " << threads << " threads";
    }
  }
}

}  // namespace
}  // namespace romunect::fusion
