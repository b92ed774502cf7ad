// The fusion loop and the fuse job in-process: frames of an analytic bin, written by the test
// as a frame directory or handed over from memory.
#include <atomic>
#include <filesystem>
#include <string>
#include <thread>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "romunect/fusion/voting_grid.h"
#include "romunect/sensor/errors.h"
#include "romunect/sensor/frame_io.h"
#include "romunect/testing/analytic_bin.h"
#include "romunect/testing/test_support.h"
#include "romunect/tools/jobs/fuse.h"
#include "romunect/tools/jobs/fusion_loop.h"

namespace romunect::jobs {
namespace {
namespace fs = std::filesystem;
using testing::AnalyticBin;
using testing::AnalyticBinOptions;
using ::testing::HasSubstr;
using testing::ScratchDir;

constexpr double kVoxelM = 0.001;  // coarse: these tests are about the loop, not resolution

AnalyticBin SmallBin(int frames) {
  AnalyticBinOptions options;
  options.width = 96;
  options.height = 72;
  options.frames = frames;
  options.seed = 3;
  return AnalyticBin(options);
}

void WriteBinDirectory(const AnalyticBin& bin, const fs::path& dir) {
  FrameDirectoryWriter writer(dir, bin.camera());
  for (int i = 0; i < bin.frames(); ++i) writer.Add(bin.RenderFrame(i));
  writer.Finish();
}

// Frames from memory; an empty depth image stands for a bad frame.
class MemorySource : public FrameSource {
 public:
  MemorySource(CameraModel camera, std::vector<Frame> frames)
      : camera_(std::move(camera)), frames_(std::move(frames)) {}
  const CameraModel& camera() const override { return camera_; }
  std::string Describe() const override { return "frames in memory"; }
  FrameStatus Next(Frame* frame, std::string* error) override {
    if (next_ == frames_.size()) return FrameStatus::kEndOfStream;
    *frame = frames_[next_++];
    if (!frame->depth_m.empty()) return FrameStatus::kOk;
    *error = "unreadable frame " + std::to_string(next_ - 1);
    return FrameStatus::kBadFrame;
  }

 private:
  CameraModel camera_;
  std::vector<Frame> frames_;
  size_t next_ = 0;
};

// Records what the loop hands to a job.
class RecordingHooks : public FrameHooks {
 public:
  void OnBadFrame(size_t i, const Frame&, const std::string& error) override { bad.push_back(error); }
  void Prepare(size_t i, Frame*) override { prepared.push_back(i); }
  void OnFused(size_t i, const Frame&, const FusionSummary& summary) override {
    curve.push_back(summary.report.completeness_per_frame.back());
  }
  std::vector<std::string> bad;
  std::vector<size_t> prepared;
  std::vector<double> curve;
};

fusion::GridOptions BinGrid() {
  fusion::GridOptions grid;
  grid.min_W = AnalyticBin::RegionMin();
  grid.max_W = AnalyticBin::RegionMax();
  grid.voxel_m = kVoxelM;
  return grid;
}

TEST(FuseFrames, FusesEveryGoodFrameInOrderAndCountsTheBadOnes) {
  const AnalyticBin bin = SmallBin(6);
  std::vector<Frame> frames;
  for (int i = 0; i < bin.frames(); ++i) frames.push_back(bin.RenderFrame(i));
  frames[2].depth_m.release();  // delivered as a bad frame
  MemorySource source(bin.camera(), frames);
  fusion::VotingGrid grid(BinGrid());
  RecordingHooks hooks;
  const FusionSummary summary = FuseFrames(source, bin.camera(), grid, 2, hooks);
  const fusion::FusionReport& r = summary.report;
  EXPECT_EQ(r.frames, 5u);
  EXPECT_EQ(r.bad_frames, 1u);
  EXPECT_THAT(r.bad_frame_messages, ::testing::ElementsAre("unreadable frame 2"));
  EXPECT_EQ(hooks.bad, r.bad_frame_messages);
  EXPECT_THAT(hooks.prepared, ::testing::ElementsAre(0, 1, 3, 4, 5));
  EXPECT_EQ(r.insert_ms.size(), 5u);
  EXPECT_EQ(summary.completeness_ms.size(), 5u);
  EXPECT_EQ(r.threads, 2);
  EXPECT_EQ(hooks.curve, r.completeness_per_frame);
  // The curve never falls and ends where the fused map is.
  for (size_t i = 1; i < r.completeness_per_frame.size(); ++i) {
    EXPECT_GE(r.completeness_per_frame[i], r.completeness_per_frame[i - 1]);
  }
  EXPECT_GT(r.completeness_per_frame.back(), 0.3);
  EXPECT_GT(r.stats.hits, 0u);
  EXPECT_FALSE(summary.stopped);
  EXPECT_TRUE(summary.cameras_W.contains(bin.T_W_C(0).translation()));
}

// A source that fails mid-stream: a job that keeps what was fused says why it stopped.
class FailingSource : public MemorySource {
 public:
  using MemorySource::MemorySource;
  FrameStatus Next(Frame* frame, std::string* error) override {
    if (++calls_ == 3) throw InputError("oni://device", "", "no frame for 2 s");
    return MemorySource::Next(frame, error);
  }

 private:
  int calls_ = 0;
};

class KeepingHooks : public FrameHooks {
 public:
  bool KeepAfterSourceError(const InputError&) override { return true; }
};

TEST(FuseFrames, KeepsWhatWasFusedWhenTheJobSaysSo) {
  const AnalyticBin bin = SmallBin(4);
  std::vector<Frame> frames;
  for (int i = 0; i < bin.frames(); ++i) frames.push_back(bin.RenderFrame(i));
  fusion::VotingGrid grid(BinGrid());
  FailingSource keeping(bin.camera(), frames);
  KeepingHooks keep;
  const FusionSummary summary = FuseFrames(keeping, bin.camera(), grid, 1, keep);
  EXPECT_EQ(summary.report.frames, 2u);
  ASSERT_TRUE(summary.stopped);
  EXPECT_THAT(*summary.stopped, HasSubstr("no frame for 2 s"));
  FailingSource rethrowing(bin.camera(), frames);
  FrameHooks defaults;
  EXPECT_THROW(FuseFrames(rethrowing, bin.camera(), grid, 1, defaults), InputError);
}

FuseOptions OptionsFor(const fs::path& source, const fs::path& out) {
  FuseOptions o;
  o.source = source.string();
  o.out = out.string();
  o.voxel_m = kVoxelM;
  return o;
}

TEST(FuseJob, WritesTheMapAndItsReport) {
  ScratchDir dir("fuse_job");
  const AnalyticBin bin = SmallBin(6);
  WriteBinDirectory(bin, dir / "capture");
  const FuseJobSummary s = RunFuse(OptionsFor(dir / "capture", dir / "fused"));
  EXPECT_EQ(s.out, dir / "fused");
  EXPECT_EQ(s.report.frames, 6u);
  EXPECT_EQ(s.box_from, "the default box");
  EXPECT_EQ(s.depth_from, "the frame directory's depth");
  EXPECT_FALSE(s.stopped);
  EXPECT_GT(s.report.completeness, 0.3);
  for (const char* file :
       {"fused_depth.exr", "fused_depth.png", "fused_points.ply", "completeness.png", "report.json"}) {
    EXPECT_TRUE(fs::exists(dir / "fused" / file)) << file;
  }
  const nlohmann::json report = nlohmann::json::parse(testing::ReadText(dir / "fused" / "report.json"));
  for (const char* key : {"frames", "completeness", "depth_from", "box_from", "dropped_frames", "stopped_early"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_EQ(report["frames"].get<int>(), 6);
  EXPECT_FALSE(report["stopped_early"].get<bool>());
  EXPECT_FALSE(report.contains("stop_reason"));
  EXPECT_THAT(FuseSummaryText(s), HasSubstr("fused 6 frames into " + (dir / "fused").string() + ": completeness"));
  EXPECT_NO_THROW(CheckSourceEnded(s, OptionsFor(dir / "capture", dir / "fused")));
  // A finished fusion is never overwritten.
  try {
    RunFuse(OptionsFor(dir / "capture", dir / "fused"));
    FAIL() << "a second run into the same folder";
  } catch (const InputError& e) {
    EXPECT_THAT(e.what(), HasSubstr("holds a finished fusion (report.json)"));
  }
}

// A 1 mm recording fused at 0.25 mm voxels rounds depths to 4 voxels: fuse says so; 100 um
// (less than half a voxel) is fine, and 1 mm at 2 mm voxels too.
TEST(FuseJob, WarnsWhenTheDepthUnitIsCoarseForTheVoxel) {
  const auto coarse = DepthUnitWarning(1e-3, 0.25e-3);
  ASSERT_TRUE(coarse.has_value());
  EXPECT_THAT(*coarse, HasSubstr("1 mm steps, coarser than half the 0.25 mm voxel"));
  EXPECT_FALSE(DepthUnitWarning(1e-4, 0.25e-3).has_value());
  EXPECT_FALSE(DepthUnitWarning(1e-3, 2e-3).has_value());
  EXPECT_TRUE(DepthUnitWarning(1e-4, 0.1e-3).has_value());
}

// Two fuse runs into one --out at once, many times: one is refused before it fuses a frame, the
// other's maps are the bytes of a lone run (its report differs only in timings). Two runs used to
// both succeed, with the EXR of one and the PNG of the other.
TEST(FuseJob, TwoRunsAtOnceIntoOneFolder) {
  ScratchDir dir("fuse_job");
  WriteBinDirectory(SmallBin(2), dir / "capture");
  RunFuse(OptionsFor(dir / "capture", dir / "lone"));
  const char* kMaps[] = {"fused_depth.exr", "fused_depth.png", "fused_points.ply", "completeness.png"};
  constexpr int kTrials = 12;  // each trial ~0.1 s; the run-folder test interleaves many more
  for (int trial = 0; trial < kTrials; ++trial) {
    const fs::path out = dir / ("fused" + std::to_string(trial));
    std::atomic<int> ready{0}, succeeded{0};
    std::string refusal;
    auto one_run = [&] {
      ready++;
      while (ready < 2) {
      }
      try {
        RunFuse(OptionsFor(dir / "capture", out));
        succeeded++;
      } catch (const InputError& e) {
        refusal = e.what();
      }
    };
    std::thread a(one_run), b(one_run);
    a.join();
    b.join();
    ASSERT_EQ(succeeded, 1) << refusal;
    EXPECT_TRUE(refusal.find("another run is writing into it") != std::string::npos ||
                refusal.find("holds a finished fusion") != std::string::npos)
        << refusal;
    for (const char* map : kMaps) {
      EXPECT_EQ(testing::ReadText(out / map), testing::ReadText(dir / "lone" / map)) << map;
    }
    EXPECT_FALSE(fs::exists(out.string() + ".incomplete"));
  }
}

TEST(FuseJob, NamesTheOptionAtFaultAndWritesNothing) {
  ScratchDir dir("fuse_job");
  const AnalyticBin bin = SmallBin(2);
  WriteBinDirectory(bin, dir / "capture");
  auto error_of = [&](FuseOptions o) -> std::string {
    try {
      RunFuse(o);
    } catch (const InputError& e) {
      return e.source();
    }
    return "";
  };
  FuseOptions o = OptionsFor(dir / "capture", dir / "fused");
  o.box = "0,0,0,1,1";
  o.box_given = true;
  EXPECT_EQ(error_of(o), "--box");
  o.box = "0.1,0,0,0,1,1";  // inverted x
  EXPECT_EQ(error_of(o), "--box");
  o.box = "0,0,0,100,100,1";  // sound, but more than 65535 voxels along x
  o.voxel_m = 0.001;
  EXPECT_EQ(error_of(o), "--voxel");
  o.box = "1,1,1,1.2,1.2,1.2";  // misses the scene
  EXPECT_EQ(error_of(o), "--box");
  o = OptionsFor(dir / "capture", dir / "fused");
  o.threads = 0;
  EXPECT_EQ(error_of(o), "--threads");
  o = OptionsFor(dir / "capture", dir / "fused");
  o.poses = "poses.csv";
  EXPECT_EQ(error_of(o), "--poses");  // a frame directory carries its own
  EXPECT_FALSE(fs::exists(dir / "fused"));
}

}  // namespace
}  // namespace romunect::jobs
